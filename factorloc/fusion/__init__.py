"""Fusion strategies: the patent's closed-form Gaussian product and the GTSAM factor graph.

Both implement :class:`~factorloc.fusion.base.FusionStrategy` and must agree
(to 1e-9) whenever no estimate couples position and heading.
"""

from factorloc.fusion.base import Fused, FusionStrategy, SequentialStrategy
from factorloc.fusion.graph import GraphFusion
from factorloc.fusion.product import ProductFusion
from factorloc.fusion.robust import RobustGraphFusion
from factorloc.fusion.smoother import FixedLagSmoother, TrajectorySmoother

__all__ = [
    "FixedLagSmoother",
    "Fused",
    "FusionStrategy",
    "GraphFusion",
    "ProductFusion",
    "RobustGraphFusion",
    "SequentialStrategy",
    "TrajectorySmoother",
]

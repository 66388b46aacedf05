"""Fusion strategies: the patent's closed-form Gaussian product and the GTSAM factor graph.

Both implement :class:`~factorloc.fusion.base.FusionStrategy` and must agree
(to 1e-9) whenever no estimate couples position and heading.
"""

from factorloc.fusion.base import Fused, FusionStrategy, SequentialStrategy
from factorloc.fusion.graph import GraphFusion
from factorloc.fusion.product import ProductFusion

__all__ = ["Fused", "FusionStrategy", "SequentialStrategy", "GraphFusion", "ProductFusion"]

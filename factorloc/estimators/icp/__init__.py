"""Step 4 of the hierarchy: ICP → (x4, y4, θ4) with a geometry-aware covariance.

The query scan (a laser scan, or the patent's horizontal cut of the query's 3D cloud) is aligned to the
reference scan by point-to-line ICP (:func:`factorloc.registration.icp2d.align`; Censi, "An ICP variant using a
point-to-line metric", ICRA 2008), seeded by the latest reliable position and heading. Without them, or when the
seeded solution is unreliable (and not merely degenerate), a global initialization — a correlative scan matcher
over a pose grid (Olson, "Real-time correlative scan matching", ICRA 2009;
:mod:`factorloc.registration.global_search`) — proposes candidates that ICP refines.

Output: a full (x, y, θ) estimate in the world frame (``T_world_query = T_world_reference · T_reference_query``)
with the 3×3 covariance of :mod:`.covariance` rotated into the world frame. Its reliability is the conjunction of
the named rules of :mod:`.rules` (typed checks ``icp.<rule>``); the reason a user reads is rendered from them.

Parts: :mod:`.config` (the nested configuration), :mod:`.reference` (the prepared reference), :mod:`.candidates`
(seeded and global solutions), :mod:`.covariance`, :mod:`.rules`, :mod:`.step` (:func:`estimate`,
:class:`IcpStep`). How each default was measured: ``docs/calibration/icp.md``.
"""

from factorloc.estimators.icp.config import (
    AlignmentConfig,
    CovarianceConfig,
    GlobalInitConfig,
    IcpConfig,
    ReliabilityConfig,
    SeedConfig,
)
from factorloc.estimators.icp.covariance import UNCONSTRAINED_SIGMA_M, constraint_strength
from factorloc.estimators.icp.reference import IcpReference, prepare_reference, query_points
from factorloc.estimators.icp.step import IcpStep, estimate

__all__ = [
    "UNCONSTRAINED_SIGMA_M",
    "AlignmentConfig",
    "CovarianceConfig",
    "GlobalInitConfig",
    "IcpConfig",
    "IcpReference",
    "IcpStep",
    "ReliabilityConfig",
    "SeedConfig",
    "constraint_strength",
    "estimate",
    "prepare_reference",
    "query_points",
]

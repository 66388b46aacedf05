"""Mapping: a pose graph of places built from one run (graph SLAM with the hierarchy's ICP step as the scan
matcher and loop-closure verifier, a robust GTSAM back end and honest marginals).

:func:`build_map` (:mod:`.build`) takes a laser log and a :class:`MapConfig` (:mod:`.config`) and returns a
:class:`MapResult` (:mod:`.result`): places with optimized poses and marginal covariances, the pose of every
scan, and the loop closures with their typed verdicts. ``docs/mapping.md`` has the method and the benchmark.
"""

from factorloc.mapping.build import build_map, select_places
from factorloc.mapping.config import ROBUST_BACK_ENDS, MapConfig
from factorloc.mapping.result import Closure, MappedPlace, MapResult, relative_covariance

__all__ = [
    "ROBUST_BACK_ENDS",
    "Closure",
    "MapConfig",
    "MapResult",
    "MappedPlace",
    "build_map",
    "relative_covariance",
    "select_places",
]

"""Choosing places with a reliable pose hypothesis: the places whose view can overlap the query, nearest first.

A place's view reaches as far as its reference scan/cloud (:attr:`~factorloc.places.Place.footprint_m`, the 90 %
quantile of its points' planar ranges; ``panorama_range_m`` for a panorama-only place). A query at the
hypothesis position can overlap it when its distance to the place is at most that reach plus the hypothesis'
uncertainty (``n_sigma`` times the largest position σ of its covariance), and at most ``max_distance_m``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from factorloc._validate import nonnegative_float, positive_float, positive_int
from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.places.placemap import PlaceMap

__all__ = ["ChoiceConfig", "places_in_view"]


@dataclass(frozen=True)
class ChoiceConfig:
    """How places are chosen around a pose hypothesis.

    Parameters
    ----------
    k
        At most this many places.
    max_distance_m
        No place farther than this from the hypothesis (m).
    n_sigma
        The hypothesis' position uncertainty added to a place's reach, in σ of its largest axis.
    panorama_range_m
        The reach of a place that holds only a panorama (m).
    """

    k: int = 3
    max_distance_m: float = 8.0
    n_sigma: float = 3.0
    panorama_range_m: float = 4.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "k", positive_int("ChoiceConfig.k", self.k))
        object.__setattr__(self, "max_distance_m", positive_float("ChoiceConfig.max_distance_m", self.max_distance_m))
        object.__setattr__(self, "n_sigma", nonnegative_float("ChoiceConfig.n_sigma", self.n_sigma))
        object.__setattr__(self, "panorama_range_m", positive_float("ChoiceConfig.panorama_range_m", self.panorama_range_m))


def places_in_view(
    place_map: PlaceMap,
    T_world_robot: Pose2,
    covariance: np.ndarray | None = None,
    config: ChoiceConfig = ChoiceConfig(),
) -> tuple[tuple[str, float], ...]:
    """The ids of the places whose view can overlap a query at ``T_world_robot``, nearest first, with distances (m).

    ``covariance`` is the hypothesis' 3×3 world-frame covariance (None: taken as exact). At most ``config.k``.
    """
    if not isinstance(place_map, PlaceMap):
        raise InputError(f"places_in_view needs a PlaceMap, got {type(place_map).__name__}")
    if not isinstance(T_world_robot, Pose2):
        raise InputError(f"T_world_robot must be a Pose2, got {type(T_world_robot).__name__}")
    margin = 0.0
    if covariance is not None:
        cov = np.asarray(covariance, dtype=np.float64)
        if cov.shape != (3, 3):
            raise InputError(f"covariance must be 3×3, got shape {cov.shape}")
        largest = float(np.linalg.eigvalsh(cov[:2, :2])[-1]) if np.all(np.isfinite(cov[:2, :2])) else math.inf
        margin = config.n_sigma * math.sqrt(max(largest, 0.0))
    here = T_world_robot.translation
    found = []
    for p in place_map:
        d = float(np.hypot(*(p.position_m - here)))
        reach = p.footprint_m if p.footprint_m > 0.0 else config.panorama_range_m
        if d <= min(config.max_distance_m, reach + margin):
            found.append((p.id, d))
    found.sort(key=lambda item: (item[1], item[0]))
    return tuple(found[: config.k])

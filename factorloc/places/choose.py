"""Choosing places with a reliable pose hypothesis: the places whose view can overlap the query, nearest first.

A place's view reaches as far as its reference scan/cloud (:attr:`~factorloc.places.Place.footprint_m`, the 90 %
quantile of its points' planar ranges; ``panorama_range_m`` for a panorama-only place). A query at the
hypothesis position can overlap it when its distance to the place is at most that reach plus the hypothesis'
uncertainty (``n_sigma`` times the largest position σ of its covariance), and at most ``max_distance_m``.

A scanner that sees less than the full circle (the 180° lasers of the real logs) shares little with a place
taken facing the other way, however near: given the query's scan, the places whose points mostly fall in the
directions the query sees (:func:`view_overlap` ≥ ``min_overlap``, seen from the hypothesis) come first, nearest
first, then the others. With 360° scans every place overlaps fully and the order is the distance's.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from factorloc._validate import nonnegative_float, positive_float, positive_int
from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.places.placemap import PlaceMap

__all__ = ["ChoiceConfig", "places_in_view", "view_overlap"]


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
    min_overlap
        With the query's scan given: places whose :func:`view_overlap` is below this fraction come after the others.
    sector_rad
        The angular sectors :func:`view_overlap` counts the query's coverage in (rad).
    """

    k: int = 3
    max_distance_m: float = 8.0
    n_sigma: float = 3.0
    panorama_range_m: float = 4.0
    min_overlap: float = 0.5
    sector_rad: float = math.radians(5.0)

    def __post_init__(self) -> None:
        object.__setattr__(self, "k", positive_int("ChoiceConfig.k", self.k))
        object.__setattr__(self, "max_distance_m", positive_float("ChoiceConfig.max_distance_m", self.max_distance_m))
        object.__setattr__(self, "n_sigma", nonnegative_float("ChoiceConfig.n_sigma", self.n_sigma))
        object.__setattr__(self, "panorama_range_m", positive_float("ChoiceConfig.panorama_range_m", self.panorama_range_m))
        object.__setattr__(self, "sector_rad", positive_float("ChoiceConfig.sector_rad", self.sector_rad))
        if not 0.0 <= self.min_overlap <= 1.0:
            raise InputError(f"ChoiceConfig.min_overlap must be in [0, 1], got {self.min_overlap!r}")


def _sectors(points_m: np.ndarray, sector_rad: float) -> np.ndarray:
    """The sector index of each point's bearing (robot frame), sectors of ``sector_rad`` from −π."""
    n = max(int(round(2.0 * math.pi / sector_rad)), 1)
    bearing = np.arctan2(points_m[:, 1], points_m[:, 0])
    return np.minimum(((bearing + math.pi) * (n / (2.0 * math.pi))).astype(np.int64), n - 1)


def view_overlap(
    place_points_m: np.ndarray,
    T_world_place: Pose2,
    T_world_robot: Pose2,
    query_points_m: np.ndarray,
    sector_rad: float = math.radians(5.0),
) -> float:
    """The fraction of a place's scan points that lie in the directions a query's scan covers, in [0, 1].

    ``place_points_m`` (N×2, place frame) are moved into the robot frame of the hypothesis ``T_world_robot``; a
    point counts when its bearing falls in a sector (of ``sector_rad``) that holds at least one point of
    ``query_points_m`` (M×2, robot frame). 1 for two 360° scans; about 0 for two 180° scans facing apart.
    """
    if len(place_points_m) == 0 or len(query_points_m) == 0:
        return 0.0
    n = max(int(round(2.0 * math.pi / sector_rad)), 1)
    covered = np.zeros(n, dtype=bool)
    covered[_sectors(np.asarray(query_points_m, dtype=np.float64), sector_rad)] = True
    T = T_world_robot.inverse().compose(T_world_place)
    c, s = math.cos(T.theta), math.sin(T.theta)
    pts = np.asarray(place_points_m, dtype=np.float64)
    moved = np.column_stack([c * pts[:, 0] - s * pts[:, 1] + T.x, s * pts[:, 0] + c * pts[:, 1] + T.y])
    return float(np.count_nonzero(covered[_sectors(moved, sector_rad)])) / len(pts)


def places_in_view(
    place_map: PlaceMap,
    T_world_robot: Pose2,
    covariance: np.ndarray | None = None,
    config: ChoiceConfig = ChoiceConfig(),
    query_points_m: np.ndarray | None = None,
) -> tuple[tuple[str, float], ...]:
    """The ids of the places whose view can overlap a query at ``T_world_robot``, nearest first, with distances (m).

    ``covariance`` is the hypothesis' 3×3 world-frame covariance (None: taken as exact). ``query_points_m`` (N×2,
    robot frame) is the query's scan: places that share less than ``config.min_overlap`` of their view with it
    (:func:`view_overlap`) then come after those that do (module docstring). At most ``config.k``.
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
    if query_points_m is not None and len(found) > config.k:

        def apart(pid: str) -> bool:
            p = place_map[pid]
            pts = p.planar_points_m()
            if pts is None:
                return False
            return view_overlap(pts, p.T_world_reference, T_world_robot, query_points_m, config.sector_rad) < config.min_overlap

        found.sort(key=lambda item: apart(item[0]))  # stable: nearest first within each group
    return tuple(found[: config.k])

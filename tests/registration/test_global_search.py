"""Correlative global search: finds a robot moved by metres and turned by a large angle."""

from __future__ import annotations

import math

import numpy as np

from factorloc.geometry import Pose2
from factorloc.registration.global_search import GlobalSearchParams, search
from factorloc.registration.icp2d import align, prepare_target


def test_search_then_icp_recovers_a_kidnapped_pose(room_points: np.ndarray) -> None:
    true = Pose2(2.5, 1.5, math.radians(130.0))
    rng = np.random.default_rng(0)
    src = true.inverse().transform_points(room_points[::3]) + rng.normal(0, 0.005, room_points[::3].shape)
    cands = search(room_points, src, GlobalSearchParams(radius_m=4.0))
    best = cands[0].T_reference_query
    err = true.between(best)
    assert math.hypot(err.x, err.y) < 0.15
    assert abs(math.degrees(err.theta)) < 3.0
    refined = align(prepare_target(room_points), src, best).T_target_source
    err = true.between(refined)
    assert math.hypot(err.x, err.y) < 0.005
    assert abs(math.degrees(err.theta)) < 0.1


def test_search_respects_the_heading_window(room_points: np.ndarray) -> None:
    true = Pose2(1.0, -0.5, math.radians(-40.0))
    src = true.inverse().transform_points(room_points[::3])
    cands = search(
        room_points, src, GlobalSearchParams(radius_m=2.0), heading_rad=math.radians(-35.0), heading_half_width_rad=0.2
    )
    for c in cands:
        assert abs(math.remainder(c.T_reference_query.theta - math.radians(-35.0), 2 * math.pi)) <= 0.2 + math.radians(3.5)
    assert math.hypot(cands[0].T_reference_query.x - 1.0, cands[0].T_reference_query.y + 0.5) < 0.15

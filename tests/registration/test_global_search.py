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


def test_the_compiled_window_kernel_equals_the_numpy_gather_bitwise() -> None:
    """score_lattice's kernel sums the same cells in the same order as the gather it replaced: equal to the bit,
    for windows inside, across and beyond the field's border, with and without a stride, one corner or one per
    heading."""
    from factorloc.registration.global_search import build_field, score_lattice, score_lattice_gather

    rng = np.random.default_rng(5)
    pts = rng.uniform(-3.0, 3.0, (200, 2))
    for resolution in (0.3, 0.05):
        field = build_field(pts, resolution, 0.3 if resolution > 0.1 else 0.08, 0.9)
        for stride in (1, 2, 3):
            for corner in (np.array([-2.0, -1.0]), rng.normal(0.0, 4.0, (6, 2)), np.array([40.0, -40.0])):
                thetas = rng.uniform(-np.pi, np.pi, 6)
                query = rng.uniform(-4.0, 4.0, (57, 2))
                a = score_lattice(field, query, thetas, corner, (17, 12), stride)
                b = score_lattice_gather(field, query, thetas, corner, (17, 12), stride)
                assert a.shape == b.shape == (6, -(-17 // stride), -(-12 // stride))
                assert a.dtype == b.dtype == np.float32
                assert np.array_equal(a, b)
    assert score_lattice(field, query, thetas, np.array([1e9, 0.0]), (5, 5)).max() == 0.0


def test_suppression_keeps_maxima_exactly_one_separation_apart_whatever_the_rounding() -> None:
    """Two lattice maxima exactly ``separation_m`` apart (two coarse cells of 0.3 m for 0.6 m) are distinct, one
    closer is suppressed; in heading the same holds across the ±π seam."""
    from factorloc.registration.global_search import _suppress

    thetas = np.arange(120) * (2 * np.pi / 120)  # 3° steps, full circle
    a = np.array([0, 0, 0, 119, 3])
    kx = np.array([10, 12, 11, 10, 10])  # 0.6 m, 0.3 m away; the same cell at -3°; the same cell at +9°
    ky = np.array([10, 10, 10, 10, 10])
    kept = _suppress(a, kx, ky, thetas, 0.3, 0.6, np.radians(10.0), 10)
    assert kept.tolist() == [0, 1]
    assert _suppress(a, kx, ky, thetas, 0.3, 0.6, np.radians(10.0), 1).tolist() == [0]
    assert _suppress(a, kx, ky, thetas, 0.3, 0.6, np.radians(8.0), 10).tolist() == [0, 1, 4]

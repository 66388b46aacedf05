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


def test_the_compiled_peak_test_finds_the_cells_scipys_maximum_filter_finds() -> None:
    """search's local maxima (``_peaks``) are the cells of ``scores >= maximum_filter(scores) & scores > 0``, with
    ties (equal neighbours), odd and even windows, windows wider than the volume, the heading axis wrapped or
    clamped."""
    from scipy import ndimage

    from factorloc.registration.global_search import _peaks

    rng = np.random.default_rng(0)
    for t in range(200):
        n_a, n_c = int(rng.integers(1, 12)), int(rng.integers(1, 9))
        if t % 2:
            scores = (rng.random((n_a, n_c, n_c)) - 0.2).astype(np.float32)
        else:
            scores = (rng.integers(0, 4, (n_a, n_c, n_c)) / 3).astype(np.float32)  # many ties
        size_a, size_c, wrap = int(rng.integers(1, n_a + 1)), int(rng.integers(1, 6)), bool(t % 3)
        mode = ("wrap" if wrap else "nearest", "nearest", "nearest")
        window_max = ndimage.maximum_filter(scores, size=(size_a, size_c, size_c), mode=mode)
        expected = np.flatnonzero((scores >= window_max) & (scores > 0))
        assert np.array_equal(_peaks(scores, size_a, size_c, wrap), expected)


def test_the_compiled_lattice_cells_equal_the_numpy_expression_bitwise() -> None:
    """``_lattice_cells``'s kernel computes ``floor(((c·qx − s·qy) + tx − ox)/res + 1e-9)`` (and its y twin) with the
    same float64 operations as the numpy expression it replaced: the same cells, for one corner or one per heading."""
    from factorloc.registration.global_search import LikelihoodField, _lattice_cells

    rng = np.random.default_rng(3)
    for t in range(100):
        n_a, n = int(rng.integers(1, 150)), int(rng.integers(3, 200))
        field = LikelihoodField(np.zeros((3, 3), np.float32), rng.normal(0.0, 10.0, 2), float(rng.choice([0.05, 0.3])))
        query, thetas = rng.normal(0.0, 8.0, (n, 2)), rng.uniform(-4.0, 4.0, n_a)
        corner = rng.normal(0.0, 5.0, 2) if t % 2 else rng.normal(0.0, 5.0, (n_a, 2))
        c, s = np.cos(thetas), np.sin(thetas)
        rx = c[:, None] * query[None, :, 0] - s[:, None] * query[None, :, 1]
        ry = s[:, None] * query[None, :, 0] + c[:, None] * query[None, :, 1]
        tx, ty = (corner[0], corner[1]) if corner.ndim == 1 else (corner[:, :1], corner[:, 1:])
        bx = np.floor((rx + tx - field.origin_m[0]) / field.resolution_m + 1e-9).astype(np.int64)
        by = np.floor((ry + ty - field.origin_m[1]) / field.resolution_m + 1e-9).astype(np.int64)
        got = _lattice_cells(field, query, thetas, corner)
        assert np.array_equal(got[0], bx) and np.array_equal(got[1], by)

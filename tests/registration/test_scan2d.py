"""Scan extraction from clouds, voxel grid, normals, free-space profile."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from factorloc.errors import InputError
from factorloc.registration.scan2d import (
    ScanExtraction,
    estimate_normals_2d,
    extract_scan,
    free_space_violation,
    median_range_m,
    polar_profile,
    voxel_downsample_2d,
)
from factorloc.types import PointCloud


def _wall_cloud(rng: np.random.Generator) -> np.ndarray:
    """A wall at x = 2 m from floor to ceiling (z 0–2.5 m) plus floor and ceiling points."""
    y = rng.uniform(-2, 2, 4000)
    z = rng.uniform(0, 2.5, 4000)
    wall = np.column_stack([np.full_like(y, 2.0), y, z])
    floor = np.column_stack([rng.uniform(0.5, 2, 1000), rng.uniform(-2, 2, 1000), np.zeros(1000)])
    ceiling = np.column_stack([rng.uniform(0.5, 2, 1000), rng.uniform(-2, 2, 1000), np.full(1000, 2.5)])
    return np.vstack([wall, floor, ceiling])


def test_extract_scan_keeps_the_band_drops_floor_and_ceiling_and_bounds_the_count() -> None:
    cloud = PointCloud(_wall_cloud(np.random.default_rng(0)))
    scan = extract_scan(cloud, ScanExtraction(min_height_m=0.8, max_height_m=1.2, voxel_m=0.05, max_points=50))
    assert len(scan) == 50
    np.testing.assert_allclose(scan.points_m[:, 0], 2.0, atol=1e-9)  # only the wall survives
    full = extract_scan(cloud, ScanExtraction(min_height_m=0.8, max_height_m=1.2, voxel_m=0.05, max_points=1000))
    assert 75 <= len(full) <= 81  # 4 m of wall in 5 cm cells


def test_extract_scan_raises_when_the_band_is_empty() -> None:
    cloud = PointCloud(np.array([[1.0, 0.0, 0.0], [1.0, 0.1, 0.0], [1.0, 0.2, 0.01], [1.0, 0.3, 2.5]]))
    with pytest.raises(InputError, match="height band"):
        extract_scan(cloud)


def test_voxel_downsample_replaces_each_cell_by_its_centroid() -> None:
    pts = np.array([[0.01, 0.01], [0.03, 0.03], [0.51, 0.01]])
    out = voxel_downsample_2d(pts, 0.1)
    np.testing.assert_allclose(sorted(out[:, 0]), [0.02, 0.51])


def test_voxel_downsample_gives_the_bits_of_the_row_unique_and_add_at_form() -> None:
    """The grid's 1-D cell keys and bincount sums give the cells, their order and their centroids of the form they
    replaced (``np.unique(cells, axis=0)`` and ``np.add.at``), also for cells too far apart for one key."""
    rng = np.random.default_rng(1)
    for t in range(200):
        pts = rng.normal(0.0, rng.uniform(0.1, 20.0), (int(rng.integers(1, 300)), 2))
        if t % 5 == 0:
            pts = np.round(pts, 1)  # points on cell borders, several per cell
        if t % 7 == 0:
            pts[0] = [1e17, -1e17]  # the fallback: no single int64 key spans these cells
        voxel = float(rng.choice([0.025, 0.15, 1.0]))
        cells = np.floor(pts / voxel).astype(np.int64)
        _, inverse, counts = np.unique(cells, axis=0, return_inverse=True, return_counts=True)
        sums = np.zeros((len(counts), 2))
        np.add.at(sums, inverse.ravel(), pts)
        assert np.array_equal(voxel_downsample_2d(pts, voxel), sums / counts[:, None])


def test_normals_of_a_line_are_perpendicular_and_face_the_sensor() -> None:
    y = np.linspace(-1, 1, 101)
    pts = np.column_stack([np.full_like(y, 3.0), y])
    n, q = estimate_normals_2d(pts)
    np.testing.assert_allclose(n, np.tile([-1.0, 0.0], (101, 1)), atol=1e-9)
    assert q.min() > 0.99


def test_free_space_violation_counts_points_the_sensor_saw_through() -> None:
    ang = np.linspace(-math.pi, math.pi, 720, endpoint=False)
    circle = 3.0 * np.column_stack([np.cos(ang), np.sin(ang)])  # a round room of radius 3 m
    prof = polar_profile(circle)
    assert free_space_violation(prof, circle) == 0.0
    inside = 1.5 * np.column_stack([np.cos(ang[:100]), np.sin(ang[:100])])  # inside the seen-empty room
    outside = 4.0 * np.column_stack([np.cos(ang[:100]), np.sin(ang[:100])])  # behind the wall: unknown
    assert free_space_violation(prof, inside) == 1.0
    assert free_space_violation(prof, outside) == 0.0


def test_polar_profile_fills_narrow_gaps_only() -> None:
    ang = np.concatenate([np.linspace(-1.0, -0.1, 50), np.linspace(0.1, 1.0, 50)])  # a 0.2 rad doorway
    pts = 2.0 * np.column_stack([np.cos(ang), np.sin(ang)])
    prof = polar_profile(pts, gap_free_m=5.0)
    bins = np.floor((np.array([0.0, 2.0]) + math.pi) / (2 * math.pi) * 720).astype(int)
    assert prof[bins[0]] == pytest.approx(2.0, abs=0.01)  # doorway: free up to the nearer jamb
    assert np.isnan(prof[bins[1]])  # outside the field of view: unknown


def _reference_normals(pts: np.ndarray, k: int = 7, max_radius_m: float = 0.5) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """PCA line normals written plainly (cKDTree, ``numpy.linalg.eigh`` per point): what the vectorized closed form
    of :func:`estimate_normals_2d` must reproduce; and where the k nearest neighbours are ambiguous (a tie at the
    k-th distance: two exact searches may keep either point)."""
    n = len(pts)
    d, idx = cKDTree(pts).query(pts, k=min(k, n) + 1, distance_upper_bound=max_radius_m)
    d, idx = d.reshape(n, -1), idx.reshape(n, -1)
    tie = np.zeros(n, dtype=bool) if k >= n else (d[:, k - 1] == d[:, k]) & np.isfinite(d[:, k])
    d, idx = d[:, : min(k, n)], idx[:, : min(k, n)]
    normals, quality = np.empty((n, 2)), np.zeros(n)
    for i in range(n):
        nb = pts[idx[i][d[i] < np.inf]]
        to_sensor = -pts[i] / max(np.hypot(*pts[i]), 1e-12)
        if len(nb) < 3:
            normals[i] = to_sensor
            continue
        lam, vec = np.linalg.eigh(np.cov(nb.T, bias=True) * len(nb))
        normals[i] = vec[:, 0] if vec[:, 0] @ to_sensor >= 0.0 else -vec[:, 0]
        quality[i] = 1.0 - lam[0] / lam[1] if lam[1] > 0.0 else 0.0
    return normals, np.clip(quality, 0.0, 1.0), tie


def _assert_same_normals(pts: np.ndarray) -> None:
    n, q = estimate_normals_2d(pts)
    n0, q0, tie = _reference_normals(pts)
    assert np.mean(tie) < 0.05
    np.testing.assert_allclose(q[~tie], q0[~tie], atol=1e-9)
    line = (q0 > 1e-6) & ~tie  # the direction of an isotropic neighbourhood is arbitrary
    np.testing.assert_allclose(n[line], n0[line], atol=1e-7)
    np.testing.assert_allclose(np.hypot(n[:, 0], n[:, 1]), 1.0, atol=1e-12)
    assert np.all(np.einsum("ij,ij->i", n, -pts) >= -1e-12)  # every normal faces the sensor at the origin


def test_normals_reproduce_a_per_point_eigen_decomposition_on_random_scenes() -> None:
    rng = np.random.default_rng(2)
    for size in (3, 5, 40, 400):
        _assert_same_normals(rng.uniform(-4.0, 4.0, (size, 2)))
        a = rng.uniform(-math.pi, math.pi, size)
        _assert_same_normals(np.column_stack([np.cos(a), np.sin(a)]) * rng.uniform(1, 6, (size, 1)))


def test_normals_of_degenerate_neighbourhoods() -> None:
    pts = np.array([[1.0, 1.0]] * 5 + [[2.0, 0.0], [2.0, 0.1], [2.0, 0.2], [5.0, 5.0]])
    n, q = estimate_normals_2d(pts)
    _assert_same_normals(pts)
    assert np.all(q[:5] == 0.0)  # five copies of one point: no line
    assert q[8] == 0.0 and np.allclose(n[8], -pts[8] / np.hypot(*pts[8]))  # isolated: faces the sensor
    collinear = np.column_stack([np.linspace(0.5, 3.0, 30), np.linspace(0.5, 3.0, 30)])  # a line through the sensor
    n, q = estimate_normals_2d(collinear)
    assert q.min() > 0.999
    np.testing.assert_allclose(np.abs(n @ [1.0, 1.0]), 0.0, atol=1e-9)


def test_normals_reject_non_finite_points() -> None:
    with pytest.raises(InputError, match="NaN"):
        estimate_normals_2d(np.array([[1.0, 0.0], [np.inf, 1.0], [2.0, 2.0]]))


def test_normals_reproduce_a_per_point_eigen_decomposition_on_real_laser_scans(shared_data) -> None:
    from factorloc.datasets.rosbag import read_scans

    track = read_scans(shared_data / "laser" / "aces.sort.bag")
    for scan in track.scans[::400]:
        _assert_same_normals(scan.points_m)


def _reference_profile(pts: np.ndarray, n_bins: int = 720, gap_free_m: float = 0.0, max_gap_rad: float = 0.35) -> np.ndarray:
    """The free-range profile bin by bin (loops): what the vectorized :func:`polar_profile` must reproduce."""
    prof = np.full(n_bins, np.inf)
    for x, y in pts:
        b = int(np.floor((math.atan2(y, x) + math.pi) / (2 * math.pi) * n_bins)) % n_bins
        prof[b] = min(prof[b], np.hypot(x, y))
    seen = [k for k in range(n_bins) if np.isfinite(prof[k])]
    out = prof.copy()
    if gap_free_m > 0.0 and 0 < len(seen) < n_bins:
        for k in range(n_bins):
            if np.isfinite(prof[k]):
                continue
            prev = max((s for s in seen if s < k), default=seen[-1] - n_bins)
            nxt = min((s for s in seen if s > k), default=seen[0] + n_bins)
            if nxt - prev - 1 <= int(max_gap_rad / (2 * math.pi) * n_bins):
                out[k] = min(prof[prev % n_bins], prof[nxt % n_bins], gap_free_m)
    out[~np.isfinite(out)] = np.nan
    return out


def _reference_violation(prof: np.ndarray, pts: np.ndarray, margin_m: float = 0.15, margin_ratio: float = 0.05) -> float:
    bad = 0
    for x, y in pts:
        free = prof[int(np.floor((math.atan2(y, x) + math.pi) / (2 * math.pi) * len(prof))) % len(prof)]
        bad += bool(np.isfinite(free) and np.hypot(x, y) < free - max(margin_m, margin_ratio * free))
    return bad / len(pts)


def test_polar_profile_and_violation_reproduce_a_per_point_loop() -> None:
    rng = np.random.default_rng(8)
    a = rng.uniform(-math.pi, math.pi, 150)
    room = np.column_stack([np.cos(a), np.sin(a)]) * rng.uniform(1.0, 5.0, (150, 1))
    half = room[room[:, 0] > 0.0]  # a 180° field of view
    edge = np.array([[-2.0, 0.0], [-2.0, -1e-18], [3.0, 0.0]])  # bearings +π, −π (the same bin) and 0
    for pts in (room, half, half[:1], edge, room[:2]):
        for gap in (0.0, 2.0):
            prof = polar_profile(pts, gap_free_m=gap)
            np.testing.assert_array_equal(prof, _reference_profile(pts, gap_free_m=gap))
            probe = pts * rng.uniform(0.3, 1.2, (len(pts), 1))
            assert free_space_violation(prof, probe) == _reference_violation(prof, probe)
    assert np.all(np.isnan(polar_profile(np.zeros((0, 2)), gap_free_m=2.0)))
    assert free_space_violation(np.full(720, np.nan), room) == 0.0


def _reference_overlap(prof_a, pts_a, prof_b, pts_b, T, d: float) -> tuple[float, int]:
    """Overlap fitness written plainly (cKDTree, numpy): what the compiled :func:`overlap_fitness` must reproduce."""
    out = []
    b_in_a = T.transform_points(pts_b)
    a_in_b = T.inverse().transform_points(pts_a)
    for pts, prof, other in ((b_in_a, prof_a, pts_a), (a_in_b, prof_b, pts_b)):
        bins = np.floor((np.arctan2(pts[:, 1], pts[:, 0]) + np.pi) / (2 * np.pi) * len(prof)).astype(np.int64) % len(prof)
        free = prof[bins]
        rho = np.hypot(pts[:, 0], pts[:, 1])
        vis = np.isfinite(free) & (rho <= free + np.maximum(0.15, 0.05 * np.nan_to_num(free)))
        if not vis.any():
            out.append((0.0, 0))
            continue
        dist, _ = cKDTree(other).query(pts[vis], distance_upper_bound=d)
        out.append((float(np.mean(dist < d)), int(vis.sum())))
    (f1, n1), (f2, n2) = out
    return min(f1, f2), min(n1, n2)


def _room_scan(rng: np.random.Generator, n: int, fov_rad: float) -> np.ndarray:
    a = rng.uniform(-fov_rad / 2, fov_rad / 2, n)
    return np.column_stack([np.cos(a), np.sin(a)]) * rng.uniform(1.0, 6.0, (n, 1))


def test_overlap_fitness_and_alignment_violation_reproduce_the_plain_numpy_forms() -> None:
    from factorloc.geometry import Pose2
    from factorloc.registration.scan2d import alignment_violation, overlap_fitness, profile_and_violation

    rng = np.random.default_rng(5)
    checked_fit = checked_violation = 0
    for trial in range(40):
        a = _room_scan(rng, 180, math.pi)
        b = _room_scan(rng, 150, math.pi if trial % 2 else 2 * math.pi)
        T = Pose2(rng.normal(0, 0.5), rng.normal(0, 0.5), rng.uniform(-math.pi, math.pi))
        pa, pb = polar_profile(a, gap_free_m=2.0), polar_profile(b, gap_free_m=2.0)
        for d in (0.05, 0.3):
            got = overlap_fitness(pa, a, pb, b, T, d)
            assert got == _reference_overlap(pa, a, pb, b, T, d)
            checked_fit += got[1] > 0 and 0.0 < got[0] < 1.0
        v = max(free_space_violation(pa, T.transform_points(b)), free_space_violation(pb, T.inverse().transform_points(a)))
        assert alignment_violation(pa, a, pb, b, T) == v
        prof, v2 = profile_and_violation(pa, a, b, T, 2.0)
        np.testing.assert_array_equal(prof, pb)
        assert v2 == v
        checked_violation += 0.0 < v < 1.0
    assert checked_fit >= 20 and checked_violation >= 20  # the comparisons saw partial fits and violations


def test_profile_and_violation_reject_nan_points() -> None:
    bad = np.array([[1.0, 0.0], [np.nan, 1.0], [2.0, 2.0]])
    with pytest.raises(InputError, match="NaN"):
        polar_profile(bad)
    with pytest.raises(InputError, match="NaN"):
        free_space_violation(np.full(720, 3.0), bad)
    from factorloc.geometry import Pose2
    from factorloc.registration.scan2d import alignment_violation, overlap_fitness, profile_and_violation

    good, prof = np.array([[1.0, 0.0], [2.0, 1.0], [2.0, 2.0]]), np.full(720, 3.0)
    with pytest.raises(InputError, match="finite"):
        alignment_violation(prof, good, prof, bad, Pose2())
    with pytest.raises(InputError, match="finite"):
        overlap_fitness(prof, bad, prof, good, Pose2(), 0.1)
    with pytest.raises(InputError, match="finite"):
        profile_and_violation(prof, good, bad, Pose2(), 2.0)
    with pytest.raises(InputError, match="profile"):
        alignment_violation(np.zeros(0), good, prof, good, Pose2())


def test_compiled_pca_reproduces_the_numpy_form() -> None:
    """The compiled PCA of the k = 7 neighbourhoods (sums in numpy's order, φ from numpy's arctan2) gives the
    normals and qualities of the plain numpy form, on random scenes, a noisy arc and a lattice (equidistant
    neighbours), with all neighbours inside the radius and with some outside."""
    from factorloc.registration.nn import KdTree2D
    from factorloc.registration.scan2d import _pca_numpy, pca_normals

    rng = np.random.default_rng(9)
    arc = np.column_stack([np.cos(np.linspace(-1.5, 1.5, 181)), np.sin(np.linspace(-1.5, 1.5, 181))]) * 4.0
    lattice = np.stack(np.meshgrid(np.arange(12) * 0.1, np.arange(9) * 0.1), axis=-1).reshape(-1, 2) + [2.0, -1.0]
    for pts in (rng.uniform(-5, 5, (300, 2)), arc + rng.normal(0, 0.01, arc.shape), lattice, rng.uniform(-1, 1, (9, 2))):
        pts = np.ascontiguousarray(pts)
        d, idx = KdTree2D(pts).nearest_lifted(KdTree2D(pts).lifted, 7)
        for radius in (0.5, 0.05):
            n1, q1 = pca_normals(pts, d, idx, radius)
            n0, q0 = _pca_numpy(pts, d, idx, radius)
            np.testing.assert_allclose(n1, n0, rtol=0, atol=1e-12)
            np.testing.assert_allclose(q1, q0, rtol=0, atol=1e-12)
    # (bit for bit on the development machine, whose OpenBLAS and numpy einsum orders the compiled sums emulate;
    # another BLAS kernel may add the numpy form's terms in another order, hence the tolerance)


def test_free_space_calls_without_validation_give_the_checked_figures():
    """``validate=False`` (for arrays already checked) skips the checks only: the same profile and violations."""
    from factorloc.geometry import Pose2
    from factorloc.registration.scan2d import alignment_violation, polar_profile, profile_and_violation

    rng = np.random.default_rng(3)
    a = np.column_stack([np.cos(np.linspace(-2, 2, 120)), np.sin(np.linspace(-2, 2, 120))]) * rng.uniform(2, 4, (120, 1))
    b = a[::2] + rng.normal(0, 0.02, (60, 2))
    T = Pose2(0.1, -0.05, 0.03)
    pa = polar_profile(a)
    prof, v = profile_and_violation(pa, a, b, T, 1.0)
    prof2, v2 = profile_and_violation(pa, a, b, T, 1.0, validate=False)
    assert np.array_equal(prof, prof2, equal_nan=True) and v == v2
    assert alignment_violation(pa, a, prof, b, T) == alignment_violation(pa, a, prof, b, T, validate=False)


@pytest.mark.parametrize("n", [1, 2, 3, 180, 181, 361])
def test_the_compiled_median_range_is_numpys_median_of_the_hypot_bitwise(n):
    rng = np.random.default_rng(n)
    pts = rng.normal(size=(n, 2)) * rng.uniform(0.1, 30.0)
    assert median_range_m(pts) == float(np.median(np.hypot(pts[:, 0], pts[:, 1])))
    tied = np.repeat(pts[: max(1, n // 3)], 3, axis=0)[:n]  # repeated ranges: the middle values tie
    assert median_range_m(tied) == float(np.median(np.hypot(tied[:, 0], tied[:, 1])))

"""Scan extraction from clouds, voxel grid, normals, free-space profile."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc.errors import InputError
from factorloc.registration.scan2d import (
    ScanExtraction,
    estimate_normals_2d,
    extract_scan,
    free_space_violation,
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

"""The parallax bound read from the heading votes' own spread (:func:`factorloc.vision.depth.spread_parallax_bound`)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc.errors import InputError
from factorloc.vision.depth import spread_parallax_bound

HALF_FOV = math.radians(28.5)  # a 57° view


def _parallax(phi: np.ndarray, normal: float, distance_m: float, step_m: float, direction: float) -> np.ndarray:
    """The bearing change (rad, exact) of points on a plane (normal ``normal``, at ``distance_m``) seen at ``phi`` from
    the origin, when the camera steps ``step_m`` towards ``direction``."""
    r = distance_m / np.cos(phi - normal)
    p = np.column_stack([r * np.cos(phi), r * np.sin(phi)])
    q = p - step_m * np.array([math.cos(direction), math.sin(direction)])
    return np.arctan2(q[:, 1], q[:, 0]) - phi


def test_an_even_57_degree_view_gives_the_closed_form_ratio() -> None:
    """Bearings spread evenly over ±h: the worst case is a sideways step against a wall straight ahead, where
    every bearing turns by (d/D) cos²φ: k = mean(cos²φ) / std(cos²φ) = 13.3 for h = 28.5° (worked by hand from
    the moments of cos 2φ and cos 4φ over the view)."""
    phi = np.linspace(-HALF_FOV, HALF_FOV, 2001)
    _, k = spread_parallax_bound(phi, np.full(phi.size, 1e-3), n_effective=30, confidence=0.99)
    # the closed form of the worst case: (|M| + 1) / S at u = π/2, M = −mean cos 2φ, S = std cos 2φ
    c = np.cos(2.0 * phi)
    assert k == pytest.approx((abs(c.mean()) + 1.0) / c.std(), rel=1e-4)
    assert k == pytest.approx(13.4, abs=0.1)


def test_the_bound_covers_the_bias_of_any_plane_and_step() -> None:
    """Noise-free votes from a plane seen after a step: the mode's bias never exceeds the bound, whatever the
    plane's orientation and distance and the step's direction and length, and bunched bearings only widen it."""
    rng = np.random.default_rng(3)
    worst = 0.0
    for _ in range(400):
        centre = rng.uniform(-math.pi, math.pi)
        width = rng.uniform(0.05, 1.0) * HALF_FOV
        phi = centre + rng.uniform(-width, width, size=int(rng.integers(8, 40)))
        normal = centre + rng.uniform(-0.6, 0.6)
        delta = _parallax(phi, normal, rng.uniform(0.8, 8.0), rng.uniform(0.02, 0.4), rng.uniform(-math.pi, math.pi))
        bias = float(delta.mean())
        bound, k = spread_parallax_bound(phi, delta - bias, n_effective=len(phi), confidence=0.5)
        assert abs(bias) <= bound * 1.02, f"bias {math.degrees(bias):.3f}° > bound {math.degrees(bound):.3f}° (k {k:.1f})"
        worst = max(worst, abs(bias) / bound)
    assert worst > 0.5  # the bound is attained up to the plane's and the step's finite size, not loose by design


def test_the_upper_confidence_limit_widens_few_votes_more() -> None:
    phi = np.linspace(-HALF_FOV, HALF_FOV, 40)
    e = np.tile([1e-3, -1e-3], 20)
    few, k = spread_parallax_bound(phi, e, n_effective=5, confidence=0.99)
    many, k2 = spread_parallax_bound(phi, e, n_effective=30, confidence=0.99)
    assert k == k2 and few > many > k * 1e-3


def test_bearings_that_coincide_bound_nothing() -> None:
    phi = np.full(12, 0.7)
    assert spread_parallax_bound(phi, np.zeros(12), n_effective=12, confidence=0.99) == (math.inf, math.inf)
    assert spread_parallax_bound(phi[:1], np.zeros(1), n_effective=1, confidence=0.99) == (math.inf, math.inf)
    assert spread_parallax_bound(np.zeros(3), np.zeros(4), n_effective=3, confidence=0.99) == (math.inf, math.inf)


def test_a_spread_the_inlier_band_may_have_cut_bounds_nothing() -> None:
    """Votes spread across the whole inlier band: the band kept a slice of a wider spread (a 360° view from a step
    away), whose rms says nothing about the parallax; the bound then holds only while 3 × its rms fits the band."""
    phi = np.linspace(-math.pi, math.pi, 60, endpoint=False)
    band = math.radians(1.5)
    cut = np.random.default_rng(1).uniform(-band, band, 60)
    bound, k = spread_parallax_bound(phi, cut, n_effective=30, confidence=0.99, band_rad=band)
    assert bound == math.inf and math.isfinite(k)
    tight = 0.02 * cut
    bound, k2 = spread_parallax_bound(phi, tight, n_effective=30, confidence=0.99, band_rad=band)
    assert k2 == k and 3.0 * bound / k < band


def test_bad_input_is_refused_by_name() -> None:
    phi = np.linspace(-HALF_FOV, HALF_FOV, 10)
    with pytest.raises(InputError, match="finite"):
        spread_parallax_bound(phi, np.full(10, math.nan), n_effective=10, confidence=0.99)
    with pytest.raises(InputError, match="finite"):
        spread_parallax_bound(np.append(phi[:-1], math.inf), np.zeros(10), n_effective=10, confidence=0.99)
    with pytest.raises(InputError, match="confidence"):
        spread_parallax_bound(phi, np.zeros(10), n_effective=10, confidence=1.0)


def test_a_scan_gives_a_planar_depth_map_and_a_cloud_does_not() -> None:
    """``DepthMap.planar``: a reference with only a planar scan gives one row of ranges read for every elevation (the
    compass then uses its ``planar_*`` range errors); with a cloud the rows resolve elevation. A square room 2 m
    from the reference on every side: the scan's range straight ahead is 2 m at any elevation."""
    from factorloc import Pose2, Reference, Scan
    from factorloc.vision.depth import depth_map
    from factorloc.vision.strips import Grid

    t = np.linspace(-2.0, 2.0, 200)
    walls = np.concatenate([np.column_stack([np.full_like(t, s), t]) for s in (-2.0, 2.0)])
    walls = np.concatenate([walls, walls[:, ::-1]])
    grid = Grid(width_px=720, height_px=120, fov_v_rad=math.radians(60.0), azimuth_col0_rad=math.pi)
    planar = depth_map(Reference(scan=Scan(walls), T_world_reference=Pose2(0.0, 0.0, 0.0)), grid, 1.2)
    assert planar is not None and planar.planar and planar.range_m.shape[0] == 1
    assert planar.range_at(np.array([0.0, 0.0]), np.array([-0.3, 0.3])) == pytest.approx([2.0, 2.0], abs=0.03)
    z = np.linspace(0.0, 2.4, 13)
    cloud = np.concatenate([np.column_stack([walls, np.full(len(walls), h)]) for h in z])
    from factorloc import PointCloud

    full = depth_map(Reference(cloud=PointCloud(cloud), T_world_reference=Pose2(0.0, 0.0, 0.0)), grid, 1.2)
    assert full is not None and not full.planar
    one_row = depth_map(Reference(cloud=PointCloud(cloud), T_world_reference=Pose2(0.0, 0.0, 0.0)), grid, 1.2, (1, 360))
    assert one_row is not None and not one_row.planar  # a cloud on a one-row grid is still a cloud

"""Faults: photometric formulas, blur, dropout, occluders and glass, checked against what they must do."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc import Pose2
from factorloc.errors import InputError
from factorloc.sim import (
    DepthCamera,
    apartment,
    depth_dropout,
    most_seen_face,
    motion_blur,
    place_occluders,
    relight,
    render_camera,
    render_cloud,
)


def test_relight_applies_gain_then_gamma() -> None:
    img = np.tile(np.arange(0, 256, 1, dtype=np.uint8)[None, :, None], (8, 1, 3))
    out = relight(img, gain=0.8, gamma=1.5)
    expected = np.round(255.0 * (0.8 * np.arange(256) / 255.0) ** 1.5)
    assert np.abs(out[0, :, 0].astype(float) - expected).max() <= 1.0


def test_relight_shadows_only_darken() -> None:
    rng = np.random.default_rng(0)
    img = np.full((120, 160, 3), 200, np.uint8)
    out = relight(img, shadows=2, rng=rng, shadow_strength=0.5)
    assert out.max() <= 200
    assert out.min() == pytest.approx(100, abs=2)  # 50 % darker inside a shadow
    assert 0.05 < np.mean(out < 190) < 0.8
    with pytest.raises(InputError, match="needs an rng"):
        relight(img, shadows=1)


def test_motion_blur_spreads_an_edge_over_its_length() -> None:
    img = np.zeros((40, 100, 3), np.uint8)
    img[:, 50:] = 255
    out = motion_blur(img, length_px=21, angle_rad=0.0)
    row = out[20, :, 0].astype(float)
    ramp = np.nonzero((row > 5) & (row < 250))[0]
    assert ramp.max() - ramp.min() + 1 == pytest.approx(21, abs=2)
    assert out[:, :, 0].mean() == pytest.approx(img[:, :, 0].mean(), rel=0.02)  # energy preserved
    vertical = motion_blur(img, length_px=21, angle_rad=math.pi / 2)
    assert np.array_equal(vertical[5:35], img[5:35])  # a vertical blur does not touch a vertical edge


def test_depth_dropout_removes_the_fraction_and_holes() -> None:
    rng = np.random.default_rng(1)
    az = rng.uniform(-0.5, 0.5, 20000)
    el = rng.uniform(-0.3, 0.3, 20000)
    pts = np.column_stack([2 * np.cos(az), 2 * np.sin(az), 1.0 + 2 * np.tan(el)])
    out = depth_dropout(pts, rng, random_fraction=0.2, n_holes=0)
    assert len(out) / len(pts) == pytest.approx(0.8, abs=0.02)
    holes = depth_dropout(pts, rng, random_fraction=0.0, n_holes=3, hole_radius_rad=0.1)
    assert 0.75 < len(holes) / len(pts) < 0.99


def test_occluders_stand_in_view_in_free_space_and_hide_the_wall() -> None:
    w = apartment()
    T = Pose2(2.6, 2.2, 0.2)
    occ = place_occluders(w, T, np.random.default_rng(3), n=2)
    assert len(occ) >= 1
    for o in occ:
        c = np.mean(o.vertices_xy, axis=0)
        bearing = math.atan2(c[1] - T.y, c[0] - T.x) - T.theta
        assert abs(bearing) <= math.radians(28.0) + 1e-9
        assert 0.9 <= math.dist(c, (T.x, T.y)) <= 2.5
        assert w.is_free(np.asarray(o.vertices_xy), 0.2).all()
    clean = render_cloud(w, T, DepthCamera(stride_px=4), None).points_m
    hidden = render_cloud(w, T, DepthCamera(stride_px=4), None, occluders=occ).points_m
    from matplotlib.path import Path as MplPath

    def on_occluders(pts: np.ndarray) -> np.ndarray:
        xy = T.transform_points(pts[:, :2])
        hit = np.zeros(len(pts), bool)
        for o in occ:  # within 1 mm of the occluder's outline, below its top
            grown = MplPath(np.asarray(o.vertices_xy)).contains_points(xy, radius=0.002)
            shrunk = MplPath(np.asarray(o.vertices_xy)).contains_points(xy, radius=-0.002)
            hit |= (grown ^ shrunk) & (pts[:, 2] <= o.height_m + 1e-6)
        return hit

    assert on_occluders(hidden).sum() > 50  # the depth camera sees the occluders' surfaces
    assert on_occluders(clean).sum() == 0
    img_clean = render_camera(w, T).image_bgr
    img_occ = render_camera(w, T, occluders=occ).image_bgr
    assert np.mean(np.any(img_clean != img_occ, axis=2)) > 0.05


def test_glass_face_returns_no_depth() -> None:
    w = apartment()
    T = Pose2(2.6, 2.2, math.pi)  # facing the living room's west wall
    face = most_seen_face(w, T)
    assert face is not None
    full = render_cloud(w, T, DepthCamera(stride_px=4), None)
    glass = render_cloud(w, T, DepthCamera(stride_px=4), None, glass_faces=[face])
    assert len(glass) < 0.7 * len(full)
    xy = T.transform_points(glass.points_m[:, :2])
    inner = (xy[:, 1] > 0.05) & (xy[:, 1] < 3.45)  # away from the corners with the neighbouring walls
    on_west_wall = (np.abs(xy[:, 0]) < 0.02) & inner & (glass.points_m[:, 2] > 0.05) & (glass.points_m[:, 2] < 2.45)
    assert on_west_wall.sum() == 0
    xy_full = T.transform_points(full.points_m[:, :2])
    assert ((np.abs(xy_full[:, 0]) < 0.02) & (full.points_m[:, 2] > 0.05)).sum() > 100  # it was there before

"""ICP covariance: Censi's formula is calibrated under white noise; geometry shapes it (corridor)."""

from __future__ import annotations

import math

import numpy as np

from factorloc.geometry import Pose2
from factorloc.registration.covariance import (
    bias_covariance,
    censi_bias_covariance,
    censi_covariance,
    chamfer_covariance,
    hessian_covariance,
    scale_heading,
)
from factorloc.registration.icp2d import IcpParams, align, prepare_target

TRUE = Pose2(0.3, 0.2, math.radians(10.0))


def test_censi_covariance_is_calibrated_on_white_noise(room_points: np.ndarray) -> None:
    """Mean NEES of (x, y) over 40 noisy trials is near 2 (χ² with 2 dof), and of (x, y, θ) near 3."""
    rng = np.random.default_rng(0)
    params = IcpParams(min_correspondence_m=0.1, sigma_point_m=0.01)
    nees2, nees3 = [], []
    for _ in range(40):
        tgt_pts = room_points[::3] + rng.normal(0, 0.01, room_points[::3].shape)
        src = TRUE.inverse().transform_points(room_points[1::3]) + rng.normal(0, 0.01, room_points[1::3].shape)
        res = align(prepare_target(tgt_pts, params), src, TRUE, params)
        cov = censi_covariance(res)
        e = res.T_target_source.as_array() - TRUE.as_array()
        nees2.append(e[:2] @ np.linalg.solve(cov[:2, :2], e[:2]))
        nees3.append(e @ np.linalg.solve(cov, e))
    assert 1.2 < np.mean(nees2) < 3.0
    assert 2.0 < np.mean(nees3) < 4.5


def test_corridor_covariance_is_long_along_the_corridor(corridor_points: np.ndarray) -> None:
    rng = np.random.default_rng(1)
    target = prepare_target(corridor_points)
    src = corridor_points[::2] + rng.normal(0, 0.005, corridor_points[::2].shape)
    res = align(target, src, Pose2(0.05, 0.02, 0.0))
    for cov in (censi_covariance(res), hessian_covariance(res), bias_covariance(res, 0.01)):
        lam, vec = np.linalg.eigh(cov[:2, :2])
        major = vec[:, 1]
        assert abs(major[0]) > 0.99  # the long axis is x, along the corridor
        assert math.sqrt(lam[1]) > 30.0 * math.sqrt(lam[0])
        assert math.sqrt(cov[0, 0]) > 1.0  # metres: x is not constrained at all
    iso = chamfer_covariance(res, 1.0)
    assert iso[0, 0] == iso[1, 1]  # the patent's Chamfer σ is blind to the geometry


def test_room_covariance_is_round_and_small(room_points: np.ndarray) -> None:
    rng = np.random.default_rng(2)
    target = prepare_target(room_points)
    src = room_points[::2] + rng.normal(0, 0.005, room_points[::2].shape)
    res = align(target, src, Pose2(0.02, 0.02, 0.01))
    s = np.sqrt(np.linalg.eigvalsh(censi_covariance(res)[:2, :2]))
    assert s[1] < 0.002
    assert s[1] < 3.0 * s[0]


def test_censi_bias_covariance_equals_its_two_terms_with_the_heading_scale(
    room_points: np.ndarray, corridor_points: np.ndarray
) -> None:
    """The compiled one-decomposition form (room: full rank) and its fallback (corridor: rank-deficient) both give
    ``scale · Σ_censi + D Σ_bias D``, ``D = diag(1, 1, k)``."""
    rng = np.random.default_rng(3)
    for pts in (room_points, corridor_points):
        src = pts[::2] + rng.normal(0, 0.005, pts[::2].shape)
        res = align(prepare_target(pts), src, Pose2(0.02, 0.02, 0.01))
        for k in (1.0, 0.85):
            got = censi_bias_covariance(res, 1.5, 0.004, heading_scale=k)
            want = 1.5 * censi_covariance(res) + scale_heading(bias_covariance(res, 0.004), k)
            np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-15)
        bias = bias_covariance(res, 0.004)
        d = scale_heading(bias, 0.5) - bias
        assert np.allclose(d[:2, :2], 0.0) and d[2, 2] == -0.75 * bias[2, 2] and d[0, 2] == -0.5 * bias[0, 2]

"""ICP covariance: Censi's formula is calibrated under white noise; geometry shapes it (corridor)."""

from __future__ import annotations

import math

import numpy as np

from factorloc.geometry import Pose2
from factorloc.registration.covariance import bias_covariance, censi_covariance, chamfer_covariance, hessian_covariance
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

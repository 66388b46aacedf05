"""Point-to-line ICP: accuracy on a synthetic room, agreement with Open3D, input checks."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.registration.icp2d import IcpParams, align, prepare_target
from factorloc.registration.kernels import Cauchy
from factorloc.registration.open3d_peer import open3d_icp

TRUE = Pose2(0.6, -0.4, math.radians(25.0))


def _query(room: np.ndarray, rng: np.random.Generator, sigma_m: float = 0.005) -> np.ndarray:
    """The room seen from TRUE (query frame), every 2nd point, with Gaussian noise."""
    pts = TRUE.inverse().transform_points(room[::2])
    return pts + rng.normal(0.0, sigma_m, pts.shape)


def test_align_recovers_the_true_pose_from_an_offset_seed(room_points: np.ndarray) -> None:
    target = prepare_target(room_points)
    src = _query(room_points, np.random.default_rng(0))
    seed = Pose2(TRUE.x + 0.15, TRUE.y - 0.10, TRUE.theta + math.radians(4.0))
    res = align(target, src, seed, IcpParams(min_correspondence_m=0.1), Cauchy(0.05))
    err = TRUE.between(res.T_target_source)
    assert math.hypot(err.x, err.y) < 0.002
    assert abs(math.degrees(err.theta)) < 0.05
    assert res.converged
    assert res.fitness > 0.99
    assert res.rmse_m < 0.008


def test_align_agrees_with_open3d_point_to_plane_on_the_same_pair(room_points: np.ndarray) -> None:
    target = prepare_target(room_points)
    src = _query(room_points, np.random.default_rng(1))
    seed = Pose2(TRUE.x - 0.05, TRUE.y + 0.05, TRUE.theta - math.radians(2.0))
    ours = align(target, src, seed).T_target_source
    peer = open3d_icp(room_points, src, seed, method="point_to_plane", target_normals=target.normals).T_target_source
    d = ours.between(peer)
    assert math.hypot(d.x, d.y) < 0.003
    assert abs(math.degrees(d.theta)) < 0.1


def test_align_reports_no_fit_when_the_scans_do_not_overlap(room_points: np.ndarray) -> None:
    target = prepare_target(room_points)
    far = room_points[::4] + np.array([100.0, 100.0])
    res = align(target, far, Pose2())
    assert res.fitness == 0.0
    assert res.n_inliers < 3
    assert not res.converged


def test_align_rejects_malformed_input(room_points: np.ndarray) -> None:
    target = prepare_target(room_points)
    with pytest.raises(InputError, match="N×2"):
        align(target, np.zeros((10, 3)), Pose2())
    with pytest.raises(InputError, match=">= 3 points"):
        align(target, np.zeros((2, 2)), Pose2())
    with pytest.raises(InputError, match="min_correspondence_m"):
        IcpParams(min_correspondence_m=2.0, max_correspondence_m=1.0)

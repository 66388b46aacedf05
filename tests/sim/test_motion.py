"""Trajectories and the odometry drift model."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc import Pose2
from factorloc.errors import InputError
from factorloc.geometry import wrap_angle
from factorloc.sim import (
    DriftModel,
    apartment,
    path_length_m,
    path_rotation_rad,
    random_walk,
    sample_free_pose,
    simulate_odometry,
    waypoint_trajectory,
)


def test_waypoints_are_visited_with_bounded_steps() -> None:
    traj = waypoint_trajectory([Pose2(1, 1, 0), (3, 1), Pose2(3, 3, math.pi)], step_m=0.05, step_rad=0.05)
    assert np.allclose(traj[0], [1, 1, 0])
    assert np.allclose(traj[-1], [3, 3, -math.pi]) or np.allclose(traj[-1], [3, 3, math.pi])
    assert any(np.allclose(p[:2], [3, 1]) for p in traj)
    assert path_length_m(traj) == pytest.approx(4.0)
    assert path_rotation_rad(traj) == pytest.approx(math.pi)  # +90° at (3, 1), +90° at (3, 3)
    steps = np.hypot(np.diff(traj[:, 0]), np.diff(traj[:, 1]))
    assert steps.max() <= 0.05 + 1e-12
    assert np.abs(wrap_angle(np.diff(traj[:, 2]))).max() <= 0.05 + 1e-12


def test_random_walk_has_the_requested_length_and_stays_in_free_space() -> None:
    w = apartment()
    rng = np.random.default_rng(1)
    traj = random_walk(w, Pose2(2.6, 2.2, 0.0), 12.0, rng, clearance_m=0.35)
    assert path_length_m(traj) == pytest.approx(12.0)
    assert w.is_free(traj[:, :2], 0.35 - 1e-9).all()
    # it cannot have crossed a wall: consecutive positions see each other
    assert w.line_of_sight(traj[:-1, :2], traj[1:, :2]).all()


def test_random_walk_refuses_a_start_inside_a_wall() -> None:
    with pytest.raises(InputError, match="closer than clearance_m"):
        random_walk(apartment(), Pose2(0.1, 2.0, 0.0), 1.0, np.random.default_rng(0))


def test_sample_free_pose_is_free() -> None:
    w = apartment()
    rng = np.random.default_rng(4)
    poses = [sample_free_pose(w, rng, 0.4) for _ in range(20)]
    assert w.is_free(np.array([[p.x, p.y] for p in poses]), 0.4).all()


def test_error_free_odometry_is_the_truth_with_growing_sigma() -> None:
    traj = waypoint_trajectory([Pose2(1, 4.1, 0), (9, 4.1)])  # 8 m straight down the corridor
    run = simulate_odometry(traj, None)
    assert np.allclose(run.poses, traj, atol=1e-9)
    sx = np.sqrt(run.covariances[:, 0, 0])  # along the path: the 5 % scale error
    assert sx[-1] == pytest.approx(0.05 * 8.0, rel=0.05)
    i_half = int(np.argmin(np.abs(run.distance_m - 4.0)))
    assert sx[i_half] == pytest.approx(0.05 * 4.0, rel=0.05)
    st = np.sqrt(run.covariances[:, 2, 2])
    assert st[-1] == pytest.approx(0.02 * 8.0, rel=0.05)  # heading drift 0.02 rad/m
    odo = run.odometry(model=DriftModel())
    assert odo.sigma_x_m == pytest.approx(sx[-1])


def test_odometry_sigma_is_honest_nees_close_to_three() -> None:
    """Over many drift draws the true odometry error is consistent with the reported covariance."""
    w = apartment()
    traj = random_walk(w, Pose2(2.6, 2.2, 0.3), 4.0, np.random.default_rng(2), step_m=0.1)
    rng = np.random.default_rng(3)
    nees = []
    for _ in range(300):
        run = simulate_odometry(traj, rng)
        e = run.poses[-1] - traj[-1]
        e[2] = wrap_angle(e[2])
        nees.append(e @ np.linalg.solve(run.covariances[-1], e))
    assert np.mean(nees) == pytest.approx(3.0, abs=0.35)
    assert np.mean(np.array(nees) > 11.34) < 0.03  # χ²₃ 99 % quantile


def test_drift_grows_with_distance() -> None:
    traj = waypoint_trajectory([Pose2(0.5, 4.1, 0), (9.5, 4.1)], step_m=0.1)
    rng = np.random.default_rng(0)
    err = []
    for _ in range(200):
        run = simulate_odometry(traj, rng)
        err.append(np.hypot(*(run.poses[:, :2] - traj[:, :2]).T))
    rms = np.sqrt(np.mean(np.square(err), axis=0))
    i3, i9 = (int(np.argmin(np.abs(run.distance_m - d))) for d in (3.0, 9.0))
    assert rms[i9] / rms[i3] > 2.5  # roughly proportional to the distance (≥ 3× for 3× the distance)
    assert 0.03 * 9.0 < rms[i9] < 0.15 * 9.0  # the order of the patent's 5 %

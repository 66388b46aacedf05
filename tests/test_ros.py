"""ROS-shaped outputs against hand computations: the 6×6 PoseWithCovariance layout and map → odom."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.ros import UNOBSERVED_VARIANCE, map_to_odom, pose_covariance_6x6, quaternion_from_yaw, transform_fields


def test_covariance_goes_to_x_y_yaw_of_the_row_major_6x6() -> None:
    cov = np.array([[0.04, 0.01, 0.002], [0.01, 0.09, -0.003], [0.002, -0.003, 0.0025]])
    c = pose_covariance_6x6(cov)
    assert len(c) == 36
    # by hand: row-major index 6·row + col, yaw is index 5
    assert c[0] == 0.04 and c[1] == 0.01 and c[5] == 0.002
    assert c[6] == 0.01 and c[7] == 0.09 and c[11] == -0.003
    assert c[30] == 0.002 and c[31] == -0.003 and c[35] == 0.0025
    assert c[14] == c[21] == c[28] == UNOBSERVED_VARIANCE  # z, roll, pitch
    assert sum(v != 0 for v in c) == 9 + 3


def test_an_undetermined_component_gets_the_large_variance_and_no_correlation() -> None:
    cov = np.diag([0.01, 0.01, math.inf])
    c = np.array(pose_covariance_6x6(cov)).reshape(6, 6)
    assert c[5, 5] == UNOBSERVED_VARIANCE and c[0, 5] == 0.0 and c[0, 0] == 0.01
    with pytest.raises(InputError, match="3×3"):
        pose_covariance_6x6(np.eye(2))


def test_quaternion_of_a_yaw() -> None:
    assert quaternion_from_yaw(math.pi / 2) == pytest.approx((0.0, 0.0, math.sqrt(0.5), math.sqrt(0.5)))
    assert quaternion_from_yaw(0.0) == (0.0, 0.0, 0.0, 1.0)


def test_map_to_odom_by_hand() -> None:
    # the robot is at (2, 1) facing +y in the map; the odometry says (1, 0) facing +x
    T_map_robot = Pose2(2.0, 1.0, math.pi / 2)
    T_odom_robot = Pose2(1.0, 0.0, 0.0)
    T = map_to_odom(T_map_robot, T_odom_robot)
    # T_map_odom = T_map_robot · T_odom_robot⁻¹: rotation π/2, translation (2, 1) + R(π/2)·(−1, 0) = (2, 0)
    assert (T.x, T.y, T.theta) == pytest.approx((2.0, 0.0, math.pi / 2))
    # and the chain map → odom → robot gives the fused pose back
    back = T.compose(T_odom_robot)
    assert (back.x, back.y, back.theta) == pytest.approx((2.0, 1.0, math.pi / 2))
    (tx, ty, tz), q = transform_fields(T)
    assert (tx, ty, tz) == pytest.approx((2.0, 0.0, 0.0)) and q == pytest.approx(quaternion_from_yaw(math.pi / 2))


def test_the_example_node_compiles(repo_root: Path) -> None:
    """rclpy is not on PyPI: the node is not run in CI, but its source must at least compile."""
    src = (repo_root / "examples" / "ros2_node.py").read_text(encoding="utf-8")
    compile(src, "ros2_node.py", "exec")
    assert "pose_covariance_6x6" in src and "map_to_odom" in src

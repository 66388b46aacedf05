"""ROS-shaped outputs of a planar pose, for a thin ROS node (no ROS import here: plain numbers and tuples).

* :func:`pose_covariance_6x6`: a 3×3 planar covariance (x, y, θ; world frame) as the 36 row-major numbers of
  ``geometry_msgs/PoseWithCovariance.covariance`` (order x, y, z, roll, pitch, yaw; REP-103). The axes a planar
  localizer does not observe (z, roll, pitch), and a planar component it left undetermined (variance ``inf``), get
  :data:`UNOBSERVED_VARIANCE` (10⁶ m² or rad², the "very large" value robot_localization's documentation suggests
  for a variable one does not measure) and no correlation with the others.
* :func:`quaternion_from_yaw`: ``(x, y, z, w)`` of a rotation about z.
* :func:`map_to_odom`: the ``map → odom`` transform a localizer publishes (REP-105):
  ``T_map_odom = T_map_robot · T_odom_robot⁻¹`` — from the fused pose in the map and the odometry's pose of the
  same instant, so that ``map → odom → base_link`` puts the robot where the localizer says.

``examples/ros2_node.py`` wraps these in an rclpy node (rclpy is not on PyPI: the example is not run in CI).
"""

from __future__ import annotations

import math

import numpy as np

from factorloc.errors import InputError
from factorloc.geometry import Pose2

__all__ = ["UNOBSERVED_VARIANCE", "map_to_odom", "pose_covariance_6x6", "quaternion_from_yaw", "transform_fields"]

#: Variance (m², rad²) given to an axis the planar localizer does not observe (z, roll, pitch) or left undetermined.
UNOBSERVED_VARIANCE = 1.0e6

#: Where x, y, θ go in the 6×6 (x, y, z, roll, pitch, yaw).
_INDEX = (0, 1, 5)


def pose_covariance_6x6(covariance: np.ndarray, unobserved_variance: float = UNOBSERVED_VARIANCE) -> list[float]:
    """The 36 row-major numbers of ``PoseWithCovariance.covariance`` from a 3×3 (x, y, θ) covariance.

    ``covariance`` is m², rad² in the frame of the pose's parent (the map / world frame), which is the frame ROS
    expresses a ``PoseWithCovarianceStamped`` covariance in. A component whose variance is not finite is
    undetermined: it gets ``unobserved_variance`` and its correlations are zeroed.
    """
    cov = np.asarray(covariance, dtype=np.float64)
    if cov.shape != (3, 3):
        raise InputError(f"covariance must be 3×3 (x, y, θ), got shape {cov.shape}")
    if not (math.isfinite(unobserved_variance) and unobserved_variance > 0):
        raise InputError(f"unobserved_variance must be a finite number > 0, got {unobserved_variance!r}")
    out = np.zeros((6, 6))
    out[2, 2] = out[3, 3] = out[4, 4] = unobserved_variance
    known = [i for i in range(3) if math.isfinite(cov[i, i])]
    for i in range(3):
        for j in range(3):
            a, b = _INDEX[i], _INDEX[j]
            if i in known and j in known:
                out[a, b] = cov[i, j]
            elif i == j:
                out[a, b] = unobserved_variance
    if not np.all(np.isfinite(out)):
        raise InputError(f"covariance has a non-finite correlation between determined components: {cov.tolist()}")
    return [float(v) for v in out.ravel()]


def quaternion_from_yaw(yaw_rad: float) -> tuple[float, float, float, float]:
    """``(x, y, z, w)`` of the rotation by ``yaw_rad`` about z (w ≥ 0 for |yaw| ≤ π)."""
    half = 0.5 * float(yaw_rad)
    return (0.0, 0.0, math.sin(half), math.cos(half))


def map_to_odom(T_map_robot: Pose2, T_odom_robot: Pose2) -> Pose2:
    """``T_map_odom = T_map_robot · T_odom_robot⁻¹`` (REP-105's ``map → odom``), both poses of the same instant."""
    if not isinstance(T_map_robot, Pose2) or not isinstance(T_odom_robot, Pose2):
        raise InputError("map_to_odom needs two Pose2 (the fused pose in the map, the odometry's pose)")
    return T_map_robot.compose(T_odom_robot.inverse())


def transform_fields(T: Pose2) -> tuple[tuple[float, float, float], tuple[float, float, float, float]]:
    """``(translation (x, y, 0), rotation (qx, qy, qz, qw))`` of a planar transform, as ``geometry_msgs/Transform``."""
    return (T.x, T.y, 0.0), quaternion_from_yaw(T.theta)

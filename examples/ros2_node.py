"""A thin ROS 2 node around factorloc's tracker: laser scans and odometry in, a pose with covariance and the
``map → odom`` transform out.

NOT RUN IN CI: rclpy is not on PyPI (it comes with a ROS 2 installation), so this file is only compiled by the
test suite (``tests/test_ros.py``). Everything it computes comes from library functions that are tested:
:class:`factorloc.places.Tracker` (the pose), :func:`factorloc.ros.pose_covariance_6x6` (the 36-number covariance,
x, y, z, roll, pitch, yaw, unobserved axes 10⁶) and :func:`factorloc.ros.map_to_odom` (REP-105).

Run (in a sourced ROS 2 workspace, with factorloc installed in the same Python)::

    python examples/ros2_node.py --ros-args -p map:=/path/to/map-of-places

Topics: subscribes ``/scan`` (sensor_msgs/LaserScan, laser frame = base_link) and ``/odom`` (nav_msgs/Odometry);
publishes ``/factorloc/pose`` (geometry_msgs/PoseWithCovarianceStamped, frame ``map``) and the TF ``map → odom``.
The tracker's state (tracking / relocalized / lost) is logged; a LOST result is not published.
"""

from __future__ import annotations

import math

import rclpy  # not on PyPI: a ROS 2 installation provides it
from geometry_msgs.msg import PoseWithCovarianceStamped, TransformStamped
from nav_msgs.msg import Odometry as OdometryMsg
from rclpy.node import Node
from sensor_msgs.msg import LaserScan
from tf2_ros import TransformBroadcaster

from factorloc import Odometry, Pose2, Query
from factorloc.datasets.rosbag import laser_ranges_to_scan
from factorloc.places import PlaceMap, Tracker, TrackerConfig, TrackState
from factorloc.ros import map_to_odom, pose_covariance_6x6, quaternion_from_yaw, transform_fields


def _yaw(q) -> float:  # noqa: ANN001 - a geometry_msgs Quaternion
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


class FactorlocNode(Node):
    def __init__(self) -> None:
        super().__init__("factorloc")
        self.declare_parameter("map", "")
        path = self.get_parameter("map").get_parameter_value().string_value
        self.tracker = Tracker(PlaceMap.load(path), TrackerConfig())
        self.odom: Pose2 | None = None
        self.pub = self.create_publisher(PoseWithCovarianceStamped, "/factorloc/pose", 10)
        self.tf = TransformBroadcaster(self)
        self.create_subscription(OdometryMsg, "/odom", self.on_odom, 50)
        self.create_subscription(LaserScan, "/scan", self.on_scan, 10)

    def on_odom(self, msg: OdometryMsg) -> None:
        p = msg.pose.pose
        self.odom = Pose2(p.position.x, p.position.y, _yaw(p.orientation))

    def on_scan(self, msg: LaserScan) -> None:
        if self.odom is None:
            return
        odom = self.odom  # the latest odometry (a real node would interpolate at msg.header.stamp)
        scan = laser_ranges_to_scan(msg.ranges, msg.angle_min, msg.angle_increment, msg.range_min, msg.range_max)
        result = self.tracker.update(Query(scan=scan, odometry=Odometry(odom, 0.1, 0.1, 0.1)))
        self.get_logger().info(f"{result.state.value}: places {list(result.places_used)}")
        if result.state is TrackState.LOST:
            return
        out = PoseWithCovarianceStamped()
        out.header.stamp = msg.header.stamp
        out.header.frame_id = "map"
        out.pose.pose.position.x, out.pose.pose.position.y = result.pose.x, result.pose.y
        q = quaternion_from_yaw(result.pose.theta)
        o = out.pose.pose.orientation
        o.x, o.y, o.z, o.w = q
        out.pose.covariance = pose_covariance_6x6(result.covariance)
        self.pub.publish(out)
        (tx, ty, tz), (qx, qy, qz, qw) = transform_fields(map_to_odom(result.pose, odom))
        tf = TransformStamped()
        tf.header.stamp = msg.header.stamp
        tf.header.frame_id, tf.child_frame_id = "map", "odom"
        tf.transform.translation.x, tf.transform.translation.y, tf.transform.translation.z = tx, ty, tz
        r = tf.transform.rotation
        r.x, r.y, r.z, r.w = qx, qy, qz, qw
        self.tf.sendTransform(tf)


def main() -> None:
    rclpy.init()
    node = FactorlocNode()
    try:
        rclpy.spin(node)
    finally:
        node.destroy_node()
        rclpy.shutdown()


if __name__ == "__main__":
    main()

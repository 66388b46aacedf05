"""Writing small ROS 1 bags for the conversion tests (rosbags' writer, ROS 1 Noetic types).

:class:`BagMaker` records odometry, TF, camera images (raw or JPEG) with their
``CameraInfo``, point clouds in a sensor's optical frame and laser scans; the
tests then convert the bag and compare with the truth they wrote.
"""

from __future__ import annotations

import math
from pathlib import Path

import cv2
import numpy as np
from rosbags.rosbag1 import Writer
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

from factorloc.datasets.bag.frames import Rigid3
from factorloc.geometry import Pose2

TS = get_typestore(Stores.ROS1_NOETIC)
TS.register(get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage"))
T = TS.types

#: ``T_link_optical`` of REP-103: the optical frame (z forward, x right, y down) in a body frame (x forward, z up).
OPTICAL = Rigid3(np.array([[0.0, 0.0, 1.0], [-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]]), np.zeros(3))


def _time(t_s: float):
    sec = int(math.floor(t_s))
    return T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int(round((t_s - sec) * 1e9)) % 1_000_000_000)


def _header(t_s: float, frame: str):
    return T["std_msgs/msg/Header"](seq=0, stamp=_time(t_s), frame_id=frame)


def _transform(parent: str, child: str, Tr: Rigid3, t_s: float):
    q = Tr.quaternion
    return T["geometry_msgs/msg/TransformStamped"](
        header=_header(t_s, parent),
        child_frame_id=child,
        transform=T["geometry_msgs/msg/Transform"](
            translation=T["geometry_msgs/msg/Vector3"](x=Tr.t[0], y=Tr.t[1], z=Tr.t[2]),
            rotation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        ),
    )


class BagMaker:
    """A ROS 1 bag being written; times are seconds (``t0_s`` added), the bag time equals the header stamp."""

    def __init__(self, path: Path, t0_s: float = 1000.0) -> None:
        self.path = Path(path)
        self.t0 = t0_s
        self._w = Writer(self.path)
        self._w.open()
        self._conns: dict[str, object] = {}

    def _write(self, topic: str, msgtype: str, msg: object, t_s: float) -> None:
        if topic not in self._conns:
            self._conns[topic] = self._w.add_connection(topic, msgtype, typestore=TS)
        self._w.write(self._conns[topic], int(round((self.t0 + t_s) * 1e9)), TS.serialize_ros1(msg, msgtype))

    def close(self) -> Path:
        self._w.close()
        return self.path

    def static_tf(self, edges: dict[tuple[str, str], Rigid3]) -> None:
        msg = T["tf2_msgs/msg/TFMessage"](transforms=[_transform(p, c, Tr, self.t0) for (p, c), Tr in edges.items()])
        self._write("/tf_static", "tf2_msgs/msg/TFMessage", msg, 0.0)

    def tf(self, parent: str, child: str, Tr: Rigid3, t_s: float) -> None:
        msg = T["tf2_msgs/msg/TFMessage"](transforms=[_transform(parent, child, Tr, self.t0 + t_s)])
        self._write("/tf", "tf2_msgs/msg/TFMessage", msg, t_s)

    def odometry(self, pose: Pose2, t_s: float, topic: str = "/odom", child: str = "base_link") -> None:
        q = Rigid3.from_pose2(pose).quaternion
        P = T["geometry_msgs/msg/Pose"](
            position=T["geometry_msgs/msg/Point"](x=pose.x, y=pose.y, z=0.0),
            orientation=T["geometry_msgs/msg/Quaternion"](x=q[0], y=q[1], z=q[2], w=q[3]),
        )
        zero = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
        msg = T["nav_msgs/msg/Odometry"](
            header=_header(self.t0 + t_s, "odom"),
            child_frame_id=child,
            pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=P, covariance=np.zeros(36)),
            twist=T["geometry_msgs/msg/TwistWithCovariance"](
                twist=T["geometry_msgs/msg/Twist"](linear=zero, angular=zero), covariance=np.zeros(36)
            ),
        )
        self._write(topic, "nav_msgs/msg/Odometry", msg, t_s)

    def camera_info(self, topic: str, frame: str, width: int, height: int, K: np.ndarray, D=(0.0,) * 5, t_s: float = 0.0) -> None:
        roi = T["sensor_msgs/msg/RegionOfInterest"](x_offset=0, y_offset=0, height=0, width=0, do_rectify=False)
        P = np.zeros(12)
        P[[0, 1, 2, 4, 5, 6, 10]] = [K[0, 0], 0, K[0, 2], 0, K[1, 1], K[1, 2], 1]
        msg = T["sensor_msgs/msg/CameraInfo"](
            header=_header(self.t0 + t_s, frame),
            height=height,
            width=width,
            distortion_model="plumb_bob",
            D=np.asarray(D, dtype=np.float64),
            K=np.asarray(K, dtype=np.float64).reshape(9),
            R=np.eye(3).reshape(9),
            P=P,
            binning_x=0,
            binning_y=0,
            roi=roi,
        )
        self._write(topic, "sensor_msgs/msg/CameraInfo", msg, t_s)

    def image(self, topic: str, frame: str, bgr: np.ndarray, t_s: float, encoding: str = "bgr8") -> None:
        data = bgr[:, :, ::-1] if encoding == "rgb8" else bgr
        h, w = bgr.shape[:2]
        msg = T["sensor_msgs/msg/Image"](
            header=_header(self.t0 + t_s, frame),
            height=h,
            width=w,
            encoding=encoding,
            is_bigendian=0,
            step=w * 3,
            data=np.ascontiguousarray(data).reshape(-1),
        )
        self._write(topic, "sensor_msgs/msg/Image", msg, t_s)

    def compressed_image(self, topic: str, frame: str, bgr: np.ndarray, t_s: float, quality: int = 95) -> None:
        ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, quality])
        assert ok
        msg = T["sensor_msgs/msg/CompressedImage"](
            header=_header(self.t0 + t_s, frame), format="bgr8; jpeg compressed bgr8", data=buf.reshape(-1)
        )
        self._write(topic, "sensor_msgs/msg/CompressedImage", msg, t_s)

    def cloud(self, topic: str, frame: str, points: np.ndarray, t_s: float) -> None:
        pts = np.ascontiguousarray(points, dtype=np.float32)
        F = T["sensor_msgs/msg/PointField"]
        fields = [F(name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")]
        msg = T["sensor_msgs/msg/PointCloud2"](
            header=_header(self.t0 + t_s, frame),
            height=1,
            width=len(pts),
            fields=fields,
            is_bigendian=False,
            point_step=12,
            row_step=12 * len(pts),
            data=pts.view(np.uint8).reshape(-1),
            is_dense=True,
        )
        self._write(topic, "sensor_msgs/msg/PointCloud2", msg, t_s)

    def scan(self, topic: str, frame: str, ranges: np.ndarray, angle_min: float, angle_inc: float, t_s: float) -> None:
        msg = T["sensor_msgs/msg/LaserScan"](
            header=_header(self.t0 + t_s, frame),
            angle_min=angle_min,
            angle_max=angle_min + angle_inc * (len(ranges) - 1),
            angle_increment=angle_inc,
            time_increment=0.0,
            scan_time=0.0,
            range_min=0.05,
            range_max=30.0,
            ranges=np.asarray(ranges, dtype=np.float32),
            intensities=np.zeros(0, dtype=np.float32),
        )
        self._write(topic, "sensor_msgs/msg/LaserScan", msg, t_s)


def ideal_K(width: int, height: int, hfov_rad: float) -> np.ndarray:
    """The camera matrix of factorloc's pinhole model: f = (W/2)/tan(hfov/2), principal point at the centre."""
    f = 0.5 * width / math.tan(0.5 * hfov_rad)
    return np.array([[f, 0.0, (width - 1) / 2.0], [0.0, f, (height - 1) / 2.0], [0.0, 0.0, 1.0]])

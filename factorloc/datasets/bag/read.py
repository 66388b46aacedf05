"""Reading a robot's bag for conversion: which topics hold what, and the messages' times.

A bag is read in two passes. :func:`read_bag_index` reads, in one pass over the
chosen topics, everything small — the odometry, the TF tree, the cameras'
``CameraInfo``, the laser scans — and only the time stamps and frames of the large
messages (point clouds, images). Once the conversion has chosen the times it needs,
:func:`read_messages` deserializes just those messages. Both accept whatever
``rosbags`` reads: ROS 1 ``.bag`` files, ROS 2 bag directories (sqlite3 or MCAP storage).

Topics are found by message type when not named (:func:`resolve_topics`): the bag's only
``nav_msgs/Odometry``, ``sensor_msgs/LaserScan`` and ``sensor_msgs/PointCloud2`` topics,
and every ``sensor_msgs/Image`` / ``CompressedImage`` topic holding colour images.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from factorloc.datasets.bag.frames import Rigid3, TransformTree
from factorloc.datasets.bag.images import CameraIntrinsics, is_colour_encoding
from factorloc.datasets.rosbag import OdometryTrack, laser_ranges_to_scan, message_stamp_s, open_bag
from factorloc.errors import DatasetError

_log = logging.getLogger(__name__)

__all__ = [
    "BagData",
    "BagTopic",
    "SensorTopics",
    "StampIndex",
    "bag_topics",
    "read_bag_index",
    "read_messages",
    "resolve_topics",
]

ODOMETRY = "nav_msgs/msg/Odometry"
LASER_SCAN = "sensor_msgs/msg/LaserScan"
POINT_CLOUD2 = "sensor_msgs/msg/PointCloud2"
IMAGE = "sensor_msgs/msg/Image"
COMPRESSED_IMAGE = "sensor_msgs/msg/CompressedImage"
CAMERA_INFO = "sensor_msgs/msg/CameraInfo"
TF = "tf2_msgs/msg/TFMessage"


@dataclass(frozen=True)
class BagTopic:
    """One topic of a bag: its name, message type (ROS 2 spelling, ``pkg/msg/Type``) and message count."""

    topic: str
    msgtype: str
    count: int


def _opened(path: str | Path) -> Any:
    reader = open_bag(path)
    try:
        reader.open()
    except Exception as exc:  # rosbags raises its own hierarchy
        raise DatasetError(f"cannot read bag {path}: {exc}") from exc
    return reader


def bag_topics(path: str | Path) -> tuple[BagTopic, ...]:
    """The topics of a bag, sorted by name."""
    reader = _opened(path)
    try:
        out: dict[str, BagTopic] = {}
        for c in reader.connections:
            prev = out.get(c.topic)
            out[c.topic] = BagTopic(c.topic, c.msgtype, (prev.count if prev else 0) + int(c.msgcount))
        return tuple(out[t] for t in sorted(out))
    finally:
        reader.close()


@dataclass(frozen=True)
class SensorTopics:
    """The topics a conversion reads (see :func:`resolve_topics`); ``None`` = that sensor is absent."""

    odometry: str
    scan: str | None = None
    cloud: str | None = None
    cameras: tuple[str, ...] = ()
    camera_infos: Mapping[str, str] = field(default_factory=dict)


def _only(topics: Sequence[BagTopic], msgtype: str, what: str, option: str, prefer: str | None = None) -> str | None:
    found = [t.topic for t in topics if t.msgtype == msgtype]
    if not found:
        return None
    if len(found) == 1:
        return found[0]
    if prefer in found:
        return prefer
    raise DatasetError(f"the bag has {len(found)} {what} topics {found}: name the one to use with {option}")


def _named(topics: Sequence[BagTopic], topic: str, msgtypes: tuple[str, ...], option: str) -> str:
    by = {t.topic: t for t in topics}
    if topic not in by:
        raise DatasetError(f"the bag has no topic {topic!r} ({option}); topics are {sorted(by)}")
    if by[topic].msgtype not in msgtypes:
        raise DatasetError(f"topic {topic!r} ({option}) has type {by[topic].msgtype}, expected {' or '.join(msgtypes)}")
    return topic


def _camera_info_topic(image_topic: str, available: set[str]) -> str | None:
    base = image_topic[: -len("/compressed")] if image_topic.endswith("/compressed") else image_topic
    parent = base.rsplit("/", 1)[0]
    for cand in (f"{parent}/camera_info", f"{base}/camera_info"):
        if cand in available:
            return cand
    return None


def resolve_topics(
    topics: Sequence[BagTopic],
    *,
    odometry: str | None = None,
    scan: str | None = None,
    cloud: str | None = None,
    cameras: Sequence[str] | None = None,
) -> SensorTopics:
    """Choose the topics to convert. ``None`` means "find it by type"; ``""`` (or ``()`` for cameras) means "none".

    Cameras found by type: every ``Image`` and ``CompressedImage`` topic, except the
    compressed twin ``X/compressed`` of a raw topic ``X`` and topics named ``…depth…``
    (non-colour encodings are dropped later, when the first message is read). Each camera's
    ``CameraInfo`` is the sibling topic ``…/camera_info``.

    Raises
    ------
    DatasetError
        When the odometry is missing, a named topic is absent or of the wrong type, or
        several topics of one kind exist and none is named.
    """
    names = {t.topic for t in topics}
    if odometry is None:
        odom = _only(topics, ODOMETRY, "nav_msgs/Odometry", "--odometry-topic", prefer="/odom")
        if odom is None:
            raise DatasetError(f"the bag has no nav_msgs/Odometry topic; topics are {sorted(names)}")
    else:
        odom = _named(topics, odometry, (ODOMETRY,), "--odometry-topic")
    sc = _only(topics, LASER_SCAN, "sensor_msgs/LaserScan", "--scan-topic", "/scan") if scan is None else scan or None
    if sc is not None and scan:
        sc = _named(topics, sc, (LASER_SCAN,), "--scan-topic")
    cl = _only(topics, POINT_CLOUD2, "sensor_msgs/PointCloud2", "--cloud-topic") if cloud is None else cloud or None
    if cl is not None and cloud:
        cl = _named(topics, cl, (POINT_CLOUD2,), "--cloud-topic")
    if cameras is None:
        cams = [t.topic for t in topics if t.msgtype in (IMAGE, COMPRESSED_IMAGE) and "depth" not in t.topic.lower()]
        cams = [c for c in cams if not (c.endswith("/compressed") and c[: -len("/compressed")] in cams)]
    else:
        cams = [_named(topics, c, (IMAGE, COMPRESSED_IMAGE), "--camera-topic") for c in cameras]
    infos = {c: i for c in cams if (i := _camera_info_topic(c, names)) is not None}
    return SensorTopics(odom, sc, cl, tuple(cams), infos)


@dataclass(frozen=True, eq=False)
class StampIndex:
    """The messages of one sensor topic, without their payload: (N,) header times (s), bag times (ns), frames."""

    topic: str
    stamps_s: np.ndarray
    bag_times_ns: np.ndarray
    frame_ids: tuple[str, ...]

    def __len__(self) -> int:
        return int(self.stamps_s.shape[0])

    def nearest(self, t_s: float, tolerance_s: float) -> int | None:
        """Index of the message stamped nearest to ``t_s``, or None when none is within ``tolerance_s``."""
        ts = self.stamps_s
        if len(ts) == 0:
            return None
        i = int(np.searchsorted(ts, t_s))
        cands = [j for j in (i - 1, i) if 0 <= j < len(ts)]
        j = min(cands, key=lambda k: (abs(ts[k] - t_s), k))
        return j if abs(ts[j] - t_s) <= tolerance_s else None

    def within(self, t0_s: float, t1_s: float) -> np.ndarray:
        """Indices of the messages stamped in ``[t0_s, t1_s]``."""
        return np.flatnonzero((self.stamps_s >= t0_s) & (self.stamps_s <= t1_s))


def _index(topic: str, rows: list[tuple[float, int, str]]) -> StampIndex:
    rows.sort(key=lambda r: (r[0], r[1]))
    return StampIndex(
        topic,
        np.array([r[0] for r in rows], dtype=np.float64),
        np.array([r[1] for r in rows], dtype=np.int64),
        tuple(r[2] for r in rows),
    )


@dataclass(frozen=True, eq=False)
class LaserScans:
    """The laser scans of a bag in their own frame (N scans as (M, 2) arrays, laser frame x forward, y left)."""

    index: StampIndex
    points_m: tuple[np.ndarray, ...]


@dataclass(frozen=True, eq=False)
class BagData:
    """What the first pass over a bag found (see :func:`read_bag_index`).

    ``odometry`` is ``T_odom_robot`` of the odometry's child frame ``odometry_frame``;
    ``tf`` the bag's transform tree; ``scans`` the laser scans in their frame (or None);
    ``clouds`` and ``cameras`` the stamp indexes of the point clouds and of each colour
    camera topic; ``intrinsics`` each camera's first ``CameraInfo``; ``skipped`` the camera
    topics left out and why.
    """

    path: str
    topics: SensorTopics
    odometry: OdometryTrack
    odometry_frame: str
    tf: TransformTree
    scans: LaserScans | None
    clouds: StampIndex | None
    cameras: Mapping[str, StampIndex]
    intrinsics: Mapping[str, CameraIntrinsics]
    skipped: Mapping[str, str]


def _yaw(q: Any) -> float:
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))


def read_bag_index(path: str | Path, topics: SensorTopics, *, max_range_m: float | None = None) -> BagData:
    """One pass over the bag: odometry, TF, camera intrinsics, laser scans, and the stamps of clouds and images.

    Raises
    ------
    DatasetError
        When the odometry topic holds no message.
    """
    reader = _opened(path)
    tree = TransformTree()
    odom: list[tuple[float, float, float, float]] = []
    odom_frame = ""
    scan_rows: list[tuple[float, int, str]] = []
    scan_pts: list[np.ndarray] = []
    cloud_rows: list[tuple[float, int, str]] = []
    cam_rows: dict[str, list[tuple[float, int, str]]] = {c: [] for c in topics.cameras}
    intrinsics: dict[str, CameraIntrinsics] = {}
    skipped: dict[str, str] = {}
    info_of = {i: c for c, i in topics.camera_infos.items()}
    wanted = {topics.odometry, topics.scan, topics.cloud, *topics.cameras, *info_of}
    try:
        conns = [c for c in reader.connections if c.topic in wanted or c.msgtype == TF]
        for con, t_ns, raw in reader.messages(connections=conns):
            topic = con.topic
            if topic in skipped:
                continue
            msg = reader.deserialize(raw, con.msgtype)
            if con.msgtype == TF:
                static = topic.endswith("tf_static")
                for tr in msg.transforms:
                    v, q = tr.transform.translation, tr.transform.rotation
                    T = Rigid3.from_quaternion((v.x, v.y, v.z), (q.x, q.y, q.z, q.w))
                    tree.add(tr.header.frame_id, tr.child_frame_id, T, None if static else message_stamp_s(tr, t_ns))
            elif topic == topics.odometry:
                p = msg.pose.pose
                odom.append((message_stamp_s(msg, t_ns), p.position.x, p.position.y, _yaw(p.orientation)))
                odom_frame = odom_frame or str(msg.child_frame_id).lstrip("/")
            elif topic == topics.scan:
                rmax = float(msg.range_max) if msg.range_max > 0 else math.inf
                if max_range_m is not None:
                    rmax = min(rmax, float(max_range_m))
                s = laser_ranges_to_scan(msg.ranges, float(msg.angle_min), float(msg.angle_increment), float(msg.range_min), rmax)
                scan_rows.append((message_stamp_s(msg, t_ns), t_ns, msg.header.frame_id))
                scan_pts.append(s.points_m)
            elif topic == topics.cloud:
                cloud_rows.append((message_stamp_s(msg, t_ns), t_ns, msg.header.frame_id))
            elif topic in cam_rows:
                if con.msgtype == IMAGE and not is_colour_encoding(msg.encoding):
                    skipped[topic] = f"encoding {msg.encoding!r} is not a colour image"
                    continue
                if con.msgtype == COMPRESSED_IMAGE and "depth" in str(msg.format).lower():
                    skipped[topic] = f"format {msg.format!r} is a depth image"
                    continue
                cam_rows[topic].append((message_stamp_s(msg, t_ns), t_ns, msg.header.frame_id))
            elif topic in info_of and info_of[topic] not in intrinsics:
                intrinsics[info_of[topic]] = CameraIntrinsics.from_camera_info(msg)
    finally:
        reader.close()
    if not odom:
        raise DatasetError(f"topic {topics.odometry!r} of {path} holds no odometry message")
    a = np.array(odom)
    scans = None
    if scan_rows:
        order = sorted(range(len(scan_rows)), key=lambda i: (scan_rows[i][0], scan_rows[i][1], i))
        idx = _index(topics.scan or "", [scan_rows[i] for i in order])
        scans = LaserScans(idx, tuple(scan_pts[i] for i in order))
    cameras = {c: _index(c, rows) for c, rows in cam_rows.items() if c not in skipped and rows}
    for c, reason in skipped.items():
        _log.info("camera topic %s left out: %s", c, reason)
    return BagData(
        str(path),
        topics,
        OdometryTrack(a[:, 0], a[:, 1:]),
        odom_frame,
        tree.freeze(),
        scans,
        _index(topics.cloud, cloud_rows) if cloud_rows and topics.cloud else None,
        cameras,
        intrinsics,
        skipped,
    )


def read_messages(path: str | Path, wanted: Mapping[str, Iterable[int]]) -> dict[tuple[str, int], Any]:
    """Deserialize the messages ``{topic: bag times (ns)}``; returns ``{(topic, bag time): message}``."""
    need = {topic: set(int(t) for t in times) for topic, times in wanted.items()}
    need = {k: v for k, v in need.items() if v}
    out: dict[tuple[str, int], Any] = {}
    if not need:
        return out
    reader = _opened(path)
    try:
        conns = [c for c in reader.connections if c.topic in need]
        lo = min(min(v) for v in need.values())
        hi = max(max(v) for v in need.values())
        for con, t_ns, raw in reader.messages(connections=conns, start=lo, stop=hi + 1):
            if t_ns in need[con.topic] and (con.topic, t_ns) not in out:
                out[(con.topic, t_ns)] = reader.deserialize(raw, con.msgtype)
    finally:
        reader.close()
    return out

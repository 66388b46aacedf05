"""Read ROS 1 and ROS 2 bags without a ROS installation (pure-Python ``rosbags``).

Three message kinds are understood:

* ``nav_msgs/Odometry`` → an :class:`OdometryTrack` (time-stamped planar poses,
  the yaw extracted from the quaternion);
* ``sensor_msgs/LaserScan`` → a :class:`ScanTrack` of :class:`~factorloc.types.Scan`
  (points in the laser frame, x forward, y left, metres; returns outside
  ``[range_min, range_max)`` are dropped);
* ``sensor_msgs/PointCloud2`` → :class:`~factorloc.types.PointCloud` (the ``x``,
  ``y``, ``z`` fields, NaN points dropped).

:func:`read_laser_log` bundles the odometry and the scans of one bag in a
:class:`LaserLog`, the input of the relations benchmark
(:mod:`factorloc.evaluation.relations`). The CARMEN text reader
(:mod:`factorloc.datasets.carmen`) returns the same types.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from factorloc.errors import DatasetError, InputError
from factorloc.geometry import Pose2, wrap_angle
from factorloc.types import PointCloud, Scan

_log = logging.getLogger(__name__)

__all__ = [
    "LaserLog",
    "OdometryTrack",
    "ScanTrack",
    "laser_ranges_to_scan",
    "message_stamp_s",
    "open_bag",
    "pointcloud2_to_cloud",
    "read_laser_log",
    "read_odometry",
    "read_point_clouds",
    "read_scans",
]


# --------------------------------------------------------------------------
# Value types
# --------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class OdometryTrack:
    """Time-stamped planar odometry poses ``T_odom_robot``.

    Parameters
    ----------
    stamps_s
        (N,) strictly increasing times in seconds.
    poses
        (N, 3) ``[x_m, y_m, theta_rad]`` of the robot in the odometry frame.
    """

    stamps_s: np.ndarray
    poses: np.ndarray

    def __post_init__(self) -> None:
        t = np.array(self.stamps_s, dtype=np.float64).ravel()
        p = np.array(self.poses, dtype=np.float64)
        if p.ndim != 2 or p.shape[1] != 3 or p.shape[0] != t.shape[0]:
            raise InputError(f"OdometryTrack.poses must have shape N×3 with N = len(stamps_s) = {t.shape[0]}, got {p.shape}")
        if t.shape[0] < 1:
            raise InputError("OdometryTrack needs at least one pose, got 0")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(p))):
            raise InputError("OdometryTrack contains NaN or infinite stamps or poses")
        if np.any(np.diff(t) < 0):
            order = np.argsort(t, kind="stable")
            t, p = t[order], p[order]
        p[:, 2] = wrap_angle(p[:, 2])
        # cumulative path length and absolute rotation, for distance_between()
        step = np.hypot(np.diff(p[:, 0]), np.diff(p[:, 1]))
        turn = np.abs(wrap_angle(np.diff(p[:, 2]))) if len(t) > 1 else np.zeros(0)
        cum_d = np.concatenate([[0.0], np.cumsum(step)])
        cum_r = np.concatenate([[0.0], np.cumsum(turn)])
        for arr in (t, p, cum_d, cum_r):
            arr.setflags(write=False)
        object.__setattr__(self, "stamps_s", t)
        object.__setattr__(self, "poses", p)
        object.__setattr__(self, "_cum_distance_m", cum_d)
        object.__setattr__(self, "_cum_rotation_rad", cum_r)

    def __len__(self) -> int:
        return int(self.stamps_s.shape[0])

    def _check_time(self, t_s: float) -> float:
        t = float(t_s)
        lo, hi = self.stamps_s[0], self.stamps_s[-1]
        # allow 1 s of extrapolation slack at both ends (scans and odometry are not synchronous)
        if not (lo - 1.0 <= t <= hi + 1.0):
            raise InputError(f"time {t!r} s is outside the odometry track [{lo!r}, {hi!r}] s")
        return t

    def pose_at(self, t_s: float) -> Pose2:
        """``T_odom_robot`` at time ``t_s``, linearly interpolated (θ along the shorter arc)."""
        t = self._check_time(t_s)
        ts = self.stamps_s
        i = int(np.clip(np.searchsorted(ts, t), 1, len(ts) - 1)) if len(ts) > 1 else 0
        if len(ts) == 1:
            return Pose2.from_array(self.poses[0])
        t0, t1 = ts[i - 1], ts[i]
        a = 0.0 if t1 == t0 else float(np.clip((t - t0) / (t1 - t0), 0.0, 1.0))
        p0, p1 = self.poses[i - 1], self.poses[i]
        dth = wrap_angle(p1[2] - p0[2])
        return Pose2(p0[0] + a * (p1[0] - p0[0]), p0[1] + a * (p1[1] - p0[1]), p0[2] + a * dth)

    def between(self, t1_s: float, t2_s: float) -> Pose2:
        """The odometry's relative motion ``T_robot(t1)_robot(t2) = odom(t1)⁻¹ · odom(t2)``."""
        return self.pose_at(t1_s).between(self.pose_at(t2_s))

    def gap_s(self, t_s: float) -> float:
        """Time (s) from ``t_s`` to the nearest pose of the track (how far :meth:`pose_at` interpolates from data)."""
        ts = self.stamps_s
        i = int(np.searchsorted(ts, t_s))
        near = [abs(ts[j] - t_s) for j in (i - 1, i) if 0 <= j < len(ts)]
        return float(min(near))

    def bracket_s(self, t_s: float) -> float:
        """Length (s) of the interval between the two poses around ``t_s`` (0 at a pose, inf outside the track)."""
        ts = self.stamps_s
        i = int(np.searchsorted(ts, t_s))
        if i < len(ts) and ts[i] == t_s:
            return 0.0
        if i == 0 or i >= len(ts):
            return math.inf
        return float(ts[i] - ts[i - 1])

    def path_length_m(self, t_s: float | np.ndarray) -> float | np.ndarray:
        """Path length (m) travelled from the first pose to ``t_s`` (clamped to the track's span)."""
        out = np.interp(t_s, self.stamps_s, self._cum_distance_m)  # type: ignore[attr-defined]
        return float(out) if np.ndim(out) == 0 else out

    def distance_between(self, t1_s: float, t2_s: float) -> tuple[float, float]:
        """Path length (m) and summed absolute rotation (rad) travelled between two times."""
        a, b = sorted((self._check_time(t1_s), self._check_time(t2_s)))
        d = np.interp([a, b], self.stamps_s, self._cum_distance_m)  # type: ignore[attr-defined]
        r = np.interp([a, b], self.stamps_s, self._cum_rotation_rad)  # type: ignore[attr-defined]
        return float(d[1] - d[0]), float(r[1] - r[0])


@dataclass(frozen=True, eq=False)
class ScanTrack:
    """Time-stamped 2D scans (laser frame = robot frame unless transformed).

    ``stamps_s`` is (N,) seconds, ``scans`` the N :class:`~factorloc.types.Scan`.
    """

    stamps_s: np.ndarray
    scans: tuple[Scan, ...]
    frame_id: str = ""

    def __post_init__(self) -> None:
        t = np.array(self.stamps_s, dtype=np.float64).ravel()
        scans = tuple(self.scans)
        if t.shape[0] != len(scans):
            raise InputError(f"ScanTrack: {t.shape[0]} stamps for {len(scans)} scans")
        for i, s in enumerate(scans):
            if not isinstance(s, Scan):
                raise InputError(f"ScanTrack.scans[{i}] must be a Scan, got {type(s).__name__}")
        if np.any(np.diff(t) < 0):
            order = np.argsort(t, kind="stable")
            t = t[order]
            scans = tuple(scans[i] for i in order)
        t.setflags(write=False)
        object.__setattr__(self, "stamps_s", t)
        object.__setattr__(self, "scans", scans)

    def __len__(self) -> int:
        return len(self.scans)

    def index_at(self, t_s: float, tolerance_s: float = 1e-3) -> int:
        """Index of the scan stamped within ``tolerance_s`` of ``t_s``; raises when there is none."""
        ts = self.stamps_s
        if len(ts) == 0:
            raise InputError("ScanTrack is empty")
        i = int(np.clip(np.searchsorted(ts, t_s), 0, len(ts) - 1))
        cands = [j for j in (i - 1, i) if 0 <= j < len(ts)]
        j = min(cands, key=lambda k: abs(ts[k] - t_s))
        if abs(ts[j] - t_s) > tolerance_s:
            raise InputError(f"no scan within {tolerance_s} s of t = {t_s!r} s (nearest at {ts[j]!r} s)")
        return j

    def at(self, t_s: float, tolerance_s: float = 1e-3) -> Scan:
        """The scan stamped within ``tolerance_s`` of ``t_s``."""
        return self.scans[self.index_at(t_s, tolerance_s)]


@dataclass(frozen=True, eq=False)
class LaserLog:
    """A 2D laser log: odometry and scans of one robot run (laser frame = robot frame)."""

    odometry: OdometryTrack
    scans: ScanTrack
    source: str = ""


# --------------------------------------------------------------------------
# Message conversions
# --------------------------------------------------------------------------
def laser_ranges_to_scan(
    ranges_m: Sequence[float] | np.ndarray,
    angle_min_rad: float,
    angle_increment_rad: float,
    range_min_m: float = 0.0,
    range_max_m: float = math.inf,
    *,
    T_robot_laser: Pose2 | None = None,
) -> Scan:
    """Convert a polar laser scan to a :class:`~factorloc.types.Scan`.

    Beam ``i`` looks along ``angle_min_rad + i·angle_increment_rad`` (laser
    frame, counter-clockwise from x forward); its point is
    ``r·(cos a, sin a)``. Returns that are NaN/inf, below ``range_min_m`` or at
    or beyond ``range_max_m`` (the "no return" convention of ROS and CARMEN)
    are dropped. ``T_robot_laser`` maps the points to the robot frame.

    Raises
    ------
    InputError
        When ``ranges_m`` is not 1-D or the angles are not finite.
    """
    r = np.asarray(ranges_m, dtype=np.float64)
    if r.ndim != 1:
        raise InputError(f"ranges_m must be 1-D, got shape {r.shape}")
    if not (math.isfinite(angle_min_rad) and math.isfinite(angle_increment_rad)):
        raise InputError(f"angle_min_rad/angle_increment_rad must be finite, got {angle_min_rad!r}, {angle_increment_rad!r}")
    a = angle_min_rad + angle_increment_rad * np.arange(r.shape[0])
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(r) & (r >= range_min_m) & (r < range_max_m) & (r > 0.0)
    pts = np.column_stack([r[ok] * np.cos(a[ok]), r[ok] * np.sin(a[ok])])
    if T_robot_laser is not None:
        pts = T_robot_laser.transform_points(pts)
    return Scan(pts.reshape(-1, 2))


_PC2_DTYPES = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def pointcloud2_to_cloud(msg: Any) -> PointCloud:
    """Convert a deserialized ``sensor_msgs/PointCloud2`` to a :class:`~factorloc.types.PointCloud`.

    Reads the ``x``, ``y``, ``z`` fields at their offsets and datatypes
    (any endianness, any ``point_step``/``row_step``) and drops points with a
    NaN or infinite coordinate. Frame: the message's frame (assumed to be the robot frame).
    """
    fields = {f.name: f for f in msg.fields}
    missing = [n for n in ("x", "y", "z") if n not in fields]
    if missing:
        raise InputError(f"PointCloud2 has no field(s) {missing}; fields are {sorted(fields)}")
    endian = ">" if msg.is_bigendian else "<"
    names, formats, offsets = [], [], []
    for n in ("x", "y", "z"):
        f = fields[n]
        if f.datatype not in _PC2_DTYPES:
            raise InputError(f"PointCloud2 field {n!r} has unknown datatype {f.datatype}")
        names.append(n)
        formats.append(endian + _PC2_DTYPES[f.datatype])
        offsets.append(f.offset)
    dtype = np.dtype({"names": names, "formats": formats, "offsets": offsets, "itemsize": int(msg.point_step)})
    data = np.asarray(msg.data, dtype=np.uint8)
    height, width = int(msg.height), int(msg.width)
    row_step = int(msg.row_step) if msg.row_step else width * int(msg.point_step)
    rows = []
    for row in range(height):
        chunk = data[row * row_step : row * row_step + width * int(msg.point_step)]
        rows.append(np.frombuffer(chunk.tobytes(), dtype=dtype, count=width))
    arr = np.concatenate(rows) if rows else np.zeros(0, dtype=dtype)
    xyz = np.column_stack([arr["x"], arr["y"], arr["z"]]).astype(np.float64)
    xyz = xyz[np.all(np.isfinite(xyz), axis=1)]
    return PointCloud(xyz.reshape(-1, 3))


def _yaw_from_quaternion(x: float, y: float, z: float, w: float) -> float:
    return math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def message_stamp_s(msg: Any, bag_time_ns: int) -> float:
    """A message's time (s): its header stamp, or the bag's receive time when the stamp is 0 or absent."""
    header = getattr(msg, "header", None)
    if header is not None:
        st = header.stamp
        t = float(st.sec) + 1e-9 * float(st.nanosec)
        if t > 0.0:
            return t
    return 1e-9 * float(bag_time_ns)


# --------------------------------------------------------------------------
# Readers
# --------------------------------------------------------------------------
def open_bag(path: str | Path):  # noqa: ANN201 - rosbags.highlevel.AnyReader
    """A (not yet opened) ``rosbags`` reader of a ROS 1 ``.bag``, a ROS 2 bag directory or an MCAP bag.

    Raises
    ------
    DatasetError
        When the path does not exist or rosbags cannot read it.
    """
    from rosbags.highlevel import AnyReader

    p = Path(path)
    if not p.exists():
        raise DatasetError(f"bag not found: {p}")
    try:
        return AnyReader([p])
    except Exception as exc:  # rosbags raises its own hierarchy
        raise DatasetError(f"cannot open bag {p}: {exc}") from exc


_open = open_bag


def _messages(path: str | Path, topic: str, msgtypes: tuple[str, ...]) -> Iterator[tuple[Any, int]]:
    reader = _open(path)
    try:
        reader.open()
    except Exception as exc:
        raise DatasetError(f"cannot read bag {path}: {exc}") from exc
    try:
        conns = [c for c in reader.connections if c.topic == topic]
        if not conns:
            topics = sorted({c.topic for c in reader.connections})
            raise DatasetError(f"bag {path} has no topic {topic!r}; topics are {topics}")
        bad = [c.msgtype for c in conns if c.msgtype not in msgtypes]
        if bad:
            raise DatasetError(f"topic {topic!r} in {path} has type {bad[0]}, expected one of {msgtypes}")
        for con, t_ns, raw in reader.messages(connections=conns):
            yield reader.deserialize(raw, con.msgtype), t_ns
    finally:
        reader.close()


def read_odometry(path: str | Path, topic: str = "/odom") -> OdometryTrack:
    """Read ``nav_msgs/Odometry`` messages of ``topic`` as a planar :class:`OdometryTrack`.

    Stamps come from the message headers (the bag time when a header stamp is 0).
    """
    stamps, poses = [], []
    for msg, t_ns in _messages(path, topic, ("nav_msgs/msg/Odometry",)):
        p = msg.pose.pose
        q = p.orientation
        stamps.append(message_stamp_s(msg, t_ns))
        poses.append((p.position.x, p.position.y, _yaw_from_quaternion(q.x, q.y, q.z, q.w)))
    if not stamps:
        raise DatasetError(f"topic {topic!r} of {path} holds no odometry message")
    return OdometryTrack(np.array(stamps), np.array(poses))


def read_scans(
    path: str | Path,
    topic: str = "/scan",
    *,
    T_robot_laser: Pose2 | None = None,
    max_range_m: float | None = None,
) -> ScanTrack:
    """Read ``sensor_msgs/LaserScan`` messages of ``topic`` as a :class:`ScanTrack`.

    Returns beyond ``min(range_max, max_range_m)`` are dropped (see
    :func:`laser_ranges_to_scan`); ``T_robot_laser`` maps points to the robot frame.
    """
    stamps, scans, frame = [], [], ""
    for msg, t_ns in _messages(path, topic, ("sensor_msgs/msg/LaserScan",)):
        rmax = float(msg.range_max) if msg.range_max > 0 else math.inf
        if max_range_m is not None:
            rmax = min(rmax, float(max_range_m))
        scans.append(
            laser_ranges_to_scan(
                msg.ranges,
                float(msg.angle_min),
                float(msg.angle_increment),
                float(msg.range_min),
                rmax,
                T_robot_laser=T_robot_laser,
            )
        )
        stamps.append(message_stamp_s(msg, t_ns))
        frame = msg.header.frame_id
    if not scans:
        raise DatasetError(f"topic {topic!r} of {path} holds no LaserScan message")
    return ScanTrack(np.array(stamps), tuple(scans), frame)


def read_point_clouds(path: str | Path, topic: str) -> tuple[np.ndarray, tuple[PointCloud, ...]]:
    """Read ``sensor_msgs/PointCloud2`` messages of ``topic``: (N,) stamps in s and N clouds."""
    stamps, clouds = [], []
    for msg, t_ns in _messages(path, topic, ("sensor_msgs/msg/PointCloud2",)):
        stamps.append(message_stamp_s(msg, t_ns))
        clouds.append(pointcloud2_to_cloud(msg))
    if not clouds:
        raise DatasetError(f"topic {topic!r} of {path} holds no PointCloud2 message")
    return np.array(stamps), tuple(clouds)


def read_laser_log(
    path: str | Path,
    scan_topic: str = "/scan",
    odom_topic: str = "/odom",
    *,
    T_robot_laser: Pose2 | None = None,
    max_range_m: float | None = None,
) -> LaserLog:
    """Read the odometry and the laser scans of one bag (ROS 1 ``.bag`` or a ROS 2 bag directory)."""
    odom = read_odometry(path, odom_topic)
    scans = read_scans(path, scan_topic, T_robot_laser=T_robot_laser, max_range_m=max_range_m)
    _log.info("read %d odometry poses and %d scans from %s", len(odom), len(scans), path)
    return LaserLog(odom, scans, str(path))

"""The sensors of a bag at a given time, in the robot frame: scans, clouds, camera views, references.

:func:`open_bag_sensors` reads a bag's index (:mod:`factorloc.datasets.bag.read`) and
returns a :class:`BagSensors`, which assembles what the robot sensed around a time
``t`` (a *keyframe*), everything moved into the robot frame at ``t``:

* the sensor's extrinsics ``T_robot_sensor`` come from the bag's TF tree (static, or
  interpolated at the message's time when a joint moves, e.g. a pan head), or from
  ``SensorConfig.extrinsics`` given by the user;
* a message joins a keyframe when it is stamped within ``sync_tolerance_s`` of it, and the
  robot's motion between the two stamps (odometry) is compensated: points are moved,
  a camera's yaw is turned;
* a reference (:meth:`BagSensors.reference`) gathers the clouds and the camera views of the
  time the robot stood on the spot and stitches the views into a panorama.

:func:`factorloc.datasets.bag.convert.convert_bag` builds a scenario with it; a tracker
reading a bag query by query can use it directly (:meth:`BagSensors.load` first, with the
messages it will need).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from types import MappingProxyType
from typing import Any

import numpy as np

from factorloc._validate import nonnegative_float, positive_float
from factorloc.datasets.bag.frames import Rigid3
from factorloc.datasets.bag.images import CameraIntrinsics, camera_image, compressed_image_to_bgr, image_to_bgr
from factorloc.datasets.bag.read import COMPRESSED_IMAGE, BagData, bag_topics, read_bag_index, read_messages, resolve_topics
from factorloc.datasets.rosbag import OdometryTrack, pointcloud2_to_cloud
from factorloc.errors import DatasetError, InputError
from factorloc.geometry import Pose2, wrap_angle
from factorloc.types import CameraImage, PointCloud, Reference, Scan

__all__ = ["BagSensors", "SensorConfig", "open_bag_sensors"]


@dataclass(frozen=True)
class SensorConfig:
    """Which topics and frames to read, and how sensors join a keyframe.

    Parameters
    ----------
    odometry_topic, scan_topic, cloud_topic
        ``None``: the bag's only topic of that type; ``""``: none (scan, cloud).
    camera_topics
        ``None``: every colour ``Image``/``CompressedImage`` topic; ``()``: none.
    robot_frame
        The frame the sensors are moved into (default: the odometry's ``child_frame_id``).
        Its origin should be on the floor: clouds are expected "z up from the floor".
    extrinsics
        ``{frame: T_robot_frame}`` given by the user; they win over the bag's TF.
    sync_tolerance_s
        Largest time (s) between a keyframe and a message of another sensor that joins it, and
        between a keyframe and the odometry message it is extrapolated from.
    max_odometry_gap_s
        A keyframe between two odometry messages at most this far apart (s) gets the pose
        interpolated between them (odometry is often slower than the sensors).
    max_range_m
        Laser returns beyond this are dropped (default: each scan's ``range_max``).
    hfov_rad
        Horizontal field of view of cameras without ``CameraInfo`` (rad); without it such a camera is an error.
    cloud_voxel_m
        Keep one point per cube of this side (m) in every cloud (None: all points).
    stationary_radius_m, reference_window_s
        A reference gathers the clouds and camera views taken while the robot stayed within
        ``stationary_radius_m`` of its position at the reference time, at most
        ``reference_window_s`` before or after.
    panorama_width_px
        Columns of the stitched reference panoramas (over 360°).
    panorama_fov_v_rad
        Their vertical field of view (rad; default: the band all views cover).
    """

    odometry_topic: str | None = None
    scan_topic: str | None = None
    cloud_topic: str | None = None
    camera_topics: tuple[str, ...] | None = None
    robot_frame: str | None = None
    extrinsics: Mapping[str, Rigid3] = field(default_factory=dict)
    sync_tolerance_s: float = 0.05
    max_odometry_gap_s: float = 1.0
    max_range_m: float | None = None
    hfov_rad: float | None = None
    cloud_voxel_m: float | None = None
    stationary_radius_m: float = 0.05
    reference_window_s: float = 60.0
    panorama_width_px: int = 2048
    panorama_fov_v_rad: float | None = None

    def __post_init__(self) -> None:
        positive_float("SensorConfig.sync_tolerance_s", self.sync_tolerance_s)
        nonnegative_float("SensorConfig.max_odometry_gap_s", self.max_odometry_gap_s)
        nonnegative_float("SensorConfig.stationary_radius_m", self.stationary_radius_m)
        nonnegative_float("SensorConfig.reference_window_s", self.reference_window_s)
        for name in ("max_range_m", "hfov_rad", "cloud_voxel_m"):
            if getattr(self, name) is not None:
                positive_float(f"SensorConfig.{name}", getattr(self, name))
        for frame, T in self.extrinsics.items():
            if not isinstance(T, Rigid3):
                raise InputError(f"SensorConfig.extrinsics[{frame!r}] must be a Rigid3 (T_robot_frame), got {type(T).__name__}")
        object.__setattr__(self, "extrinsics", MappingProxyType(dict(self.extrinsics)))
        if self.camera_topics is not None:
            object.__setattr__(self, "camera_topics", tuple(self.camera_topics))


class BagSensors:
    """A bag's sensors in the robot frame (see the module docstring). Build it with :func:`open_bag_sensors`.

    ``data`` is the bag's index (odometry ``T_odom_robot`` in the robot frame, TF tree, stamps);
    ``robot_frame`` the frame everything is moved into; ``used_frames`` the extrinsics
    ``T_robot_frame`` looked up so far (a record for the conversion report).
    """

    def __init__(self, data: BagData, config: SensorConfig, robot_frame: str) -> None:
        self.data = data
        self.config = config
        self.robot_frame = robot_frame
        self.tol = config.sync_tolerance_s
        self.used_frames: dict[str, Rigid3] = {}
        self.notes: list[str] = []
        self._messages: dict[tuple[str, int], Any] = {}

    @property
    def odometry(self) -> OdometryTrack:
        return self.data.odometry

    # --- messages ------------------------------------------------------------------
    def load(self, wanted: Mapping[str, Iterable[int]]) -> None:
        """Deserialize the cloud and image messages ``{topic: bag times (ns)}`` the next calls will use."""
        self._messages.update(read_messages(self.data.path, wanted))

    def wanted_near(self, t_s: float) -> dict[str, set[int]]:
        """The cloud and image messages (``{topic: bag times}``) a keyframe at ``t_s`` uses."""
        out: dict[str, set[int]] = {}
        for idx in ([self.data.clouds] if self.data.clouds is not None else []) + list(self.data.cameras.values()):
            j = idx.nearest(t_s, self.tol)
            if j is not None:
                out.setdefault(idx.topic, set()).add(int(idx.bag_times_ns[j]))
        return out

    def wanted_within(self, window: tuple[float, float]) -> dict[str, set[int]]:
        """The cloud and image messages stamped in ``window`` (a reference's stay on the spot)."""
        out: dict[str, set[int]] = {}
        for idx in ([self.data.clouds] if self.data.clouds is not None else []) + list(self.data.cameras.values()):
            out.setdefault(idx.topic, set()).update(int(idx.bag_times_ns[i]) for i in idx.within(*window))
        return out

    # --- frames --------------------------------------------------------------------
    def extrinsic(self, frame: str, t_s: float) -> Rigid3:
        """``T_robot_frame`` at ``t_s``.

        Raises
        ------
        DatasetError
            When the TF tree does not connect ``frame`` to the robot frame (give ``SensorConfig.extrinsics``).
        """
        frame = frame.lstrip("/") or self.robot_frame
        tree = self.data.tf
        if frame == self.robot_frame:
            T = Rigid3()
        elif tree.depends_on_time(self.robot_frame, frame):
            T = tree.lookup(self.robot_frame, frame, t_s, tolerance_s=self.tol)
        else:
            T = self.used_frames.get(frame) or tree.lookup(self.robot_frame, frame)
        self.used_frames.setdefault(frame, T)
        return T

    def motion(self, t_key_s: float, t_sensor_s: float) -> Pose2:
        """``T_robot(t_key)_robot(t_sensor)`` by odometry."""
        return self.odometry.pose_at(t_key_s).between(self.odometry.pose_at(t_sensor_s))

    # --- sensors -------------------------------------------------------------------
    def scan(self, t_key_s: float) -> Scan | None:
        """The laser scan stamped nearest ``t_key_s`` within the tolerance, in the robot frame at ``t_key_s``."""
        scans = self.data.scans
        i = None if scans is None else scans.index.nearest(t_key_s, self.tol)
        if i is None or len(scans.points_m[i]) == 0:  # type: ignore[union-attr]
            return None
        t = float(scans.index.stamps_s[i])  # type: ignore[union-attr]
        pts = scans.points_m[i]  # type: ignore[union-attr]
        T = self.extrinsic(scans.index.frame_ids[i], t)  # type: ignore[union-attr]
        xy = T.apply(np.column_stack([pts, np.zeros(len(pts))]))[:, :2]
        return Scan(self.motion(t_key_s, t).transform_points(xy))

    def cloud(self, indices: Sequence[int], t_key_s: float) -> PointCloud | None:
        """The clouds ``indices`` (of ``data.clouds``), merged in the robot frame at ``t_key_s``; None when empty."""
        idx = self.data.clouds
        if idx is None:
            return None
        parts = []
        for i in indices:
            msg = self._messages.get((idx.topic, int(idx.bag_times_ns[i])))
            if msg is None:
                continue
            try:
                pts = pointcloud2_to_cloud(msg).points_m
            except InputError:  # every point NaN: nothing to keep
                continue
            t = float(idx.stamps_s[i])
            p = self.extrinsic(idx.frame_ids[i], t).apply(pts)
            parts.append(np.column_stack([self.motion(t_key_s, t).transform_points(p[:, :2]), p[:, 2]]))
        if not parts:
            return None
        pts = np.vstack(parts)
        v = self.config.cloud_voxel_m
        if v:
            _, first = np.unique(np.floor(pts / v).astype(np.int64), axis=0, return_index=True)
            pts = pts[np.sort(first)]
        return PointCloud(pts)

    def cloud_near(self, t_key_s: float) -> PointCloud | None:
        """The cloud stamped nearest ``t_key_s`` within the tolerance."""
        j = None if self.data.clouds is None else self.data.clouds.nearest(t_key_s, self.tol)
        return None if j is None else self.cloud([j], t_key_s)

    def camera(self, topic: str, i: int, t_key_s: float) -> CameraImage | None:
        """Image ``i`` of camera ``topic`` as a :class:`~factorloc.CameraImage` of the robot at ``t_key_s``.

        Raises
        ------
        DatasetError
            When the camera has no ``CameraInfo`` and ``SensorConfig.hfov_rad`` is not given.
        """
        idx = self.data.cameras[topic]
        msg = self._messages.get((topic, int(idx.bag_times_ns[i])))
        if msg is None:
            return None
        bgr = compressed_image_to_bgr(msg) if getattr(msg, "__msgtype__", "") == COMPRESSED_IMAGE else image_to_bgr(msg)
        intr = self.data.intrinsics.get(topic)
        if intr is None:
            if self.config.hfov_rad is None:
                raise DatasetError(f"camera topic {topic!r} has no CameraInfo beside it: give its horizontal field of view")
            intr = CameraIntrinsics.from_hfov(bgr.shape[1], bgr.shape[0], self.config.hfov_rad)
        t = float(idx.stamps_s[i])
        cam = camera_image(bgr, intr, self.extrinsic(idx.frame_ids[i], t), idx.frame_ids[i])
        turn = float(wrap_angle(self.odometry.pose_at(t).theta - self.odometry.pose_at(t_key_s).theta))
        if turn == 0.0:
            return cam
        return CameraImage(cam.image_bgr, cam.hfov_rad, cam.yaw_in_robot_rad + turn, cam.pitch_rad, cam.cx_px)

    def images_near(self, t_key_s: float) -> tuple[CameraImage, ...]:
        """One view per camera: the image stamped nearest ``t_key_s`` within the tolerance."""
        out = []
        for topic, idx in self.data.cameras.items():
            j = idx.nearest(t_key_s, self.tol)
            cam = None if j is None else self.camera(topic, j, t_key_s)
            if cam is not None:
                out.append(cam)
        return tuple(out)

    # --- references ------------------------------------------------------------------
    def stationary_window(self, t_s: float) -> tuple[float, float]:
        """The time around ``t_s`` the robot stayed within ``stationary_radius_m`` of where it was then (s, s)."""
        odo = self.odometry
        ts, p = odo.stamps_s, odo.poses
        c = odo.pose_at(t_s)
        far = np.hypot(p[:, 0] - c.x, p[:, 1] - c.y) > self.config.stationary_radius_m
        w = self.config.reference_window_s
        before = np.flatnonzero(far & (ts <= t_s))
        after = np.flatnonzero(far & (ts >= t_s))
        lo = ts[before[-1]] if before.size else -math.inf
        hi = ts[after[0]] if after.size else math.inf
        return max(float(lo), t_s - w), min(float(hi), t_s + w)

    def reference(self, t_s: float, T_world_reference: Pose2, name: str) -> Reference:
        """The reference at ``t_s``: its scan, the clouds of its stay on the spot, a panorama stitched from its views.

        Raises
        ------
        DatasetError
            When it would hold no scan, no cloud and no panorama.
        """
        from factorloc.vision.panoramas import panorama_from_images

        window = self.stationary_window(t_s)
        scan = self.scan(t_s)
        cloud = None
        if self.data.clouds is not None:
            stay = self.data.clouds.within(*window)
            cloud = self.cloud(list(stay), t_s) if len(stay) else self.cloud_near(t_s)
        views, yaws = [], []
        heading = self.odometry.pose_at(t_s).theta
        for topic, idx in self.data.cameras.items():
            for i in idx.within(*window):
                t = float(idx.stamps_s[i])
                cam = self.camera(topic, int(i), t)
                if cam is not None:
                    views.append(cam)
                    yaws.append(float(wrap_angle(self.odometry.pose_at(t).theta - heading)))
        panorama = None
        if views:
            try:
                panorama = panorama_from_images(
                    views, yaws, width_px=self.config.panorama_width_px, fov_v_rad=self.config.panorama_fov_v_rad
                )
            except InputError as exc:
                self.notes.append(f"{name}: no panorama from {len(views)} view(s): {exc}")
        if panorama is None and scan is None and cloud is None:
            raise DatasetError(f"reference {name} at t = {t_s!r} s has no scan, cloud or panorama within the tolerance")
        return Reference(panorama=panorama, cloud=cloud, scan=scan, T_world_reference=T_world_reference, name=name)

    def covered(self, t_s: float) -> bool:
        """Whether the odometry gives the pose at ``t_s`` (see :meth:`keyframes`)."""
        odo = self.odometry
        return odo.gap_s(t_s) <= self.tol or odo.bracket_s(t_s) <= self.config.max_odometry_gap_s

    def keyframes(self) -> tuple[str, np.ndarray]:
        """The first sensor of laser scan, cloud, camera, and its stamps the odometry covers.

        A stamp is covered when an odometry message lies within ``sync_tolerance_s`` of it, or it lies
        between two odometry messages at most ``max_odometry_gap_s`` apart.

        Raises
        ------
        DatasetError
            When the bag has none of them, or none has odometry near it.
        """
        data = self.data
        if data.scans is not None:
            kind, stamps = "scan", data.scans.index.stamps_s
        elif data.clouds is not None:
            kind, stamps = "cloud", data.clouds.stamps_s
        elif data.cameras:
            first = sorted(data.cameras)[0]
            kind, stamps = f"camera {first}", data.cameras[first].stamps_s
        else:
            raise DatasetError(f"bag {data.path} has no laser scan, point cloud or colour camera to make queries of")
        ok = np.array([self.covered(float(t)) for t in stamps], dtype=bool)
        if not ok.any():
            raise DatasetError(f"no {kind} message of {data.path} has odometry around it (see SensorConfig.max_odometry_gap_s)")
        return kind, np.asarray(stamps)[ok]


def open_bag_sensors(path: str | Path, config: SensorConfig = SensorConfig()) -> BagSensors:
    """Find the topics, read the bag's index (one pass), and set up the robot frame and the extrinsics.

    Raises
    ------
    DatasetError
        For an unreadable bag, no odometry, ambiguous or absent topics, or a robot frame the TF does not reach.
    """
    cfg = config
    topics = resolve_topics(
        bag_topics(path), odometry=cfg.odometry_topic, scan=cfg.scan_topic, cloud=cfg.cloud_topic, cameras=cfg.camera_topics
    )
    data = read_bag_index(path, topics, max_range_m=cfg.max_range_m)
    robot = (cfg.robot_frame or data.odometry_frame or "base_link").lstrip("/")
    for frame, T in cfg.extrinsics.items():
        data.tf.add(robot, frame, T, None)
    if data.odometry_frame and robot != data.odometry_frame:
        T_base_robot = data.tf.lookup(data.odometry_frame, robot)
        poses = np.array(
            [(Rigid3.from_pose2(Pose2.from_array(p)) * T_base_robot).to_pose2().as_array() for p in data.odometry.poses]
        )
        data = replace(data, odometry=OdometryTrack(data.odometry.stamps_s, poses))
    return BagSensors(data, cfg, robot)

"""What the robot senses and knows: images, panoramas, clouds, scans, odometry, references and queries.

Frames and conventions (REP-103): x forward, y left, z up, headings counter-clockwise in radians; sensor data
in the robot frame, poses ``T_world_robot`` in the world frame. Images are OpenCV BGR ``uint8`` arrays. Every
constructor validates its fields and raises :class:`~factorloc.errors.InputError` naming the bad field.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from factorloc._validate import (
    angle_of_view,
    bgr_image,
    finite_float,
    float_array,
    nonnegative_float,
    positive_float,
    sigma_float,
)
from factorloc.errors import InputError
from factorloc.geometry import Pose2, wrap_angle

__all__ = ["CameraImage", "Odometry", "Panorama", "PointCloud", "Query", "Reference", "Scan"]


def _same_array(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    if a is None or b is None:
        return a is b
    return a.shape == b.shape and a.dtype == b.dtype and bool(np.array_equal(a, b))


def _same(a: Any, b: Any) -> bool:
    """Structural equality of two optional sensor values (``None`` equals only ``None``)."""
    if a is None or b is None:
        return a is b
    return bool(a.same_as(b))


class _ImageSize:
    """``width_px`` and ``height_px`` of an ``image_bgr`` (H×W×3)."""

    image_bgr: np.ndarray

    @property
    def width_px(self) -> int:
        return int(self.image_bgr.shape[1])

    @property
    def height_px(self) -> int:
        return int(self.image_bgr.shape[0])


@dataclass(frozen=True, eq=False)
class Panorama(_ImageSize):
    """A 360° cylindrical panorama (BGR uint8, H×W×3).

    Columns map linearly to azimuth in the frame of the robot that took it
    (x forward, y left, azimuth counter-clockwise, REP-103). Like an
    equirectangular photo viewed from inside, azimuth *decreases* to the right:

    ``azimuth(u) = azimuth_col0_rad - 2π·u / W``  (u = column index, pixel centre)

    With the default ``azimuth_col0_rad = π`` the centre column ``u = W/2``
    looks forward (azimuth 0). Rows are cylindrical: row ``v`` looks at
    elevation ``atan((H/2 - v) / f)`` with ``f = (H/2) / tan(fov_v_rad/2)``,
    the horizon at row H/2.

    ``seen_columns`` (bool, shape (W,)) marks the columns that hold imagery;
    None means all of them. A panorama stitched from a turning pinhole camera
    leaves columns it never saw: the camera steps ignore them (no keypoint,
    no correlation there) instead of matching blank pixels.
    """

    image_bgr: np.ndarray
    fov_v_rad: float = math.radians(60.0)
    azimuth_col0_rad: float = math.pi
    seen_columns: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "image_bgr", bgr_image("Panorama.image_bgr", self.image_bgr))
        if self.seen_columns is not None:
            seen = np.asarray(self.seen_columns)
            if seen.dtype != np.bool_ or seen.shape != (self.image_bgr.shape[1],):
                raise InputError(
                    f"Panorama.seen_columns must be a bool array of shape ({self.image_bgr.shape[1]},) (one per column), "
                    f"got dtype {seen.dtype} shape {seen.shape}"
                )
            if not seen.any():
                raise InputError("Panorama.seen_columns marks no column as seen: the panorama holds no imagery")
            seen = seen.copy()
            seen.setflags(write=False)
            object.__setattr__(self, "seen_columns", seen)
        fov = angle_of_view("Panorama.fov_v_rad", self.fov_v_rad)
        object.__setattr__(self, "fov_v_rad", fov)
        object.__setattr__(self, "azimuth_col0_rad", finite_float("Panorama.azimuth_col0_rad", self.azimuth_col0_rad))

    @classmethod
    def from_images(cls, images: Sequence[CameraImage], yaws_rad: Sequence[float], **kwargs: Any) -> Panorama:
        """Stitch pinhole views taken at known yaws: :func:`factorloc.vision.panoramas.panorama_from_images`."""
        from factorloc.vision.panoramas import panorama_from_images

        return panorama_from_images(images, yaws_rad, **kwargs)

    def same_as(self, other: object) -> bool:
        """Whether ``other`` is a panorama with the same pixels, field of view, azimuth origin and seen columns.

        The sensor types compare by identity (``==``; they are hashable by identity); this compares their data.
        """
        return (
            isinstance(other, Panorama)
            and _same_array(self.image_bgr, other.image_bgr)
            and self.fov_v_rad == other.fov_v_rad
            and self.azimuth_col0_rad == other.azimuth_col0_rad
            and _same_array(self.seen_columns, other.seen_columns)
        )

    @property
    def rad_per_px(self) -> float:
        """Angular width of one column."""
        return 2.0 * math.pi / self.width_px

    def azimuth_of_column(self, u: float | np.ndarray) -> float | np.ndarray:
        """Azimuth (rad, wrapped) of column ``u`` (may be fractional)."""
        return wrap_angle(self.azimuth_col0_rad - np.asarray(u, dtype=np.float64) * self.rad_per_px)

    def column_of_azimuth(self, azimuth_rad: float | np.ndarray) -> float | np.ndarray:
        """Column in [0, W) that looks at ``azimuth_rad``."""
        u = np.mod((self.azimuth_col0_rad - np.asarray(azimuth_rad, dtype=np.float64)) / self.rad_per_px, self.width_px)
        return float(u) if np.ndim(u) == 0 else u


@dataclass(frozen=True, eq=False)
class CameraImage(_ImageSize):
    """A pinhole camera image (BGR uint8, H×W×3) taken by the robot.

    ``hfov_rad`` is the horizontal field of view; pixels are square and the
    principal point is the image centre unless ``cx_px`` is given. The camera
    looks along ``yaw_in_robot_rad`` in the robot frame (0 = forward, CCW
    positive); ``pitch_rad`` tilts it up (positive) or down.
    """

    image_bgr: np.ndarray
    hfov_rad: float = math.radians(57.0)
    yaw_in_robot_rad: float = 0.0
    pitch_rad: float = 0.0
    cx_px: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "image_bgr", bgr_image("CameraImage.image_bgr", self.image_bgr))
        fov = angle_of_view("CameraImage.hfov_rad", self.hfov_rad)
        object.__setattr__(self, "hfov_rad", fov)
        object.__setattr__(
            self, "yaw_in_robot_rad", wrap_angle(finite_float("CameraImage.yaw_in_robot_rad", self.yaw_in_robot_rad))
        )
        object.__setattr__(self, "pitch_rad", finite_float("CameraImage.pitch_rad", self.pitch_rad))
        if self.cx_px is not None:
            object.__setattr__(self, "cx_px", finite_float("CameraImage.cx_px", self.cx_px))

    def same_as(self, other: object) -> bool:
        """Whether ``other`` is a camera image with the same pixels and the same camera parameters."""
        return (
            isinstance(other, CameraImage)
            and _same_array(self.image_bgr, other.image_bgr)
            and (self.hfov_rad, self.yaw_in_robot_rad, self.pitch_rad, self.cx_px)
            == (other.hfov_rad, other.yaw_in_robot_rad, other.pitch_rad, other.cx_px)
        )

    @property
    def focal_px(self) -> float:
        """Focal length in pixels: ``(W/2) / tan(hfov/2)``."""
        return 0.5 * self.width_px / math.tan(0.5 * self.hfov_rad)

    @property
    def principal_x_px(self) -> float:
        return (self.width_px - 1) / 2.0 if self.cx_px is None else self.cx_px

    @property
    def vfov_rad(self) -> float:
        """Vertical field of view implied by square pixels."""
        return 2.0 * math.atan(0.5 * self.height_px / self.focal_px)

    def azimuth_of_column(self, u: float | np.ndarray) -> float | np.ndarray:
        """Azimuth in the robot frame (rad) of image column ``u``: yaw + atan((cx - u)/f)."""
        return wrap_angle(
            self.yaw_in_robot_rad + np.arctan((self.principal_x_px - np.asarray(u, dtype=np.float64)) / self.focal_px)
        )


@dataclass(frozen=True, eq=False)
class PointCloud:
    """A 3D point cloud, N×3 metres, robot frame (x forward, y left, z up from the floor)."""

    points_m: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "points_m", float_array("PointCloud.points_m", self.points_m, (None, 3)))

    def __len__(self) -> int:
        return int(self.points_m.shape[0])

    def same_as(self, other: object) -> bool:
        """Whether ``other`` is of the same type with the same points."""
        return type(other) is type(self) and _same_array(self.points_m, other.points_m)  # type: ignore[attr-defined]


@dataclass(frozen=True, eq=False)
class Scan:
    """A 2D scan, N×2 metres, robot frame (x forward, y left): a horizontal cut or a laser scan."""

    points_m: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "points_m", float_array("Scan.points_m", self.points_m, (None, 2)))

    def __len__(self) -> int:
        return int(self.points_m.shape[0])

    def same_as(self, other: object) -> bool:
        """Whether ``other`` is of the same type with the same points."""
        return type(other) is type(self) and _same_array(self.points_m, other.points_m)  # type: ignore[attr-defined]


@dataclass(frozen=True)
class Odometry:
    """The odometry's pose of the robot in the world frame, with per-axis sigmas.

    Build it from the distance travelled with :meth:`from_distance` (the
    patent's example: 5 % drift, 1 m walked → σx = σy = 5 cm).
    """

    T_world_robot: Pose2
    sigma_x_m: float
    sigma_y_m: float
    sigma_theta_rad: float

    def __post_init__(self) -> None:
        if not isinstance(self.T_world_robot, Pose2):
            raise InputError(f"Odometry.T_world_robot must be a Pose2, got {type(self.T_world_robot).__name__}")
        object.__setattr__(self, "sigma_x_m", sigma_float("Odometry.sigma_x_m", self.sigma_x_m))
        object.__setattr__(self, "sigma_y_m", sigma_float("Odometry.sigma_y_m", self.sigma_y_m))
        object.__setattr__(self, "sigma_theta_rad", sigma_float("Odometry.sigma_theta_rad", self.sigma_theta_rad))

    @classmethod
    def from_distance(
        cls,
        T_world_robot: Pose2,
        distance_m: float,
        rotation_rad: float = 0.0,
        *,
        drift_ratio: float = 0.05,
        heading_drift_ratio: float = 0.05,
        heading_drift_rad_per_m: float = 0.02,
        min_sigma_m: float = 1e-3,
        min_sigma_rad: float = 1e-3,
    ) -> Odometry:
        """Sigmas that grow with the motion since the last reset.

        σx = σy = max(min_sigma_m, drift_ratio · distance_m);
        σθ = max(min_sigma_rad, heading_drift_ratio · |rotation_rad| + heading_drift_rad_per_m · distance_m).
        """
        d = nonnegative_float("Odometry.distance_m", distance_m)
        r = abs(finite_float("Odometry.rotation_rad", rotation_rad))
        k = nonnegative_float("Odometry.drift_ratio", drift_ratio)
        kh = nonnegative_float("Odometry.heading_drift_ratio", heading_drift_ratio)
        kd = nonnegative_float("Odometry.heading_drift_rad_per_m", heading_drift_rad_per_m)
        s_xy = max(positive_float("Odometry.min_sigma_m", min_sigma_m), k * d)
        s_th = max(positive_float("Odometry.min_sigma_rad", min_sigma_rad), kh * r + kd * d)
        return cls(T_world_robot, s_xy, s_xy, s_th)


@dataclass(frozen=True, eq=False)
class Reference:
    """What the robot knows of one place: a panorama and/or a scan or 360° cloud, and where it was taken.

    ``T_world_reference`` is the pose of the robot that captured the reference
    (default: the world origin). The cloud/scan are in that robot's frame.
    """

    panorama: Panorama | None = None
    cloud: PointCloud | None = None
    scan: Scan | None = None
    T_world_reference: Pose2 = field(default_factory=Pose2)
    name: str = "reference"

    def __post_init__(self) -> None:
        _check_type("Reference.panorama", self.panorama, Panorama)
        _check_type("Reference.cloud", self.cloud, PointCloud)
        _check_type("Reference.scan", self.scan, Scan)
        if not isinstance(self.T_world_reference, Pose2):
            raise InputError(f"Reference.T_world_reference must be a Pose2, got {type(self.T_world_reference).__name__}")
        if self.panorama is None and self.cloud is None and self.scan is None:
            raise InputError("Reference needs at least one of panorama, cloud or scan")

    def same_as(self, other: object) -> bool:
        """Whether ``other`` is a reference with the same sensor data, pose and name."""
        return (
            isinstance(other, Reference)
            and _same(self.panorama, other.panorama)
            and _same(self.cloud, other.cloud)
            and _same(self.scan, other.scan)
            and self.T_world_reference == other.T_world_reference
            and self.name == other.name
        )


@dataclass(frozen=True, eq=False)
class Query:
    """What the robot senses now; every modality is optional.

    ``images`` are pinhole views (several at different head yaws form a
    partial panorama); ``panorama`` a full 360° query; ``cloud``/``scan`` in the
    robot frame; ``odometry`` the dead-reckoned pose in the world frame.
    """

    images: tuple[CameraImage, ...] = ()
    panorama: Panorama | None = None
    cloud: PointCloud | None = None
    scan: Scan | None = None
    odometry: Odometry | None = None
    id: str = ""

    def __post_init__(self) -> None:
        images = self.images
        if isinstance(images, CameraImage):
            images = (images,)
        if not isinstance(images, Sequence) or isinstance(images, (str, bytes)):
            raise InputError(f"Query.images must be a sequence of CameraImage, got {type(images).__name__}")
        images = tuple(images)
        for i, im in enumerate(images):
            _check_type(f"Query.images[{i}]", im, CameraImage)
        object.__setattr__(self, "images", images)
        _check_type("Query.panorama", self.panorama, Panorama)
        _check_type("Query.cloud", self.cloud, PointCloud)
        _check_type("Query.scan", self.scan, Scan)
        _check_type("Query.odometry", self.odometry, Odometry)

    def same_as(self, other: object) -> bool:
        """Whether ``other`` is a query with the same id, sensor data and odometry."""
        return (
            isinstance(other, Query)
            and self.id == other.id
            and len(self.images) == len(other.images)
            and all(a.same_as(b) for a, b in zip(self.images, other.images, strict=True))
            and _same(self.panorama, other.panorama)
            and _same(self.cloud, other.cloud)
            and _same(self.scan, other.scan)
            and self.odometry == other.odometry
        )


def _check_type(name: str, value: Any, cls: type) -> None:
    if value is not None and not isinstance(value, cls):
        raise InputError(f"{name} must be a {cls.__name__} or None, got {type(value).__name__}")

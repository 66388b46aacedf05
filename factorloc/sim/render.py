"""Renderers: 360° panoramas, pinhole camera images and depth point clouds of a :class:`World`
(the 2D laser scan is :mod:`factorloc.sim.laser`).

All renderers share one vectorised ray caster (:mod:`factorloc.sim.raycast`, which explains how a
column-separable pixel grid is cast and textured): perspective, parallax and occlusion are exact; there
is no lighting model beyond a fixed shade per face orientation.

Sensor heights are metres above the floor; sensors sit on the robot's vertical axis. Camera pitch is
always 0 (optical axes horizontal).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass

import numpy as np

from factorloc._validate import finite_float, nonnegative_float, positive_float, positive_int
from factorloc.errors import InputError
from factorloc.geometry import Pose2, wrap_angle
from factorloc.sim.raycast import Hits, cast_all, shade
from factorloc.sim.world import Obstacle, World
from factorloc.types import CameraImage, Panorama, PointCloud

__all__ = [
    "DepthCamera",
    "PinholeCamera",
    "panorama_rays",
    "render_camera",
    "render_cloud",
    "render_cloud_360",
    "render_panorama",
]


# --------------------------------------------------------------------------
# Sensors
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class PinholeCamera:
    """A robot's colour camera: square pixels, optical axis horizontal.

    Defaults: 640×480 px, 57° horizontal FOV (44.3° vertical, as the robot of
    WO 2015/158682), looking forward from 1.0 m above the floor. ``yaw_in_robot_rad``
    turns it in the robot frame (CCW positive, a pan head).
    """

    width_px: int = 640
    height_px: int = 480
    hfov_rad: float = math.radians(57.0)
    yaw_in_robot_rad: float = 0.0
    height_m: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "width_px", positive_int("PinholeCamera.width_px", self.width_px, 8))
        object.__setattr__(self, "height_px", positive_int("PinholeCamera.height_px", self.height_px, 8))
        fov = positive_float("PinholeCamera.hfov_rad", self.hfov_rad)
        if fov >= math.pi:
            raise InputError(f"PinholeCamera.hfov_rad must be < π, got {fov}")
        object.__setattr__(self, "hfov_rad", fov)
        object.__setattr__(
            self, "yaw_in_robot_rad", wrap_angle(finite_float("PinholeCamera.yaw_in_robot_rad", self.yaw_in_robot_rad))
        )
        object.__setattr__(self, "height_m", positive_float("PinholeCamera.height_m", self.height_m))

    @property
    def focal_px(self) -> float:
        """``(W/2) / tan(hfov/2)``, as :attr:`factorloc.CameraImage.focal_px`."""
        return 0.5 * self.width_px / math.tan(0.5 * self.hfov_rad)

    @property
    def vfov_rad(self) -> float:
        return 2.0 * math.atan(0.5 * self.height_px / self.focal_px)


@dataclass(frozen=True)
class DepthCamera:
    """A structured-light depth sensor (Kinect/Xtion-like), optical axis horizontal.

    Defaults: 320×240 px over 58° × 45°, valid depths 0.4–4.5 m, 1.0 m above
    the floor. Depth noise (along the ray, Gaussian) has the standard deviation
    ``σ(d) = noise_sigma0_m + noise_quadratic_m_per_m2 · (d − noise_ref_m)²`` for depth ``d``
    (1.2 mm + 1.9 mm·(d − 0.4 m)², Nguyen, Izadi & Lovell 2012, Kinect axial noise).
    ``stride_px`` keeps every n-th pixel in both directions (decimation).
    Returns from faces marked ``glass`` are dropped.
    """

    width_px: int = 320
    height_px: int = 240
    hfov_rad: float = math.radians(58.0)
    vfov_rad: float = math.radians(45.0)
    min_range_m: float = 0.4
    max_range_m: float = 4.5
    yaw_in_robot_rad: float = 0.0
    height_m: float = 1.0
    noise_sigma0_m: float = 0.0012
    noise_quadratic_m_per_m2: float = 0.0019
    noise_ref_m: float = 0.4
    stride_px: int = 1

    def __post_init__(self) -> None:
        object.__setattr__(self, "width_px", positive_int("DepthCamera.width_px", self.width_px, 2))
        object.__setattr__(self, "height_px", positive_int("DepthCamera.height_px", self.height_px, 2))
        for name in ("hfov_rad", "vfov_rad"):
            fov = positive_float(f"DepthCamera.{name}", getattr(self, name))
            if fov >= math.pi:
                raise InputError(f"DepthCamera.{name} must be < π, got {fov}")
            object.__setattr__(self, name, fov)
        lo = nonnegative_float("DepthCamera.min_range_m", self.min_range_m)
        hi = positive_float("DepthCamera.max_range_m", self.max_range_m)
        if hi <= lo:
            raise InputError(f"DepthCamera.max_range_m ({hi}) must exceed min_range_m ({lo})")
        object.__setattr__(self, "min_range_m", lo)
        object.__setattr__(self, "max_range_m", hi)
        object.__setattr__(
            self, "yaw_in_robot_rad", wrap_angle(finite_float("DepthCamera.yaw_in_robot_rad", self.yaw_in_robot_rad))
        )
        object.__setattr__(self, "height_m", positive_float("DepthCamera.height_m", self.height_m))
        for name in ("noise_sigma0_m", "noise_quadratic_m_per_m2", "noise_ref_m"):
            object.__setattr__(self, name, nonnegative_float(f"DepthCamera.{name}", getattr(self, name)))
        object.__setattr__(self, "stride_px", positive_int("DepthCamera.stride_px", self.stride_px))

    def noise_sigma_m(self, depth_m: np.ndarray | float) -> np.ndarray | float:
        """σ of the depth noise (m) at depth ``depth_m``."""
        return self.noise_sigma0_m + self.noise_quadratic_m_per_m2 * (np.asarray(depth_m) - self.noise_ref_m) ** 2


# --------------------------------------------------------------------------
# Renderers
# --------------------------------------------------------------------------
def panorama_rays(
    width_px: int, height_px: int, fov_v_rad: float, azimuth_col0_rad: float = math.pi
) -> tuple[np.ndarray, np.ndarray]:
    """Column azimuths (W,) and row elevation tangents (H,) of the :class:`~factorloc.Panorama` convention.

    ``azimuth(u) = azimuth_col0_rad − 2π·u/W``; ``tan(elevation(v)) = (H/2 − v)/f``,
    ``f = (H/2)/tan(fov_v/2)``.
    """
    u = np.arange(width_px, dtype=np.float64)
    v = np.arange(height_px, dtype=np.float64)
    f = 0.5 * height_px / math.tan(0.5 * fov_v_rad)
    return azimuth_col0_rad - 2.0 * math.pi * u / width_px, (0.5 * height_px - v) / f


def _image(world: World, hits: Hits, sel: np.ndarray | None, occ_img: np.ndarray | None) -> np.ndarray:
    img = shade(world, hits)
    if sel is not None and occ_img is not None:
        img[sel] = occ_img[sel]
    return img


def render_panorama(
    world: World,
    T_world_robot: Pose2,
    height_m: float = 1.0,
    width_px: int = 2048,
    fov_v_rad: float = math.radians(60.0),
    height_px: int | None = None,
    *,
    occluders: Sequence[Obstacle] = (),
) -> Panorama:
    """Render the 360° cylindrical panorama seen from ``height_m`` above the robot's pose.

    Follows :class:`factorloc.Panorama` exactly: column ``u`` looks at robot-frame
    azimuth ``π − 2π·u/W`` (the centre column ``W/2`` looks forward, azimuth
    decreases to the right), row ``v`` at elevation ``atan((H/2 − v)/f)`` with
    ``f = (H/2)/tan(fov_v_rad/2)``. ``height_px`` defaults to ``width_px // 8``
    (2048 × 256). Rotating the robot by Δθ shifts the image by Δθ·W/2π columns
    to the right. ``occluders`` are extra obstacles (people, boxes) that are
    not part of ``world`` — what a query sees and the reference did not.
    """
    if not isinstance(T_world_robot, Pose2):
        raise InputError(f"T_world_robot must be a Pose2, got {type(T_world_robot).__name__}")
    W = positive_int("width_px", width_px, 8)
    H = W // 8 if height_px is None else positive_int("height_px", height_px, 8)
    fov = positive_float("fov_v_rad", fov_v_rad)
    if fov >= math.pi:
        raise InputError(f"fov_v_rad must be < π for a cylindrical panorama, got {fov}")
    az, row_tan = panorama_rays(W, H, fov)
    f = 0.5 * H / math.tan(0.5 * fov)
    ang = np.full(W, max(2.0 * math.pi / W, 1.0 / f))
    hits, sel, occ = cast_all(world, occluders, T_world_robot, positive_float("height_m", height_m), az, row_tan, np.ones(W), ang)
    return Panorama(_image(world, hits, sel, occ), fov_v_rad=fov, azimuth_col0_rad=math.pi)


def _camera_rays(
    width: int, height: int, fx: float, fy: float, stride: int = 1
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    u = np.arange(0, width, stride, dtype=np.float64)
    v = np.arange(0, height, stride, dtype=np.float64)
    a = ((width - 1) / 2.0 - u) / fx  # left component of the ray (forward = 1)
    b = ((height - 1) / 2.0 - v) / fy  # up component
    return u, v, a, b


def render_camera(
    world: World,
    T_world_robot: Pose2,
    camera: PinholeCamera = PinholeCamera(),
    *,
    occluders: Sequence[Obstacle] = (),
) -> CameraImage:
    """Render a pinhole image (BGR uint8, ``camera.height_px × camera.width_px``).

    Column ``u`` looks at robot-frame azimuth ``yaw + atan((cx − u)/f)`` with
    ``cx = (W−1)/2``, ``f = (W/2)/tan(hfov/2)`` — :meth:`factorloc.CameraImage.azimuth_of_column`;
    row ``v`` at elevation tangent ``(cy − v)/f / sqrt(1 + ((cx − u)/f)²)``.
    ``occluders``: extra obstacles not in ``world`` (see :func:`render_panorama`).
    """
    if not isinstance(T_world_robot, Pose2):
        raise InputError(f"T_world_robot must be a Pose2, got {type(T_world_robot).__name__}")
    if not isinstance(camera, PinholeCamera):
        raise InputError(f"camera must be a PinholeCamera, got {type(camera).__name__}")
    f = camera.focal_px
    _, _, a, b = _camera_rays(camera.width_px, camera.height_px, f, f)
    col_scale = 1.0 / np.sqrt(1.0 + a * a)
    T_sensor = T_world_robot * Pose2(0.0, 0.0, camera.yaw_in_robot_rad)
    hits, sel, occ = cast_all(world, occluders, T_sensor, camera.height_m, np.arctan(a), b, col_scale, col_scale / f)
    return CameraImage(_image(world, hits, sel, occ), hfov_rad=camera.hfov_rad, yaw_in_robot_rad=camera.yaw_in_robot_rad)


def _cloud_world(
    world: World,
    T_world_robot: Pose2,
    cam: DepthCamera,
    rng: np.random.Generator | None,
    occluders: Sequence[Obstacle] = (),
    glass_faces: Collection[int] = (),
) -> tuple[np.ndarray, Hits, np.ndarray]:
    fx = 0.5 * cam.width_px / math.tan(0.5 * cam.hfov_rad)
    fy = 0.5 * cam.height_px / math.tan(0.5 * cam.vfov_rad)
    _, _, a, b = _camera_rays(cam.width_px, cam.height_px, fx, fy, cam.stride_px)
    col_scale = 1.0 / np.sqrt(1.0 + a * a)
    T_sensor = T_world_robot * Pose2(0.0, 0.0, cam.yaw_in_robot_rad)
    hits, _, _ = cast_all(
        world, occluders, T_sensor, cam.height_m, np.arctan(a), b, col_scale, col_scale / fx * cam.stride_px, texture=False
    )
    depth = hits.distance_m * col_scale[None, :]  # along the optical axis
    keep = (depth >= cam.min_range_m) & (depth <= cam.max_range_m) & ~hits.glass
    if glass_faces:
        keep &= ~np.isin(hits.face, np.fromiter(glass_faces, dtype=np.int64))
    factor = np.ones_like(depth)
    if rng is not None:
        sigma = cam.noise_sigma_m(depth)
        factor = 1.0 + rng.standard_normal(depth.shape) * sigma / np.maximum(depth, 1e-9)
    pts = np.stack(
        [
            T_sensor.x + (hits.x_m - T_sensor.x) * factor,
            T_sensor.y + (hits.y_m - T_sensor.y) * factor,
            cam.height_m + (hits.z_m - cam.height_m) * factor,
        ],
        axis=-1,
    )
    return pts[keep], hits, keep


def _to_robot(points_world: np.ndarray, T_world_robot: Pose2) -> np.ndarray:
    xy = T_world_robot.inverse().transform_points(points_world[:, :2])
    out = np.column_stack([xy, points_world[:, 2]])
    return out.astype(np.float32).astype(np.float64)  # float32-exact: stores losslessly as float32


def render_cloud(
    world: World,
    T_world_robot: Pose2,
    depth_camera: DepthCamera = DepthCamera(),
    rng: np.random.Generator | None = None,
    *,
    occluders: Sequence[Obstacle] = (),
    glass_faces: Collection[int] = (),
) -> PointCloud:
    """Render the point cloud a depth camera returns (robot frame, z up from the floor).

    Points are N×3 metres in the robot frame (x forward, y left, z from the
    floor), row-major over the (strided) pixel grid, keeping true depths in
    ``[min_range_m, max_range_m]`` (the range test precedes the noise, so a noisy
    depth may exceed the limits by a few σ) and dropping glass (faces marked ``glass`` in
    the world, plus the face indices ``glass_faces`` into ``world.segments.faces``).
    With ``rng`` each depth gets Gaussian noise of σ = ``depth_camera.noise_sigma_m(depth)``
    along its ray; ``rng=None`` renders noise-free. Values are rounded to float32
    precision (so that a float32 file stores them exactly). ``occluders``: extra
    obstacles not in ``world``.
    """
    if not isinstance(T_world_robot, Pose2):
        raise InputError(f"T_world_robot must be a Pose2, got {type(T_world_robot).__name__}")
    if not isinstance(depth_camera, DepthCamera):
        raise InputError(f"depth_camera must be a DepthCamera, got {type(depth_camera).__name__}")
    pts, _, _ = _cloud_world(world, T_world_robot, depth_camera, rng, occluders, glass_faces)
    if len(pts) == 0:
        raise InputError(
            f"the depth camera at {T_world_robot} sees nothing within {depth_camera.min_range_m}–{depth_camera.max_range_m} m"
        )
    return PointCloud(_to_robot(pts, T_world_robot))


def render_cloud_360(
    world: World,
    T_world_robot: Pose2,
    depth_camera: DepthCamera = DepthCamera(),
    rng: np.random.Generator | None = None,
    n_views: int | None = None,
    *,
    occluders: Sequence[Obstacle] = (),
    glass_faces: Collection[int] = (),
) -> PointCloud:
    """A 360° cloud: the robot turns its head through ``n_views`` equally spaced yaws and merges the views.

    ``n_views`` defaults to ``ceil(2π / hfov)`` (7 for 58°), so neighbouring views
    overlap slightly. The camera's own ``yaw_in_robot_rad`` is the first yaw.
    Points are in the robot frame as in :func:`render_cloud`.
    """
    if not isinstance(depth_camera, DepthCamera):
        raise InputError(f"depth_camera must be a DepthCamera, got {type(depth_camera).__name__}")
    n = math.ceil(2.0 * math.pi / depth_camera.hfov_rad) if n_views is None else positive_int("n_views", n_views)
    parts = []
    for i in range(n):
        cam = dataclasses.replace(depth_camera, yaw_in_robot_rad=depth_camera.yaw_in_robot_rad + 2.0 * math.pi * i / n)
        pts, _, _ = _cloud_world(world, T_world_robot, cam, rng, occluders, glass_faces)
        parts.append(pts)
    pts = np.vstack(parts)
    if len(pts) == 0:
        raise InputError(
            f"the depth camera at {T_world_robot} sees nothing within {depth_camera.min_range_m}–{depth_camera.max_range_m} m"
        )
    return PointCloud(_to_robot(pts, T_world_robot))

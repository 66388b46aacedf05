"""Renderers: 360° panoramas, pinhole camera images, depth point clouds and 2D scans of a :class:`World`.

All renderers share one vectorised ray caster. A sensor's pixel grid is
*column-separable*: every image column is a vertical plane through the
sensor's (vertical) axis, so a column's horizontal ray is intersected with all
S plan segments at once (a W×S array), the K nearest hits are kept, and each
pixel's elevation decides which of them it sees:

* a hit at horizontal distance ``d`` is seen by the pixel of elevation tangent
  ``t`` when the ray's height there, ``z = z_cam + d·t``, lies on the face
  (``0 ≤ z ≤ height``); nearer hits win (occlusion);
* a ray that passes above a low obstacle's front face and meets its back face
  from inside has hit the obstacle's *top* at ``d = (z_cam − h)/(−t)``;
* a ray that meets no face hits the floor at ``d = z_cam/(−t)`` or the ceiling
  at ``d = (H − z_cam)/t``.

Textures are sampled bilinearly from the world's mip-mapped atlas
(:func:`factorloc.sim.textures.atlas_of`) with :func:`cv2.remap`, the level
chosen per pixel from the texel footprint. Perspective, parallax and
occlusion are therefore exact; there is no lighting model beyond a fixed
shade per face orientation.

Sensor heights are metres above the floor; sensors sit on the robot's
vertical axis. Camera pitch is always 0 (optical axes horizontal).
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections.abc import Collection, Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from factorloc._validate import finite_float, nonnegative_float, positive_float
from factorloc.errors import InputError
from factorloc.geometry import Pose2, wrap_angle
from factorloc.sim.textures import atlas_of
from factorloc.sim.world import Obstacle, World
from factorloc.types import CameraImage, Panorama, PointCloud, Scan

#: Number of nearest segment hits kept per column (enough for a few low obstacles in front of a wall).
_MAX_LAYERS = 6
_FLOOR, _CEILING, _FACE, _TOP = 0, 1, 2, 3


# --------------------------------------------------------------------------
# Sensors
# --------------------------------------------------------------------------
def _positive_int(name: str, value: object, minimum: int = 1) -> int:
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or int(value) < minimum:
        raise InputError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


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
        object.__setattr__(self, "width_px", _positive_int("PinholeCamera.width_px", self.width_px, 8))
        object.__setattr__(self, "height_px", _positive_int("PinholeCamera.height_px", self.height_px, 8))
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
        object.__setattr__(self, "width_px", _positive_int("DepthCamera.width_px", self.width_px, 2))
        object.__setattr__(self, "height_px", _positive_int("DepthCamera.height_px", self.height_px, 2))
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
        object.__setattr__(self, "stride_px", _positive_int("DepthCamera.stride_px", self.stride_px))

    def noise_sigma_m(self, depth_m: np.ndarray | float) -> np.ndarray | float:
        """σ of the depth noise (m) at depth ``depth_m``."""
        return self.noise_sigma0_m + self.noise_quadratic_m_per_m2 * (np.asarray(depth_m) - self.noise_ref_m) ** 2


# --------------------------------------------------------------------------
# The ray caster
# --------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Hits:
    """What each pixel of a column-separable sensor sees (all arrays H×W).

    ``kind``: 0 floor, 1 ceiling, 2 wall/obstacle face, 3 obstacle top.
    ``distance_m``: horizontal distance from the sensor axis to the hit (capped at 1 km).
    ``face``: index into ``world.segments.faces`` (−1 unless kind 2).
    ``x_m``, ``y_m``, ``z_m``: world coordinates of the hit (float64, computed on access).
    ``glass``: the hit face is glass (no depth return).
    """

    kind: np.ndarray
    dist: np.ndarray
    face: np.ndarray
    origin: tuple[float, float, float]
    dx: np.ndarray
    dy: np.ndarray
    tan_e: np.ndarray
    face_sel: np.ndarray
    plane_h: np.ndarray
    wall_h: float
    glass: np.ndarray
    map_x: np.ndarray | None = None  # float32 coordinates into atlas.packed, for cv2.remap
    map_y: np.ndarray | None = None

    @property
    def distance_m(self) -> np.ndarray:
        return self.dist.astype(np.float64)

    @property
    def x_m(self) -> np.ndarray:
        return self.origin[0] + self.distance_m * self.dx[None, :]

    @property
    def y_m(self) -> np.ndarray:
        return self.origin[1] + self.distance_m * self.dy[None, :]

    @property
    def z_m(self) -> np.ndarray:
        d = self.distance_m
        z_face = self.origin[2] + d * self.tan_e
        z = self.face_sel * z_face + (1.0 - self.face_sel) * self.plane_h
        return np.clip(z, 0.0, self.wall_h)


def cast_rays(
    world: World,
    T_world_sensor: Pose2,
    z_m: float,
    azimuth_rad: np.ndarray,
    row_tan: np.ndarray,
    col_scale: np.ndarray,
    pixel_angle_rad: np.ndarray,
    *,
    texture: bool = True,
) -> Hits:
    """Cast the rays of a column-separable sensor.

    Parameters
    ----------
    world
        The world.
    T_world_sensor
        Pose of the sensor axis in the world (its heading is azimuth 0).
    z_m
        Height of the optical centre above the floor (m), in (0, wall height).
    azimuth_rad
        W azimuths of the columns in the sensor frame (rad, CCW).
    row_tan, col_scale
        The elevation tangent of pixel (v, u) is ``row_tan[v] * col_scale[u]``.
    pixel_angle_rad
        W angular sizes of a pixel (rad), for the texture level of detail.
    texture
        Compute the atlas coordinates (``map_x``, ``map_y``); False for depth-only sensors.
    """
    seg = world.segments
    ox, oy = T_world_sensor.x, T_world_sensor.y
    if bool(world.inside_obstacle(np.array([[ox, oy]]))[0]):
        raise InputError(f"sensor pose {T_world_sensor} is inside an obstacle of world '{world.name}'")
    if not 0.0 < z_m < world.wall_height_m:
        raise InputError(
            f"sensor height {z_m} m must be inside (0, {world.wall_height_m}) m, the wall height of world '{world.name}'"
        )
    wall_h = world.wall_height_m
    az = T_world_sensor.theta + np.asarray(azimuth_rad, np.float64)
    dx, dy = np.cos(az), np.sin(az)  # W
    row_tan = np.asarray(row_tan, np.float64)
    col_scale = np.asarray(col_scale, np.float64)
    H, W = row_tan.shape[0], az.shape[0]

    # --- column rays against all segments (W×S) -------------------------------
    e = seg.p1 - seg.p0
    wx, wy = seg.p0[:, 0] - ox, seg.p0[:, 1] - oy
    denom = dx[:, None] * e[None, :, 1] - dy[:, None] * e[None, :, 0]
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (wx * e[:, 1] - wy * e[:, 0])[None, :] / denom
        s = (wx[None, :] * dy[:, None] - wy[None, :] * dx[:, None]) / denom
    valid = (np.abs(denom) > 1e-12) & (t > 1e-9) & (s >= 0.0) & (s <= 1.0)
    t = np.where(valid, t, np.inf)
    on_left = (e[:, 0] * (oy - seg.p0[:, 1]) - e[:, 1] * (ox - seg.p0[:, 0])) > 0.0  # S: which side the sensor is on
    seen_face = np.where(on_left, seg.face_left, seg.face_right)  # S, −1 = inside of an obstacle

    K = min(_MAX_LAYERS, seg.count)
    if K < seg.count:
        idx = np.argpartition(t, K - 1, axis=1)[:, :K]
    else:
        idx = np.broadcast_to(np.arange(seg.count), (W, seg.count)).copy()
    tk = np.take_along_axis(t, idx, axis=1)
    order = np.argsort(tk, axis=1, kind="stable")
    idx = np.take_along_axis(idx, order, axis=1)
    tk = np.take_along_axis(tk, order, axis=1)
    full = np.isfinite(tk) & (seg.height_m[idx] >= wall_h - 1e-9)
    first_full = np.where(full.any(axis=1), np.argmax(full, axis=1), K - 1)
    Kp = int(first_full.max()) + 1

    # per (layer, column) tables; row Kp is the pseudo-layer "no face: floor or ceiling"
    idx = idx[:, :Kp].T  # Kp×W
    d_tab = tk[:, :Kp].T
    hit_ok = np.isfinite(d_tab)
    h_tab = seg.height_m[idx]
    f_tab = seen_face[idx]  # −1: top of an obstacle

    # --- per pixel: nearest layer whose face spans the pixel's elevation --------
    # (branch-free arithmetic on H×W arrays: np.where / boolean indexing are 10–50× slower here)
    ft = np.float32 if texture else np.float64
    tan_e = (row_tan[:, None] * col_scale[None, :]).astype(ft)  # H×W
    layer = np.full((H, W), Kp, np.int8)
    with np.errstate(divide="ignore", invalid="ignore"):
        lo_tab = np.where(hit_ok, -z_m / d_tab, np.inf).astype(ft)
        hi_tab = np.where(hit_ok, (h_tab - z_m) / d_tab, -np.inf).astype(ft)
    for k in range(Kp - 1, -1, -1):  # painter's algorithm: far to near
        cover = tan_e >= lo_tab[k]
        cover &= tan_e <= hi_tab[k]
        layer -= cover.view(np.int8) * (layer - np.int8(k))

    lin = layer.astype(np.intp) * W + np.arange(W, dtype=np.intp)[None, :]
    is_face_tab = (f_tab >= 0) & hit_ok
    pseudo = layer == Kp
    up = tan_e >= 0.0
    pseudo_up = pseudo & up

    def table(values: np.ndarray, pseudo_value: float = 0.0, dtype: type = ft) -> np.ndarray:
        return np.vstack([values, np.full((1, W), pseudo_value)]).ravel().astype(dtype)

    fsel = np.take(table(is_face_tab), lin)  # 1 on faces, 0 on floor/ceiling/tops
    # planar pixels: distance = (z_cam − plane height)/(−tan e); faces: the layer's distance
    num = np.take(table(np.where(is_face_tab, 0.0, z_m - h_tab)), lin)
    num += pseudo * ft(z_m) - pseudo_up * ft(wall_h)
    tan_safe = tan_e + (tan_e == 0.0) * ft(1e-12)
    dist = num / -tan_safe + np.take(table(np.where(is_face_tab, d_tab, 0.0)), lin)
    np.clip(dist, 0.0, 1e3, out=dist)

    kind = np.take(table(np.where(is_face_tab, _FACE, _TOP), _FLOOR, np.int8), lin)
    kind += pseudo_up.view(np.int8) * np.int8(_CEILING - _FLOOR)
    face = np.take(table(np.where(is_face_tab, f_tab, -1), -1, np.int64), lin)
    plane_h = np.take(table(np.where(is_face_tab, 0.0, h_tab)), lin) + pseudo_up * ft(wall_h)
    glass = np.take(table(is_face_tab & seg.face_glass[np.maximum(f_tab, 0)], 0, bool), lin)
    if not texture:
        return Hits(kind, dist, face, (ox, oy, z_m), dx, dy, tan_e, fsel, plane_h, wall_h, glass)

    # --- texture coordinates (float32) -------------------------------------------
    atlas = atlas_of(world)
    ppm = atlas.ppm
    f32 = np.float32
    fsafe = np.maximum(f_tab, 0)
    s_tab = np.take_along_axis(s, idx.T, axis=1).T
    L = seg.face_length_m[fsafe]
    u_m = np.where(on_left[idx], (1.0 - s_tab) * L, s_tab * L)
    ax_tab = np.where(is_face_tab, atlas.face_x0[fsafe] + u_m * ppm, 0.0)
    ay_tab = np.where(is_face_tab, atlas.face_y0[fsafe] + (seg.face_height_m[fsafe] - z_m) * ppm, 0.0)  # − ppm·d·tan e per pixel
    cos_h = np.abs(e[idx, 0] * dy[None, :] - e[idx, 1] * dx[None, :]) / np.hypot(e[idx, 0], e[idx, 1])
    fp_tab = np.where(is_face_tab, ppm * pixel_angle_rad[None, :] * np.where(hit_ok, d_tab, 0.0) / np.clip(cos_h, 0.35, 1.0), 0.0)
    dist_t = dist * tan_e
    # tiles: 0 floor, 1 ceiling, 2 + k top of obstacle k (face pixels get tile 0: finite, then discarded)
    tile = np.take(table(np.where(is_face_tab, 0, 2 + seg.obstacle[idx]), 0, np.intp), lin) + pseudo_up
    tppm = np.take(atlas.tile_ppm.astype(f32), tile)
    tpx = np.take(atlas.tile_px.astype(f32), tile)
    xs = (f32(ox) + dist * dx.astype(f32)[None, :]) * tppm
    ys = (f32(-oy) - dist * dy.astype(f32)[None, :]) * tppm
    ax_t = np.take(atlas.tile_x0.astype(f32), tile) + xs - np.floor(xs / tpx) * tpx
    ay_t = np.take(atlas.tile_y0.astype(f32), tile) + ys - np.floor(ys / tpx) * tpx
    face_px = fsel > 0.5
    ax = np.where(face_px, np.take(table(ax_tab), lin), ax_t)
    ay = np.where(face_px, np.take(table(ay_tab), lin) - f32(ppm) * dist_t, ay_t)

    # texel footprint (level-0 texels per pixel) → mip level
    t2 = 1.0 + tan_e * tan_e
    fp_plane = f32(ppm) * pixel_angle_rad.astype(f32)[None, :] * dist / np.maximum(np.abs(tan_e), f32(0.35))
    fp = np.where(face_px, np.take(table(fp_tab), lin), fp_plane) * t2
    level = np.frexp(fp)[1]  # fp = m·2^e, m ∈ [0.5, 1): floor(log2 fp) = e − 1
    level -= 1
    np.clip(level, 0, len(atlas.levels) - 1, out=level)
    scale = np.ldexp(f32(1.0), -level)  # 2^−level, exact
    map_x = np.take(atlas.level_x0, level) + ax * scale - f32(0.5)
    map_y = np.take(atlas.level_y0, level) + ay * scale - f32(0.5)
    return Hits(kind, dist, face, (ox, oy, z_m), dx, dy, tan_e, fsel, plane_h, wall_h, glass, map_x, map_y)


def _shade(world: World, hits: Hits) -> np.ndarray:
    """Sample the packed atlas bilinearly: H×W×3 BGR uint8."""
    return cv2.remap(atlas_of(world).packed, hits.map_x, hits.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


# --------------------------------------------------------------------------
# Public renderers
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


def _occluder_world(world: World, occluders: Sequence[Obstacle]) -> World | None:
    occ = tuple(occluders)
    if not occ:
        return None
    for i, o in enumerate(occ):
        if not isinstance(o, Obstacle):
            raise InputError(f"occluders[{i}] must be an Obstacle, got {type(o).__name__}")
    return _occluder_world_cached(world.wall_height_m, world.texture_px_per_m, occ)


@functools.lru_cache(maxsize=16)
def _occluder_world_cached(wall_h: float, ppm: float, occ: tuple[Obstacle, ...]) -> World:
    return World("occluders", (), occ, wall_height_m=wall_h, texture_px_per_m=ppm)


def _cast_all(
    world: World, occluders: Sequence[Obstacle], *args: Any, texture: bool = True
) -> tuple[Hits, np.ndarray | None, np.ndarray | None]:
    """Cast against the world and (separately) the occluders; returns the merged hits and the
    per-pixel choice ``sel`` (True where an occluder is nearer) plus the occluders' image."""
    hits = cast_rays(world, *args, texture=texture)
    ow = _occluder_world(world, occluders)
    if ow is None:
        return hits, None, None
    oh = cast_rays(ow, *args, texture=texture)
    sel = (oh.kind >= _FACE) & (oh.dist < hits.dist)
    if not np.any(sel):
        return hits, None, None
    merged = Hits(
        kind=np.where(sel, oh.kind, hits.kind),
        dist=np.where(sel, oh.dist, hits.dist),
        face=np.where(sel, -1, hits.face),
        origin=hits.origin,
        dx=hits.dx,
        dy=hits.dy,
        tan_e=hits.tan_e,
        face_sel=np.where(sel, oh.face_sel, hits.face_sel),
        plane_h=np.where(sel, oh.plane_h, hits.plane_h),
        wall_h=hits.wall_h,
        glass=hits.glass & ~sel,
        map_x=hits.map_x,
        map_y=hits.map_y,
    )
    return merged, sel, (_shade(ow, oh) if texture else None)


def _image(world: World, hits: Hits, sel: np.ndarray | None, occ_img: np.ndarray | None) -> np.ndarray:
    img = _shade(world, hits)
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
    W = _positive_int("width_px", width_px, 8)
    H = W // 8 if height_px is None else _positive_int("height_px", height_px, 8)
    fov = positive_float("fov_v_rad", fov_v_rad)
    if fov >= math.pi:
        raise InputError(f"fov_v_rad must be < π for a cylindrical panorama, got {fov}")
    az, row_tan = panorama_rays(W, H, fov)
    f = 0.5 * H / math.tan(0.5 * fov)
    ang = np.full(W, max(2.0 * math.pi / W, 1.0 / f))
    hits, sel, occ = _cast_all(
        world, occluders, T_world_robot, positive_float("height_m", height_m), az, row_tan, np.ones(W), ang
    )
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
    hits, sel, occ = _cast_all(world, occluders, T_sensor, camera.height_m, np.arctan(a), b, col_scale, col_scale / f)
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
    hits, _, _ = _cast_all(
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
    n = math.ceil(2.0 * math.pi / depth_camera.hfov_rad) if n_views is None else _positive_int("n_views", n_views)
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


#: Defaults of :func:`render_scan`'s error model: a SICK LMS200-class 2D lidar, the scanner class of the
#: real logs (Intel, ACES, MIT CSAIL), set from those logs' ICP residuals rather than from the datasheet
#: (``benchmarks/bench_lidar_model.py``; ``docs/calibration/icp.md``). The datasheet's statistical error
#: (5 mm, 1σ) and ±15 mm systematic error per surface (SICK LMS200 technical description, mm mode, 1–8 m;
#: later SICK families alike) made simulated residuals too correlated along a wall (lag-1 autocorrelation
#: 0.41 against the logs' 0.11–0.25); 8 mm white and a 4 mm per-surface offset give the logs' residual RMSE
#: (14 mm; logs 11–21 mm) and their autocorrelation (0.27 / 0.15 / 0.07 at lags 1 / 2 / 5; Intel 0.25 /
#: 0.15 / 0.07). Beam divergence 4.6 mrad and 13 mm exit spot: the spot diameter ``d·0.0046 + 0.013`` m of
#: the LMS5xx (HR) operating instructions, §3.5.2.
SCAN_SIGMA_M = 0.008
SCAN_SYSTEMATIC_SIGMA_M = 0.004
SCAN_BEAM_DIVERGENCE_RAD = 0.0046
SCAN_SPOT_EXIT_M = 0.013
#: The sensor-pose error of :func:`render_scan` (1σ per axis and in heading): the pose a real scan was taken from
#: differs from the pose it is stamped with (motion during the sweep, timing, the mount), an error shared by all
#: its beams that no residual shows. Without it the simulated ICP errs half as much as the logs' at the same
#: residuals (median position error 0.82 cm against 0.91–2.57 cm); with it ICP's error on simulated pairs sits
#: among the logs' (median ~2 cm, MIT CSAIL's).
SCAN_POSE_SIGMA_M = 0.014
SCAN_POSE_SIGMA_RAD = math.radians(0.25)
#: Degrees of freedom of that error (Student's t, scaled to the σ above; ``inf``: Gaussian): real scans' errors
#: are heavy-tailed (on MIT CSAIL the mean ICP error is 1.4× the median, the NEES's 99 % quantile 2× χ²'s).
SCAN_POSE_DOF = math.inf


def render_scan(
    world: World,
    T_world_robot: Pose2,
    n_beams: int = 360,
    height_m: float = 0.3,
    max_range_m: float = 10.0,
    sigma_m: float = SCAN_SIGMA_M,
    rng: np.random.Generator | None = None,
    *,
    occluders: Sequence[Obstacle] = (),
    systematic_sigma_m: float = SCAN_SYSTEMATIC_SIGMA_M,
    beam_divergence_rad: float = SCAN_BEAM_DIVERGENCE_RAD,
    spot_exit_m: float = SCAN_SPOT_EXIT_M,
    mixed_min_jump_m: float = 0.05,
    pose_sigma_m: float = SCAN_POSE_SIGMA_M,
    pose_sigma_rad: float = SCAN_POSE_SIGMA_RAD,
    pose_dof: float = SCAN_POSE_DOF,
) -> Scan:
    """A planar laser scan at ``height_m`` above the floor: ``n_beams`` beams over 360°, beam i at azimuth 2π·i/n.

    Returns hits closer than ``max_range_m`` (N×2, robot frame). Glass is
    invisible to it as to the depth camera; obstacles lower than ``height_m``
    are not seen. Without ``rng`` the ranges are exact; with it they carry
    the error model of a real 2D lidar (defaults: SICK LMS200 class, see
    :data:`SCAN_SIGMA_M` and below), whose errors are *not* all white:

    * **statistical error** ``sigma_m`` (m, 1σ): independent Gaussian range
      noise per beam (8 mm: the datasheet's 5 mm and what else a real
      scan's residuals hold, see :data:`SCAN_SIGMA_M`);
    * **systematic error** ``systematic_sigma_m`` (m, 1σ): one Gaussian range
      offset per surface (wall/obstacle face, all occluders together) and
      per scan, shared by every beam that hits that surface in this scan
      (4 mm, see :data:`SCAN_SIGMA_M`).
      The datasheet's ±15 mm systematic error depends on the surface's
      reflectivity, the incidence angle and the range, so a surface seen
      from another pose is offset differently: each scan draws its own
      offsets. A shared offset moves a whole wall, which no amount of beams
      averages out: this is the correlated error the ICP covariance's
      ``bias_rmse_ratio`` term accounts for;
    * **mixed pixels** at depth edges: the spot (diameter
      ``spot_exit_m + beam_divergence_rad·r``) of a beam next to a range jump
      larger than ``mixed_min_jump_m`` straddles the edge with probability
      ``min(1, spot / beam spacing)``; its return is then a range drawn
      uniformly between the near and the far surface (a phantom point in
      free space), as real time-of-flight scanners report.

    * **sensor-pose error** ``pose_sigma_m`` (m, per axis) and ``pose_sigma_rad``: the scan is taken from
      ``T_world_robot · δ`` with one rigid motion δ per scan (Student's t with ``pose_dof`` degrees of
      freedom, scaled to those σ) and returned in the frame of
      ``T_world_robot``: the motion during the sweep, timing and the mount move the real scan as a whole, an
      error that no residual between two scans shows (the real logs' ICP errors are 1–2 cm larger than their
      residuals explain; see :data:`SCAN_POSE_SIGMA_M`).

    Angular errors (encoder jitter) are not modelled: for the scanners
    above they are far below the beam spacing.

    Random numbers: the statistical noise is drawn from ``rng`` exactly as
    before this model existed (``n_beams`` normals, only when
    ``sigma_m > 0``); the systematic offsets and mixed pixels come from a
    child generator (``rng.spawn(1)``), the sensor-pose error from a second one
    (only when its σ are not 0), so ``rng``'s own stream, and hence everything
    a simulator draws after the scan, does not depend on them.
    """
    if not isinstance(T_world_robot, Pose2):
        raise InputError(f"T_world_robot must be a Pose2, got {type(T_world_robot).__name__}")
    n = _positive_int("n_beams", n_beams, 4)
    rmax = positive_float("max_range_m", max_range_m)
    sig = nonnegative_float("sigma_m", sigma_m)
    sig_sys = nonnegative_float("systematic_sigma_m", systematic_sigma_m)
    div = nonnegative_float("beam_divergence_rad", beam_divergence_rad)
    spot0 = nonnegative_float("spot_exit_m", spot_exit_m)
    jump = positive_float("mixed_min_jump_m", mixed_min_jump_m)
    pose_m = nonnegative_float("pose_sigma_m", pose_sigma_m)
    pose_rad = nonnegative_float("pose_sigma_rad", pose_sigma_rad)
    dof = float(pose_dof)
    if not dof > 2.0:
        raise InputError(f"pose_dof must be > 2 (a finite variance), got {pose_dof!r}")
    az = 2.0 * math.pi * np.arange(n) / n
    systematic = rng is not None and (sig_sys > 0 or div > 0 or spot0 > 0)
    moved = rng is not None and (pose_m > 0 or pose_rad > 0)
    # one spawn for both children: the systematic one is the child a single spawn gives (as before this error)
    children = rng.spawn(int(systematic) + int(moved)) if systematic or moved else []
    T_world_sensor = T_world_robot
    if moved:
        g = children[-1]
        # Student's t with pose_dof degrees of freedom, scaled to a standard deviation of 1 (Gaussian when inf)
        u = g.normal(0.0, 1.0, 3) if math.isinf(dof) else g.standard_t(dof, 3) / math.sqrt(dof / (dof - 2.0))
        d = u * np.array([pose_m, pose_m, pose_rad])
        T_world_sensor = T_world_robot * Pose2(float(d[0]), float(d[1]), float(d[2]))
    hits, _, _ = _cast_all(
        world,
        occluders,
        T_world_sensor,
        positive_float("height_m", height_m),
        az,
        np.zeros(1),
        np.ones(n),
        np.full(n, 2 * math.pi / n),
        texture=False,
    )
    r = hits.distance_m[0].copy()
    keep = (hits.kind[0] >= _FACE) & (r < rmax) & ~hits.glass[0]
    if rng is not None and sig > 0:
        r = r + rng.normal(0.0, sig, r.shape)
    if systematic:
        r = _lidar_systematic(r, keep, hits.face[0], children[0], sig_sys, div, spot0, jump, 2 * math.pi / n)
    pts = np.column_stack([r * np.cos(az), r * np.sin(az)])[keep]
    if len(pts) == 0:
        raise InputError(f"the scanner at {T_world_robot} sees nothing within {rmax} m")
    return Scan(pts.astype(np.float32).astype(np.float64))


def _lidar_systematic(
    r: np.ndarray,
    keep: np.ndarray,
    face: np.ndarray,
    rng: np.random.Generator,
    sigma_sys_m: float,
    divergence_rad: float,
    spot_exit_m: float,
    min_jump_m: float,
    spacing_rad: float,
) -> np.ndarray:
    """Per-surface range offsets and mixed pixels of :func:`render_scan` (ranges ``r`` of all n beams, metres)."""
    n = len(r)
    # per-(scan, surface) offset; face −1 (occluders, floor) shares one slot
    slot = face.astype(np.int64) + 1
    offsets = rng.normal(0.0, sigma_sys_m, int(slot.max()) + 1 if n else 1)
    out = r + np.where(keep, offsets[slot], 0.0)
    # mixed pixels: beam i whose neighbour (i±1, cyclic) is nearer by more than min_jump_m, and whose spot
    # reaches over the edge (probability spot/spacing at the edge's range), returns a range in between
    u_mix = rng.random(n)
    u_pos = rng.random(n)
    side = rng.random(n) < 0.5  # which neighbour's edge when both qualify
    nb = np.where(side, np.roll(np.arange(n), 1), np.roll(np.arange(n), -1))
    other = np.where(side, np.roll(np.arange(n), -1), np.roll(np.arange(n), 1))
    near_nb = keep[nb] & (r[nb] < r - min_jump_m)
    nb = np.where(near_nb, nb, other)
    near = keep[nb] & (r[nb] < r - min_jump_m)
    r_edge = r[nb]
    p = np.minimum(1.0, (spot_exit_m + divergence_rad * r_edge) / np.maximum(r_edge * spacing_rad, 1e-9))
    mixed = keep & near & (u_mix < p)
    return np.where(mixed, out[nb] + u_pos * (out - out[nb]), out)

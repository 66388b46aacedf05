"""The vectorised ray caster every renderer of :mod:`factorloc.sim` shares. A sensor's pixel grid is
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
chosen per pixel from the texel footprint.
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import cv2
import numpy as np

from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.sim.determinism import without_ipp
from factorloc.sim.textures import atlas_of
from factorloc.sim.world import Obstacle, World

__all__ = ["CEILING", "FACE", "FLOOR", "TOP", "Hits", "cast_all", "cast_rays", "shade"]

#: Number of nearest segment hits kept per column (enough for a few low obstacles in front of a wall).
_MAX_LAYERS = 6
#: What a ray hit (``Hits.kind``): the floor, the ceiling, a face, the top of a low obstacle.
FLOOR, CEILING, FACE, TOP = 0, 1, 2, 3


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
    ft = np.float32 if texture else np.float64
    layers = _column_layers(seg, ox, oy, dx, dy, wall_h)
    px = _pixels(layers, seg, z_m, wall_h, (row_tan[:, None] * col_scale[None, :]).astype(ft), ft)
    if not texture:
        return Hits(px.kind, px.dist, px.face, (ox, oy, z_m), dx, dy, px.tan_e, px.fsel, px.plane_h, wall_h, px.glass)
    map_x, map_y = _texture_maps(world, seg, layers, px, (ox, oy, z_m), dx, dy, np.asarray(pixel_angle_rad))
    return Hits(px.kind, px.dist, px.face, (ox, oy, z_m), dx, dy, px.tan_e, px.fsel, px.plane_h, wall_h, px.glass, map_x, map_y)


@dataclass(frozen=True, eq=False)
class _Layers:
    """The nearest segment hits of each column, nearest first, up to the first full-height one (Kp layers).

    ``idx``, ``d_tab``, ``hit_ok``, ``h_tab``, ``f_tab``: Kp×W segment index, distance (m), hit, top height (m),
    seen face (−1: an obstacle's top); ``s``: W×S position of each hit along its segment; ``on_left``: S, the
    sensor's side of each segment; ``e``: S×2 segment vectors.
    """

    idx: np.ndarray
    d_tab: np.ndarray
    hit_ok: np.ndarray
    h_tab: np.ndarray
    f_tab: np.ndarray
    s: np.ndarray
    on_left: np.ndarray
    e: np.ndarray


def _column_layers(seg: Any, ox: float, oy: float, dx: np.ndarray, dy: np.ndarray, wall_h: float) -> _Layers:
    """Column rays against all segments (W×S), reduced to the K nearest layers per column."""
    W = dx.shape[0]
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

    # per (layer, column) tables; row Kp (in the pixel stage) is the pseudo-layer "no face: floor or ceiling"
    idx = idx[:, :Kp].T  # Kp×W
    d_tab = tk[:, :Kp].T
    return _Layers(idx, d_tab, np.isfinite(d_tab), seg.height_m[idx], seen_face[idx], s, on_left, e)


@dataclass(frozen=True, eq=False)
class _Pixels:
    """Per pixel (H×W): the layer seen and what it is; ``table`` lays out per-layer values for ``np.take(…, lin)``."""

    tan_e: np.ndarray
    lin: np.ndarray
    is_face_tab: np.ndarray
    pseudo_up: np.ndarray
    fsel: np.ndarray
    dist: np.ndarray
    kind: np.ndarray
    face: np.ndarray
    plane_h: np.ndarray
    glass: np.ndarray
    ft: Any

    def table(self, values: np.ndarray, pseudo_value: float = 0.0, dtype: Any = None) -> np.ndarray:
        return _table(values, self.tan_e.shape[1], self.ft if dtype is None else dtype, pseudo_value)


def _table(values: np.ndarray, width: int, dtype: Any, pseudo_value: float = 0.0) -> np.ndarray:
    """Kp×W per-layer ``values`` and the pseudo-layer's value, flattened for ``np.take`` with the pixels' ``lin``."""
    return np.vstack([values, np.full((1, width), pseudo_value)]).ravel().astype(dtype)


def _pixels(layers: _Layers, seg: Any, z_m: float, wall_h: float, tan_e: np.ndarray, ft: Any) -> _Pixels:
    """Per pixel, the nearest layer whose face spans the pixel's elevation (painter's algorithm), and its hit.

    Branch-free arithmetic on H×W arrays: ``np.where`` / boolean indexing are 10–50× slower here.
    """
    H, W = tan_e.shape
    Kp = layers.idx.shape[0]
    d_tab, hit_ok, h_tab, f_tab = layers.d_tab, layers.hit_ok, layers.h_tab, layers.f_tab
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

    def table(values: np.ndarray, pseudo_value: float = 0.0, dtype: Any = ft) -> np.ndarray:
        return _table(values, W, dtype, pseudo_value)

    fsel = np.take(table(is_face_tab), lin)  # 1 on faces, 0 on floor/ceiling/tops
    # planar pixels: distance = (z_cam − plane height)/(−tan e); faces: the layer's distance
    num = np.take(table(np.where(is_face_tab, 0.0, z_m - h_tab)), lin)
    num += pseudo * ft(z_m) - pseudo_up * ft(wall_h)
    tan_safe = tan_e + (tan_e == 0.0) * ft(1e-12)
    dist = num / -tan_safe + np.take(table(np.where(is_face_tab, d_tab, 0.0)), lin)
    np.clip(dist, 0.0, 1e3, out=dist)

    kind = np.take(table(np.where(is_face_tab, FACE, TOP), FLOOR, np.int8), lin)
    kind += pseudo_up.view(np.int8) * np.int8(CEILING - FLOOR)
    face = np.take(table(np.where(is_face_tab, f_tab, -1), -1, np.int64), lin)
    plane_h = np.take(table(np.where(is_face_tab, 0.0, h_tab)), lin) + pseudo_up * ft(wall_h)
    glass = np.take(table(is_face_tab & seg.face_glass[np.maximum(f_tab, 0)], 0, bool), lin)
    return _Pixels(tan_e, lin, is_face_tab, pseudo_up, fsel, dist, kind, face, plane_h, glass, ft)


def _texture_maps(
    world: World,
    seg: Any,
    layers: _Layers,
    px: _Pixels,
    origin: tuple[float, float, float],
    dx: np.ndarray,
    dy: np.ndarray,
    pixel_angle_rad: np.ndarray,
) -> tuple[np.ndarray, np.ndarray]:
    """Atlas coordinates (float32) of every pixel, at the mip level of its texel footprint."""
    ox, oy, z_m = origin
    idx, d_tab, hit_ok, f_tab, e = layers.idx, layers.d_tab, layers.hit_ok, layers.f_tab, layers.e
    is_face_tab, lin, dist, tan_e, table = px.is_face_tab, px.lin, px.dist, px.tan_e, px.table
    atlas = atlas_of(world)
    ppm = atlas.ppm
    f32 = np.float32
    fsafe = np.maximum(f_tab, 0)
    s_tab = np.take_along_axis(layers.s, idx.T, axis=1).T
    L = seg.face_length_m[fsafe]
    u_m = np.where(layers.on_left[idx], (1.0 - s_tab) * L, s_tab * L)
    ax_tab = np.where(is_face_tab, atlas.face_x0[fsafe] + u_m * ppm, 0.0)
    ay_tab = np.where(is_face_tab, atlas.face_y0[fsafe] + (seg.face_height_m[fsafe] - z_m) * ppm, 0.0)  # − ppm·d·tan e per pixel
    cos_h = np.abs(e[idx, 0] * dy[None, :] - e[idx, 1] * dx[None, :]) / np.hypot(e[idx, 0], e[idx, 1])
    fp_tab = np.where(is_face_tab, ppm * pixel_angle_rad[None, :] * np.where(hit_ok, d_tab, 0.0) / np.clip(cos_h, 0.35, 1.0), 0.0)
    dist_t = dist * tan_e
    # tiles: 0 floor, 1 ceiling, 2 + k top of obstacle k (face pixels get tile 0: finite, then discarded)
    tile = np.take(table(np.where(is_face_tab, 0, 2 + seg.obstacle[idx]), 0, np.intp), lin) + px.pseudo_up
    tppm = np.take(atlas.tile_ppm.astype(f32), tile)
    tpx = np.take(atlas.tile_px.astype(f32), tile)
    xs = (f32(ox) + dist * dx.astype(f32)[None, :]) * tppm
    ys = (f32(-oy) - dist * dy.astype(f32)[None, :]) * tppm
    ax_t = np.take(atlas.tile_x0.astype(f32), tile) + xs - np.floor(xs / tpx) * tpx
    ay_t = np.take(atlas.tile_y0.astype(f32), tile) + ys - np.floor(ys / tpx) * tpx
    face_px = px.fsel > 0.5
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
    return map_x, map_y


def shade(world: World, hits: Hits) -> np.ndarray:
    """Sample the packed atlas bilinearly: H×W×3 BGR uint8 (without IPP: see :mod:`factorloc.sim.determinism`)."""
    with without_ipp():
        return cv2.remap(atlas_of(world).packed, hits.map_x, hits.map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


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


def cast_all(
    world: World, occluders: Sequence[Obstacle], *args: Any, texture: bool = True
) -> tuple[Hits, np.ndarray | None, np.ndarray | None]:
    """Cast against the world and (separately) the occluders; returns the merged hits and the
    per-pixel choice ``sel`` (True where an occluder is nearer) plus the occluders' image."""
    hits = cast_rays(world, *args, texture=texture)
    ow = _occluder_world(world, occluders)
    if ow is None:
        return hits, None, None
    oh = cast_rays(ow, *args, texture=texture)
    sel = (oh.kind >= FACE) & (oh.dist < hits.dist)
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
    return merged, sel, (shade(ow, oh) if texture else None)

"""Textures of the simulated world, made from real photographs bundled with scikit-image.

Base textures (tiled over a face) come from ``skimage.data`` photographs of
real surfaces — ``brick``, ``gravel``, ``grass``, ``moon`` (plaster), ``coins``,
``hubble_deep_field`` (``stars``), ``immunohistochemistry`` (``wallpaper``) —
plus a few patterns built from them (``tiles``, ``wood``, ``parquet``) and two
nearly uniform paints (``plain``, ``ceiling``) for low-texture walls. Decals
(posters, doors, windows, a bookshelf) are photographs (``astronaut``,
``coffee``, ``chelsea``, ``rocket``, …) or patterns. Every image used here is
part of the scikit-image wheel (no download).

All faces of a world are baked once into a texture *atlas* (a mip pyramid of
BGR uint8 images, level ``l`` at ``texture_px_per_m / 2**l`` texels per
metre) that the renderers sample with :func:`cv2.remap`. Baking is
deterministic: the only noise is drawn from generators with fixed seeds.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from factorloc.errors import InputError
from factorloc.sim.world import Decal, Material, World

#: Names accepted by :attr:`Material.texture`.
BASE_TEXTURES = (
    "plain",
    "ceiling",
    "brick",
    "gravel",
    "grass",
    "moon",
    "coins",
    "stars",
    "wallpaper",
    "tiles",
    "wood",
    "parquet",
    "carpet",
)
#: Names accepted by :attr:`Decal.image`.
DECAL_IMAGES = (
    "astronaut",
    "coffee",
    "chelsea",
    "cat",
    "rocket",
    "camera",
    "clock",
    "hubble",
    "page",
    "text",
    "colorwheel",
    "retina",
    "moon",
    "coins",
    "logo",
    "immunohistochemistry",
    "door",
    "window",
    "bookshelf",
    "whiteboard",
)

_PAD = 4  # texels of border around every atlas entry
_LEVELS = 4  # mip levels
_ATLAS_WIDTH = 4096


def _skimage(name: str) -> np.ndarray:
    import skimage.data

    img = getattr(skimage.data, name)()
    if img.dtype == bool:
        img = img.astype(np.uint8) * 255
    if img.ndim == 2:
        return cv2.cvtColor(img, cv2.COLOR_GRAY2BGR)
    if img.shape[2] == 4:  # RGBA on white
        alpha = img[:, :, 3:4].astype(np.float32) / 255.0
        rgb = img[:, :, :3].astype(np.float32) * alpha + 255.0 * (1.0 - alpha)
        img = rgb.astype(np.uint8)
    return cv2.cvtColor(img, cv2.COLOR_RGB2BGR)


def _gray(name: str) -> np.ndarray:
    import skimage.data

    return getattr(skimage.data, name)()


@functools.cache
def base_texture(name: str) -> np.ndarray:
    """A square BGR uint8 tile of base texture ``name`` (read-only)."""
    if name not in BASE_TEXTURES:
        raise InputError(f"Material.texture must be one of {BASE_TEXTURES}, got {name!r}")
    rng = np.random.default_rng(BASE_TEXTURES.index(name) + 1000)
    if name in ("plain", "ceiling"):
        level = 205.0 if name == "plain" else 232.0
        noise = cv2.GaussianBlur(rng.normal(0.0, 1.0, (256, 256)).astype(np.float32), (0, 0), 3.0)
        tile = level + 2.5 * noise / max(float(noise.std()), 1e-6)
        out = np.repeat(tile[:, :, None], 3, axis=2)
    elif name in ("brick", "gravel", "grass", "moon", "coins"):
        out = _skimage(name).astype(np.float32)
        if name == "coins":
            out = out[:, : out.shape[0]]
        # stretch to a wall-like brightness: mean 160, keep the real contrast
        out = 160.0 + (out - out.mean()) * (45.0 / max(float(out.std()), 1e-6))
    elif name == "stars":
        out = _skimage("hubble_deep_field")[:800, :800].astype(np.float32)
    elif name == "wallpaper":
        out = _skimage("immunohistochemistry").astype(np.float32) * 0.9 + 20.0
    elif name == "tiles":
        grain = _gray("gravel").astype(np.float32)
        grain = (grain - grain.mean()) / grain.std()
        out = 215.0 + 6.0 * grain
        grout = np.zeros((512, 512), bool)
        for k in range(0, 512, 128):
            grout[k : k + 5, :] = True
            grout[:, k : k + 5] = True
        out[grout] = 120.0
        out = np.repeat(out[:, :, None], 3, axis=2)
    elif name in ("wood", "parquet"):
        grain = cv2.resize(_gray("gravel").astype(np.float32), (512, 512))
        grain = (grain - grain.mean()) / grain.std()
        yy = np.arange(512, dtype=np.float32)[:, None]
        xx = np.arange(512, dtype=np.float32)[None, :]
        rings = np.sin(2 * np.pi * (xx / 37.0 + 0.35 * grain + 0.002 * yy))
        lum = 150.0 + 25.0 * rings + 10.0 * grain
        if name == "parquet":
            plank = (xx // 64).astype(int)
            offset = (plank * 197) % 512
            lum = lum + 12.0 * np.sin(plank * 2.1)
            seams = (np.mod(yy + offset, 512) < 3) | (np.mod(xx, 64) < 2)
            lum = np.where(seams, 80.0, lum)
        out = np.stack([lum * 0.55, lum * 0.75, lum * 1.0], axis=2)
    elif name == "carpet":
        grain = _gray("grass").astype(np.float32)
        out = 120.0 + (grain - grain.mean()) * 0.5
        out = np.repeat(out[:, :, None], 3, axis=2)
    else:  # pragma: no cover - guarded above
        raise InputError(f"unknown texture {name!r}")
    tile = np.clip(out, 0, 255).astype(np.uint8)
    tile.setflags(write=False)
    return tile


@functools.cache
def decal_image(name: str) -> np.ndarray:
    """The BGR uint8 picture of decal ``name`` (read-only)."""
    if name not in DECAL_IMAGES:
        raise InputError(f"Decal.image must be one of {DECAL_IMAGES}, got {name!r}")
    rng = np.random.default_rng(DECAL_IMAGES.index(name) + 2000)
    if name == "hubble":
        img = _skimage("hubble_deep_field")
    elif name == "door":
        wood = base_texture("wood")
        img = cv2.rotate(cv2.resize(wood, (256, 512)), cv2.ROTATE_180).astype(np.float32) * 0.85
        img[:, :14] *= 0.6
        img[:, -14:] *= 0.6
        img[:14] *= 0.6
        for y0, y1 in ((60, 230), (290, 470)):  # two recessed panels
            img[y0:y1, 40:216] *= 0.88
            img[y0 : y0 + 4, 40:216] *= 0.7
            img[y1 - 4 : y1, 40:216] *= 1.15
        cv2.circle(img, (215, 280), 9, (60, 160, 200), -1)  # brass knob
        img = np.clip(img, 0, 255)
    elif name == "window":
        h, w = 400, 300
        sky = np.linspace(255, 190, h, dtype=np.float32)[:, None] * np.ones((1, w), np.float32)
        clouds = cv2.GaussianBlur(cv2.resize(_gray("gravel").astype(np.float32), (w, h)), (0, 0), 6.0)
        clouds = (clouds - clouds.mean()) / clouds.std()
        img = np.stack([sky, sky * 0.9 + 8 * clouds, sky * 0.75 + 15 * clouds], axis=2)
        img[:, :12] = img[:, -12:] = 235
        img[:12] = img[-12:] = 235
        img[:, w // 2 - 5 : w // 2 + 5] = 235
        img[h // 2 - 5 : h // 2 + 5] = 235
        img = np.clip(img, 0, 255)
    elif name == "bookshelf":
        h, w = 512, 512
        img = np.full((h, w, 3), 70.0, np.float32)
        for r in range(5):
            y0, y1 = 10 + r * 100, 10 + r * 100 + 88
            x = 8
            while x < w - 8:
                bw = int(rng.integers(10, 34))
                top = y0 + int(rng.integers(0, 25))
                col = rng.uniform(40, 230, 3)
                img[top:y1, x : min(x + bw, w - 8)] = col
                img[top + 8 : top + 14, x + 2 : min(x + bw, w - 8) - 2] = col * 0.5 + 110
                x += bw + int(rng.integers(0, 3))
            img[y1 : y1 + 12] = (60, 90, 130)
        img = np.clip(img, 0, 255)
    elif name == "whiteboard":
        txt = _gray("text").astype(np.float32)
        txt = cv2.resize(txt, (600, 240))
        img = np.full((320, 640, 3), 235.0, np.float32)
        img[40:280, 20:620] = np.repeat((235.0 - 0.8 * (255.0 - txt))[:, :, None], 3, axis=2)
        img[:8] = img[-8:] = 150
        img[:, :8] = img[:, -8:] = 150
    else:
        img = _skimage(name)
    out = np.ascontiguousarray(np.asarray(img).astype(np.uint8))
    out.setflags(write=False)
    return out


def _tinted_tile(material: Material, ppm: float) -> np.ndarray:
    tp = max(4, int(round(material.tile_m * ppm)))
    base = base_texture(material.texture)
    interp = cv2.INTER_AREA if tp < base.shape[0] else cv2.INTER_LINEAR
    tile = cv2.resize(base, (tp, tp), interpolation=interp).astype(np.float32)
    return tile * np.asarray(material.tint_bgr, np.float32)


def _bake_face(
    material: Material, decals: tuple[Decal, ...], length_m: float, height_m: float, ppm: float, shade: float, skirting: bool
) -> np.ndarray:
    w = max(2, int(round(length_m * ppm)))
    h = max(2, int(round(height_m * ppm)))
    tile = _tinted_tile(material, ppm)
    reps = (math.ceil(h / tile.shape[0]), math.ceil(w / tile.shape[1]), 1)
    img = np.tile(tile, reps)[:h, :w].copy()
    for d in decals:
        c0, c1 = int(round(d.u0_m * ppm)), int(round(d.u1_m * ppm))
        r0, r1 = int(round((height_m - d.z1_m) * ppm)), int(round((height_m - d.z0_m) * ppm))
        if c1 - c0 < 1 or r1 - r0 < 1:
            continue
        pic = cv2.resize(decal_image(d.image), (c1 - c0, r1 - r0), interpolation=cv2.INTER_AREA).astype(np.float32)
        cc0, cc1, rr0, rr1 = max(c0, 0), min(c1, w), max(r0, 0), min(r1, h)
        if cc1 > cc0 and rr1 > rr0:
            img[rr0:rr1, cc0:cc1] = pic[rr0 - r0 : rr1 - r0, cc0 - c0 : cc1 - c0]
    if skirting:
        sk = max(1, int(round(0.08 * ppm)))
        img[h - sk :] = img[h - sk :] * 0.55 + 40.0
        img[h - sk : h - sk + 1] *= 0.7
    return np.clip(img * shade, 0, 255).astype(np.uint8)


@dataclass(frozen=True, eq=False)
class Atlas:
    """All textures of a world in one mip pyramid.

    ``levels[l]`` is a BGR uint8 image at ``ppm / 2**l`` texels per metre.
    Face ``f`` occupies level-0 texels ``[face_x0[f], face_x0[f] + length·ppm) ×
    [face_y0[f], face_y0[f] + height·ppm)``; tile ``t`` (0 = floor, 1 = ceiling,
    2 + k = top of obstacle k) occupies a ``tile_px[t]``-square that repeats
    every ``tile_m[t]`` metres. Coordinates are in texel units, edge-based.
    ``packed`` holds all levels in one image (level ``l`` at ``level_x0[l], level_y0[l]``)
    so that one :func:`cv2.remap` samples every level.
    """

    levels: tuple[np.ndarray, ...]
    packed: np.ndarray
    level_x0: np.ndarray
    level_y0: np.ndarray
    ppm: float
    face_x0: np.ndarray
    face_y0: np.ndarray
    tile_x0: np.ndarray
    tile_y0: np.ndarray
    tile_px: np.ndarray
    tile_ppm: np.ndarray


def _shade_of(p0: np.ndarray, p1: np.ndarray, side: int) -> float:
    e = p1 - p0
    n = np.array([-e[1], e[0]]) * side
    n = n / max(float(np.linalg.norm(n)), 1e-12)
    light = np.array([0.8, 0.6])
    return 0.82 + 0.18 * float(n @ light)


@functools.lru_cache(maxsize=8)
def atlas_of(world: World) -> Atlas:
    """Bake (once per world, cached) every face, the floor, the ceiling and the obstacle tops."""
    ppm = world.texture_px_per_m
    seg = world.segments
    entries: list[tuple[np.ndarray, str]] = []  # image, border mode
    face_images: list[np.ndarray | None] = [None] * len(seg.faces)
    for s in range(seg.count):
        for side, fidx in ((1, seg.face_left[s]), (-1, seg.face_right[s])):
            if fidx < 0:
                continue
            face = seg.faces[fidx]
            face_images[fidx] = _bake_face(
                face.material,
                face.decals,
                float(seg.face_length_m[fidx]),
                float(seg.face_height_m[fidx]),
                ppm,
                _shade_of(seg.p0[s], seg.p1[s], side),
                skirting=bool(seg.obstacle[s] < 0),
            )
    for img in face_images:
        entries.append((img, "replicate"))
    tiles = [(world.floor, 0.95), (world.ceiling, 1.0)] + [(ob.top, 0.97) for ob in world.obstacles]
    for mat, shade in tiles:
        entries.append((np.clip(_tinted_tile(mat, ppm) * shade, 0, 255).astype(np.uint8), "wrap"))

    # shelf packing; every entry starts at a multiple of 2**(LEVELS-1) so mip levels align
    align = 2 ** (_LEVELS - 1)
    x = y = shelf_h = 0
    pos: list[tuple[int, int]] = []
    for img, _ in entries:
        h, w = img.shape[:2]
        ew, eh = _round_up(w + 2 * _PAD, align), _round_up(h + 2 * _PAD, align)
        if ew > _ATLAS_WIDTH:
            raise InputError(
                f"World({world.name}): a face of {w / ppm:.1f} m is too long for the texture atlas; "
                "split the wall or lower texture_px_per_m"
            )
        if x + ew > _ATLAS_WIDTH:
            x, y, shelf_h = 0, y + shelf_h, 0
        pos.append((x, y))
        x += ew
        shelf_h = max(shelf_h, eh)
    atlas = np.zeros((_round_up(y + shelf_h, align), _ATLAS_WIDTH, 3), np.uint8)
    for (img, mode), (ex, ey) in zip(entries, pos, strict=True):
        border = cv2.BORDER_WRAP if mode == "wrap" else cv2.BORDER_REPLICATE
        padded = cv2.copyMakeBorder(img, _PAD, _PAD, _PAD, _PAD, border)
        atlas[ey : ey + padded.shape[0], ex : ex + padded.shape[1]] = padded
    levels = [atlas]
    for _ in range(1, _LEVELS):
        prev = levels[-1]
        levels.append(cv2.resize(prev, (prev.shape[1] // 2, prev.shape[0] // 2), interpolation=cv2.INTER_AREA))
    h0, w0 = levels[0].shape[:2]
    packed = np.zeros((h0 + levels[1].shape[0], w0, 3), np.uint8)
    packed[:h0] = levels[0]
    lx, ly = [0], [0]
    x = 0
    for lv in levels[1:]:
        lx.append(x)
        ly.append(h0)
        packed[h0 : h0 + lv.shape[0], x : x + lv.shape[1]] = lv
        x += lv.shape[1]
    for lv in (*levels, packed):
        lv.setflags(write=False)
    nf = len(face_images)
    xs = np.array([p[0] + _PAD for p in pos], np.float64)
    ys = np.array([p[1] + _PAD for p in pos], np.float64)
    tile_imgs = [e[0] for e in entries[nf:]]
    return Atlas(
        levels=tuple(levels),
        packed=packed,
        level_x0=np.array(lx, np.float32),
        level_y0=np.array(ly, np.float32),
        ppm=ppm,
        face_x0=xs[:nf],
        face_y0=ys[:nf],
        tile_x0=xs[nf:],
        tile_y0=ys[nf:],
        tile_px=np.array([t.shape[1] for t in tile_imgs], np.float64),
        tile_ppm=np.array([t.shape[1] / m.tile_m for t, (m, _) in zip(tile_imgs, tiles, strict=True)], np.float64),
    )


def _round_up(v: int, m: int) -> int:
    return ((v + m - 1) // m) * m

"""Real 360° photographs as test material for the camera steps, with exact heading truth.

An *equirectangular* photograph (H×W, columns linear in azimuth over 360°,
rows linear in elevation from +90° at the top to −90° at the bottom) is
treated as the sphere of directions seen from one point. From it we resample

* the reference :class:`~factorloc.types.Panorama` (a cylindrical band around
  the horizon, columns linear in azimuth, rows ``elevation = atan((H/2 − v)/f)``,
  exactly the conventions documented in :mod:`factorloc.types`), and
* query pinhole :class:`~factorloc.types.CameraImage` views, or rotated query
  panoramas, of a robot standing at the same point with a known heading.

Frame of the photograph: pixel column ``u_e`` (pixel centre) looks at azimuth
``π − 2π·u_e/W_e`` (counter-clockwise, REP-103, so azimuth decreases to the
right as in the :class:`Panorama` convention), row ``v_e`` at elevation
``π/2 − π·(v_e + ½)/H_e``. The reference robot has heading 0 in this frame, so
the heading truth of a query is the ``heading_rad`` it was cut at. There is no
parallax: these views test appearance changes, not motion.

Photometric faults (:func:`photometric`) and occlusions (:func:`occlude`)
return new images; inputs are never modified. The resampling itself is public in
:mod:`factorloc.vision.panoramas` (:func:`load_equirectangular`, ``reference_panorama`` =
:func:`~factorloc.vision.panoramas.panorama_from_equirectangular`, ``camera_view`` =
:func:`~factorloc.vision.panoramas.camera_view_from_equirectangular`), re-exported here.
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from factorloc._validate import bgr_image, nonnegative_float, positive_float
from factorloc.errors import InputError
from factorloc.types import Panorama
from factorloc.vision.panoramas import camera_view_from_equirectangular as camera_view
from factorloc.vision.panoramas import load_equirectangular
from factorloc.vision.panoramas import panorama_from_equirectangular as reference_panorama

__all__ = [
    "load_equirectangular",
    "synthetic_equirectangular",
    "reference_panorama",
    "camera_view",
    "panorama_view",
    "photometric",
    "occlude",
]


def synthetic_equirectangular(
    height_px: int = 256,
    *,
    rng: np.random.Generator | None = None,
    period: int = 1,
) -> np.ndarray:
    """A procedural equirectangular "photo" (H×2H×3 BGR uint8) of random coloured blobs and bars.

    Multi-scale smoothed noise plus random rectangles, seamless across the
    ±180° edge. With ``period = p > 1`` the pattern repeats ``p`` times
    around the circle (an ambiguous scene for heading estimators).
    """
    h = int(positive_float("height_px", height_px))
    p = int(positive_float("period", period))
    r = rng or np.random.default_rng()
    w = 2 * h
    if w % p:
        raise InputError(f"period must divide the width {w}, got {p}")
    wp = w // p
    img = np.zeros((h, wp, 3), np.float32)
    for scale in (4, 16, 48):
        noise = r.normal(0.0, 1.0, (h, wp, 3)).astype(np.float32)
        noise = cv2.copyMakeBorder(noise, 0, 0, wp, wp, cv2.BORDER_WRAP)
        noise = cv2.GaussianBlur(noise, (0, 0), scale / 4.0)[:, wp : 2 * wp]
        img += noise / (noise.std() + 1e-6) * 40.0
    for _ in range(12 * max(1, 4 // p)):
        x0, y0 = int(r.integers(0, wp)), int(r.integers(0, h))
        bw, bh = int(r.integers(4, max(5, wp // 8))), int(r.integers(4, h // 3))
        cols = np.mod(np.arange(x0, x0 + bw), wp)
        img[y0 : y0 + bh, cols] += r.uniform(-90.0, 90.0, 3).astype(np.float32)
    img = np.tile(img, (1, p, 1)) + 128.0
    return np.clip(img, 0, 255).astype(np.uint8)


def panorama_view(
    equirect_bgr: np.ndarray,
    heading_rad: float,
    width_px: int = 1024,
    height_px: int = 160,
    fov_v_rad: float = math.radians(60.0),
) -> Panorama:
    """A query panorama of a robot with heading ``heading_rad`` (rad, photo frame) at the photo's point."""
    return reference_panorama(equirect_bgr, width_px, height_px, fov_v_rad, heading_rad=heading_rad)


def photometric(
    image_bgr: np.ndarray,
    *,
    gain: float = 1.0,
    gamma: float = 1.0,
    noise_sigma: float = 0.0,
    blur_sigma_px: float = 0.0,
    rng: np.random.Generator | None = None,
) -> np.ndarray:
    """A photometrically changed copy: ``255·gain·(I/255)^gamma``, Gaussian blur, additive Gaussian noise.

    Parameters
    ----------
    image_bgr
        H×W×3 BGR uint8.
    gain, gamma
        Brightness gain (> 0) and gamma (> 0) applied in that order.
    noise_sigma
        Standard deviation of additive noise in grey levels (0..255 scale).
    blur_sigma_px
        Standard deviation of the Gaussian blur in pixels (0 = none).
    rng
        Random generator for the noise (default: a fresh unseeded one).
    """
    img = bgr_image("image_bgr", image_bgr).astype(np.float32) / 255.0
    g = positive_float("gain", gain)
    gm = positive_float("gamma", gamma)
    ns = nonnegative_float("noise_sigma", noise_sigma)
    bs = nonnegative_float("blur_sigma_px", blur_sigma_px)
    out = 255.0 * g * np.power(img, gm)
    if bs > 0.0:
        out = cv2.GaussianBlur(out, (0, 0), bs)
    if ns > 0.0:
        out = out + (rng or np.random.default_rng()).normal(0.0, ns, out.shape).astype(np.float32)
    return np.clip(np.rint(out), 0, 255).astype(np.uint8)


def occlude(
    image_bgr: np.ndarray,
    fraction: float,
    *,
    rng: np.random.Generator | None = None,
    n_blocks: int = 1,
) -> np.ndarray:
    """A copy with ``n_blocks`` random full-height or rectangular occluders covering ≈ ``fraction`` of the area.

    Each occluder is a flat random colour with mild noise (a person, a door, a
    box in front of the camera). ``fraction`` in [0, 1).
    """
    img = bgr_image("image_bgr", image_bgr).copy()
    frac = nonnegative_float("fraction", fraction)
    if frac >= 1.0:
        raise InputError(f"fraction must be in [0, 1), got {frac!r}")
    if int(n_blocks) < 1:
        raise InputError(f"n_blocks must be >= 1, got {n_blocks!r}")
    r = rng or np.random.default_rng()
    h, w = img.shape[:2]
    per_block = frac / int(n_blocks)
    for _ in range(int(n_blocks)):
        if per_block <= 0.0:
            break
        bh = int(round(h * min(1.0, math.sqrt(per_block) * r.uniform(1.0, 1.6))))
        bw = int(round(per_block * h * w / max(bh, 1)))
        bw, bh = min(max(bw, 1), w), min(max(bh, 1), h)
        x0 = int(r.integers(0, w - bw + 1))
        y0 = int(r.integers(0, h - bh + 1))
        colour = r.integers(0, 256, 3)
        block = np.clip(colour + r.normal(0.0, 6.0, (bh, bw, 3)), 0, 255)
        img[y0 : y0 + bh, x0 : x0 + bw] = block.astype(np.uint8)
    return img

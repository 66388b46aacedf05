"""Building a reference :class:`~factorloc.Panorama`: from an equirectangular 360° photo, or from pinhole views.

**From pinhole views taken at known yaws** (:func:`panorama_from_images`, also
:meth:`factorloc.Panorama.from_images`). A robot without a 360° camera makes its
reference as the patent's robot does (WO 2015/158682): it turns its head, or its
body, on the spot and takes pictures at known yaws. Each view is resampled onto the
cylindrical grid of the panorama (the conventions of :class:`~factorloc.Panorama`:
``azimuth(u) = azimuth_col0_rad − 2π·u/W``, rows at elevation ``atan((H/2 − v)/f)``),
overlaps are blended with feathered weights (each view's weight falls linearly to zero at
its left and right borders, Szeliski 2006, "Image alignment and stitching", §6.2) after a
per-view gain compensation (Brown & Lowe 2007, "Automatic panoramic image stitching
using invariant features", §6), and the columns no view covers from top to bottom
are marked unseen (``Panorama.seen_columns``): the camera steps ignore them.

**From an equirectangular photo** (H×W, columns linear in azimuth over 360°, rows linear in
elevation from +90° at the top to −90° at the bottom; a 360° camera's native output):
:func:`panorama_from_equirectangular` resamples the band around the horizon and
:func:`camera_view_from_equirectangular` cuts a pinhole view. Photo column ``u_e``
(pixel centre) looks at azimuth ``π − 2π·u_e/W_e`` (counter-clockwise, so azimuth
decreases to the right as in the panorama), row ``v_e`` at elevation ``π/2 − π·(v_e + ½)/H_e``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path

import cv2
import numpy as np

from factorloc._validate import bgr_image, finite_float, positive_float
from factorloc.errors import InputError
from factorloc.geometry import wrap_angle
from factorloc.types import CameraImage, Panorama

__all__ = [
    "camera_view_from_equirectangular",
    "load_equirectangular",
    "panorama_from_equirectangular",
    "panorama_from_images",
]


# --------------------------------------------------------------------------
# Equirectangular photos
# --------------------------------------------------------------------------
def load_equirectangular(path: str | Path) -> np.ndarray:
    """Read an equirectangular photograph as a BGR uint8 array (H×W×3, W = 2H expected).

    Raises
    ------
    InputError
        When the file is missing, unreadable, or not a 2:1 colour image.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"equirectangular photo not found: {p}")
    image = cv2.imread(str(p), cv2.IMREAD_COLOR)
    if image is None:
        raise InputError(f"equirectangular photo {p} could not be decoded as an image")
    h, w = image.shape[:2]
    if abs(w - 2 * h) > 1:
        raise InputError(f"equirectangular photo {p} must be 2:1 (W = 2H), got {w}×{h}")
    return image


def _sample_sphere(equirect_bgr: np.ndarray, azimuth_rad: np.ndarray, elevation_rad: np.ndarray) -> np.ndarray:
    """Bilinear lookup of directions (azimuth CCW, elevation up; same-shape float arrays) in the photo."""
    he, we = equirect_bgr.shape[:2]
    pad = 2
    # horizontal wrap-around by padding columns; rows are clamped (poles)
    padded = cv2.copyMakeBorder(equirect_bgr, pad, pad, pad, pad, cv2.BORDER_WRAP)
    padded[:pad] = padded[pad]
    padded[-pad:] = padded[-pad - 1]
    u = np.mod((math.pi - azimuth_rad) * we / (2.0 * math.pi), we)
    v = (math.pi / 2.0 - elevation_rad) * he / math.pi - 0.5
    map_x = (u + pad).astype(np.float32)
    map_y = (np.clip(v, -0.5, he - 0.5) + pad).astype(np.float32)
    return cv2.remap(padded, map_x, map_y, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)


def _checked(equirect_bgr: np.ndarray, width_px: int, height_px: int, fov_name: str, fov: float) -> tuple:
    """The photo, the output size and a field of view (< π), validated."""
    eq = bgr_image("equirect_bgr", equirect_bgr)
    w = int(positive_float("width_px", width_px))
    h = int(positive_float("height_px", height_px))
    f = positive_float(fov_name, fov)
    if f >= math.pi:
        raise InputError(f"{fov_name} must be < π, got {f!r}")
    return eq, w, h, f


def panorama_from_equirectangular(
    equirect_bgr: np.ndarray,
    width_px: int = 1024,
    height_px: int = 160,
    fov_v_rad: float = math.radians(60.0),
    heading_rad: float = 0.0,
    azimuth_col0_rad: float = math.pi,
) -> Panorama:
    """Resample an equirectangular photo into a cylindrical :class:`~factorloc.Panorama`.

    Parameters
    ----------
    equirect_bgr
        Equirectangular photo, H×W×3 BGR uint8.
    width_px, height_px
        Size of the panorama (columns cover 360°, rows cover ``fov_v_rad``).
    fov_v_rad
        Vertical field of view of the cylindrical band (rad, < π).
    heading_rad
        Heading of the robot in the photo's frame (rad, CCW); 0 for the reference.
    azimuth_col0_rad
        Robot-frame azimuth of column 0 (default π: the centre column looks forward).

    Returns
    -------
    Panorama
        ``azimuth(u) = azimuth_col0_rad − 2π·u/W`` in the robot frame, which is
        ``heading_rad + azimuth(u)`` in the photo's frame.
    """
    eq, w, h, fov = _checked(equirect_bgr, width_px, height_px, "fov_v_rad", fov_v_rad)
    f = (h / 2.0) / math.tan(fov / 2.0)
    u = np.arange(w, dtype=np.float64)
    v = np.arange(h, dtype=np.float64)
    az = finite_float("heading_rad", heading_rad) + finite_float("azimuth_col0_rad", azimuth_col0_rad) - 2.0 * math.pi * u / w
    el = np.arctan((h / 2.0 - v) / f)
    az_grid, el_grid = np.meshgrid(az, el)
    return Panorama(_sample_sphere(eq, az_grid, el_grid), fov_v_rad=fov, azimuth_col0_rad=azimuth_col0_rad)


def camera_view_from_equirectangular(
    equirect_bgr: np.ndarray,
    heading_rad: float,
    yaw_in_robot_rad: float = 0.0,
    hfov_rad: float = math.radians(57.0),
    width_px: int = 640,
    height_px: int = 480,
    pitch_rad: float = 0.0,
) -> CameraImage:
    """A pinhole view from the photo's point: a robot of heading ``heading_rad``, its camera along ``yaw_in_robot_rad``.

    Pixel ``(u, v)`` with principal point ``((W−1)/2, (H−1)/2)`` and focal
    ``f = (W/2)/tan(hfov/2)`` looks along ``(f, cx − u, cy − v)`` in the camera
    frame (x forward, y left, z up), tilted by ``pitch_rad`` (positive up),
    then rotated by ``heading_rad + yaw_in_robot_rad`` about z.

    Returns
    -------
    CameraImage
        With ``hfov_rad``, ``yaw_in_robot_rad`` and ``pitch_rad`` set, so that
        :meth:`CameraImage.azimuth_of_column` + ``heading_rad`` is the photo-frame
        azimuth of a column's centre ray (exact at pitch 0).
    """
    eq, w, h, fov = _checked(equirect_bgr, width_px, height_px, "hfov_rad", hfov_rad)
    heading = finite_float("heading_rad", heading_rad)
    yaw = finite_float("yaw_in_robot_rad", yaw_in_robot_rad)
    pitch = finite_float("pitch_rad", pitch_rad)
    f = 0.5 * w / math.tan(0.5 * fov)
    cx, cy = (w - 1) / 2.0, (h - 1) / 2.0
    uu, vv = np.meshgrid(np.arange(w, dtype=np.float64), np.arange(h, dtype=np.float64))
    x, y, z = np.full_like(uu, f), cx - uu, cy - vv
    cp, sp = math.cos(pitch), math.sin(pitch)
    x, z = x * cp - z * sp, x * sp + z * cp
    az = heading + yaw + np.arctan2(y, x)
    el = np.arctan2(z, np.hypot(x, y))
    return CameraImage(_sample_sphere(eq, az, el), hfov_rad=fov, yaw_in_robot_rad=yaw, pitch_rad=pitch)


# --------------------------------------------------------------------------
# Stitching pinhole views
# --------------------------------------------------------------------------
def _default_fov_v(images: Sequence[CameraImage]) -> float:
    """The band every view covers across its whole width: ``2·(atan(tan(vfov/2)·cos(hfov/2)) − |pitch|)``, smallest view."""
    half = min(math.atan(math.tan(0.5 * im.vfov_rad) * math.cos(0.5 * im.hfov_rad)) - abs(im.pitch_rad) for im in images)
    if half <= math.radians(1.0):
        raise InputError("the views are pitched too far to share a horizontal band: give fov_v_rad")
    return 2.0 * half


def _project(
    image: CameraImage, heading_rad: float, az_cols: np.ndarray, elev_rows: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """Columns of the grid the view covers, its colours there (h×n×3 float32) and its feathered weights (h×n)."""
    f, cx = image.focal_px, image.principal_x_px
    h, w = image.height_px, image.width_px
    cy = (h - 1) / 2.0
    alpha = wrap_angle(az_cols - heading_rad - image.yaw_in_robot_rad)
    reach = 0.5 * image.hfov_rad + math.atan(abs(cx - (w - 1) / 2.0) / f) + 0.05
    cols = np.flatnonzero(np.abs(alpha) < min(reach, 0.5 * math.pi - 1e-3))
    if cols.size == 0:
        return None
    a = alpha[cols]
    ca, sa = np.cos(a)[None, :], np.sin(a)[None, :]
    ce, se = np.cos(elev_rows)[:, None], np.sin(elev_rows)[:, None]
    x, y, z = ce * ca, ce * sa, np.broadcast_to(se, (elev_rows.size, cols.size))
    cp, sp = math.cos(image.pitch_rad), math.sin(image.pitch_rad)
    xc, zc = x * cp + z * sp, -x * sp + z * cp
    with np.errstate(divide="ignore", invalid="ignore"):
        u = cx - f * y / xc
        v = cy - f * zc / xc
    valid = (xc > 1e-6) & (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    map_x = np.where(valid, u, -1).astype(np.float32)
    map_y = np.where(valid, v, -1).astype(np.float32)
    colour = cv2.remap(image.image_bgr.astype(np.float32), map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    weight = np.where(valid, np.minimum(u + 0.5, w - 0.5 - u), 0.0).astype(np.float32)
    return cols, colour, weight


def _gains(parts: list[tuple[np.ndarray, np.ndarray, np.ndarray]], width: int) -> np.ndarray:
    """Per-view gains g minimizing Σ N_ij[(g_i·I_ij − g_j·I_ji)²/σ_N² + (1 − g_i)²/σ_g²] (Brown & Lowe 2007, eq. 29)."""
    n = len(parts)
    sigma_n, sigma_g = 10.0, 0.1
    # per view: where it lies on the grid (W,), and for each of its columns the grid column → its index
    where = []
    for cols, colour, weight in parts:
        pos = np.full(width, -1, np.int64)
        pos[cols] = np.arange(cols.size)
        where.append((pos, weight > 0, colour.mean(axis=2)))
    A = np.zeros((n, n))
    b = np.zeros(n)
    for i in range(n):
        for j in range(i + 1, n):
            common = np.flatnonzero((where[i][0] >= 0) & (where[j][0] >= 0))
            if common.size == 0:
                continue
            ci, cj = where[i][0][common], where[j][0][common]
            both = where[i][1][:, ci] & where[j][1][:, cj]
            m = int(both.sum())
            if m == 0:
                continue
            Ii, Ij = float(where[i][2][:, ci][both].mean()), float(where[j][2][:, cj][both].mean())
            # derivative of N(g_i Ii − g_j Ij)²/σn² with respect to g_i and g_j
            A[i, i] += m * Ii * Ii / sigma_n**2
            A[j, j] += m * Ij * Ij / sigma_n**2
            A[i, j] -= m * Ii * Ij / sigma_n**2
            A[j, i] -= m * Ii * Ij / sigma_n**2
            for k in (i, j):
                A[k, k] += m / sigma_g**2
                b[k] += m / sigma_g**2
    for k in range(n):
        if A[k, k] == 0.0:  # a view overlapping no other keeps its gain
            A[k, k], b[k] = 1.0, 1.0
    return np.linalg.solve(A, b)


def panorama_from_images(
    images: Sequence[CameraImage],
    yaws_rad: Sequence[float] | np.ndarray,
    *,
    width_px: int = 2048,
    height_px: int | None = None,
    fov_v_rad: float | None = None,
    azimuth_col0_rad: float = math.pi,
    gain_compensation: bool = True,
) -> Panorama:
    """Stitch pinhole views taken at known yaws into a cylindrical reference panorama (see the module docstring).

    Parameters
    ----------
    images
        The views (:class:`~factorloc.CameraImage`, BGR uint8, with their intrinsics, yaw and pitch in the robot frame).
    yaws_rad
        For each view, the robot's heading when it was taken, relative to the panorama's
        frame (rad, CCW): a body turning on the spot gives its odometry headings, a pan head
        leaves them 0 and puts the head's yaw in ``CameraImage.yaw_in_robot_rad``. View ``i``
        looks along ``yaws_rad[i] + images[i].yaw_in_robot_rad``.
    width_px
        Columns over 360° (the grid's resolution).
    height_px
        Rows; default ``2·(W/2π)·tan(fov_v/2)`` (square pixels at the horizon).
    fov_v_rad
        Vertical field of view of the band; default the band every view covers across its
        whole width (``2·atan(tan(vfov/2)·cos(hfov/2))`` less the view's pitch, smallest view).
    azimuth_col0_rad
        Azimuth of column 0 (default π: the centre column looks along heading 0).
    gain_compensation
        Scale each view's brightness so that overlaps agree (auto-exposure differences).

    Returns
    -------
    Panorama
        ``seen_columns`` marks the columns some view covers from the top row to the bottom
        row (None when that is every column); unseen pixels are black.

    Raises
    ------
    InputError
        On an empty list, a yaw count that differs from the image count, a non-finite yaw,
        or views that cover no column of the band.
    """
    ims = [images] if isinstance(images, CameraImage) else list(images)
    if not ims:
        raise InputError("panorama_from_images needs at least one image")
    for i, im in enumerate(ims):
        if not isinstance(im, CameraImage):
            raise InputError(f"images[{i}] must be a factorloc.CameraImage, got {type(im).__name__}")
    yaws = np.asarray(yaws_rad, dtype=np.float64).reshape(-1)
    if yaws.shape[0] != len(ims):
        raise InputError(f"yaws_rad has {yaws.shape[0]} values for {len(ims)} images")
    if not np.all(np.isfinite(yaws)):
        raise InputError(f"yaws_rad must be finite, got {yaws.tolist()}")
    W = int(positive_float("width_px", width_px))
    if W < 8:
        raise InputError(f"width_px must be >= 8, got {W}")
    fov = _default_fov_v(ims) if fov_v_rad is None else positive_float("fov_v_rad", fov_v_rad)
    if fov >= math.pi:
        raise InputError(f"fov_v_rad must be < π, got {fov!r}")
    H = max(8, int(round(2.0 * W / (2.0 * math.pi) * math.tan(0.5 * fov)))) if height_px is None else int(height_px)
    if H < 8:
        raise InputError(f"height_px must be >= 8, got {height_px!r}")
    az0 = finite_float("azimuth_col0_rad", azimuth_col0_rad)
    az_cols = az0 - 2.0 * math.pi * np.arange(W) / W
    f_v = 0.5 * H / math.tan(0.5 * fov)
    elev = np.arctan((0.5 * H - np.arange(H)) / f_v)
    parts = [p for im, yaw in zip(ims, yaws, strict=True) if (p := _project(im, float(yaw), az_cols, elev)) is not None]
    if not parts:
        raise InputError("no view covers any column of the panorama")
    gains = _gains(parts, W) if gain_compensation and len(parts) > 1 else np.ones(len(parts))
    acc = np.zeros((H, W, 3), np.float64)
    wsum = np.zeros((H, W), np.float64)
    for (cols, colour, weight), g in zip(parts, gains, strict=True):
        acc[:, cols] += colour * (weight * g)[:, :, None]
        wsum[:, cols] += weight
    seen_px = wsum > 0.0
    out = np.where(seen_px[:, :, None], acc / np.maximum(wsum, 1e-12)[:, :, None], 0.0)
    seen = seen_px.all(axis=0)
    if not seen.any():
        raise InputError("no column of the panorama is covered from its top row to its bottom row: lower fov_v_rad")
    image = np.clip(np.rint(out), 0, 255).astype(np.uint8)
    return Panorama(image, fov_v_rad=fov, azimuth_col0_rad=az0, seen_columns=None if seen.all() else seen)

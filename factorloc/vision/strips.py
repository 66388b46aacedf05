"""Query images resampled onto the reference panorama's pixel grid ("strips").

A :class:`Grid` is the geometry of the reference :class:`~factorloc.types.Panorama`:
``W`` columns over 360° with ``azimuth(c) = azimuth_col0_rad − 2π·c/W`` and
``H`` cylindrical rows with ``elevation(v) = atan((H/2 − v)/f_v)``,
``f_v = (H/2)/tan(fov_v/2)`` (the conventions of :mod:`factorloc.types`).

A :class:`Strip` is a query view (a pinhole :class:`~factorloc.types.CameraImage`
or a query panorama) reprojected onto that same grid in the *query robot's*
frame: strip column ``j`` looks at robot-frame azimuth
``azimuth_col0_rad − 2π·(col0 + j)/W`` and strip row ``i`` at the elevation of
grid row ``row0 + i``. A robot heading θ relative to the reference then shows
as a pure horizontal shift of ``−θ·W/2π`` columns, whatever the camera's size,
field of view or yaw: both camera steps work on strips.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import cv2
import numpy as np

from factorloc.geometry import wrap_angle
from factorloc.types import CameraImage, Panorama

#: A camera image more than this many times finer than the grid is area-downsampled before the remap.
_PRESCALE_RATIO = 1.25


@dataclass(frozen=True)
class Grid:
    """Pixel geometry of a reference panorama (see module docstring)."""

    width_px: int
    height_px: int
    fov_v_rad: float
    azimuth_col0_rad: float

    @classmethod
    def of(cls, panorama: Panorama) -> Grid:
        return cls(panorama.width_px, panorama.height_px, panorama.fov_v_rad, panorama.azimuth_col0_rad)

    @property
    def rad_per_px(self) -> float:
        """Angular width of one column (rad)."""
        return 2.0 * math.pi / self.width_px

    @property
    def focal_v_px(self) -> float:
        """Cylinder radius of the rows in pixels: ``(H/2)/tan(fov_v/2)``."""
        return 0.5 * self.height_px / math.tan(0.5 * self.fov_v_rad)

    def azimuth_of_column(self, c: float | np.ndarray) -> float | np.ndarray:
        """Azimuth (rad, wrapped) of grid column ``c`` (fractional allowed)."""
        return wrap_angle(self.azimuth_col0_rad - np.asarray(c, dtype=np.float64) * self.rad_per_px)

    def column_of_azimuth(self, azimuth_rad: float | np.ndarray) -> np.ndarray:
        """Grid column in [0, W) that looks at ``azimuth_rad``."""
        return np.mod((self.azimuth_col0_rad - np.asarray(azimuth_rad, dtype=np.float64)) / self.rad_per_px, self.width_px)

    def elevation_of_row(self, v: float | np.ndarray) -> np.ndarray:
        """Elevation (rad) of grid row ``v``."""
        return np.arctan((0.5 * self.height_px - np.asarray(v, dtype=np.float64)) / self.focal_v_px)


@dataclass(frozen=True, eq=False)
class Strip:
    """A query view on the reference grid: grey float32 ``h×n`` image and its placement.

    ``col0`` (in [0, W)) and ``row0`` are the grid column and row of the strip's
    pixel (0, 0); ``full_circle`` is True when it spans 360° (``n == W``).
    """

    gray: np.ndarray
    col0: int
    row0: int
    grid: Grid
    full_circle: bool
    source: str

    @property
    def width_px(self) -> int:
        return int(self.gray.shape[1])

    @property
    def height_px(self) -> int:
        return int(self.gray.shape[0])

    def azimuth_of_column(self, j: float | np.ndarray) -> float | np.ndarray:
        """Robot-frame azimuth (rad) of strip column ``j`` (fractional allowed)."""
        return self.grid.azimuth_of_column(self.col0 + np.asarray(j, dtype=np.float64))


def to_gray(image_bgr: np.ndarray) -> np.ndarray:
    """BGR uint8 → grey float32 in [0, 255]."""
    return cv2.cvtColor(image_bgr, cv2.COLOR_BGR2GRAY).astype(np.float32)


def texture_problem(gray: np.ndarray, *, min_std: float = 2.0, min_max: float = 12.0) -> str | None:
    """Why a grey image cannot be matched (all black, flat), or None when it has texture."""
    if gray.size == 0:
        return "image is empty"
    peak = float(gray.max())
    if peak < min_max:
        return f"image is (nearly) all black (max grey level {peak:.0f})"
    std = float(gray.std())
    if std < min_std:
        return f"image is flat (grey std {std:.2f} < {min_std})"
    return None


def camera_strip(camera: CameraImage, grid: Grid, *, min_rows: int = 8, source: str = "camera") -> Strip | None:
    """Reproject a pinhole camera image onto ``grid`` (robot frame).

    The camera's rays follow :class:`~factorloc.types.CameraImage`: pixel
    ``(u, v)`` looks along ``(f, cx − u, cy − v)`` tilted up by ``pitch_rad``
    and turned by ``yaw_in_robot_rad``. The strip keeps the grid columns whose
    azimuths the camera covers and the largest band of grid rows visible in
    *all* of them (a rectangle with no invalid pixel). Returns None when fewer
    than ``min_rows`` rows or 8 columns remain.
    """
    gray = to_gray(camera.image_bgr)
    h, w = gray.shape
    f = camera.focal_px
    cx = camera.principal_x_px
    cy = (h - 1) / 2.0
    ratio = f / (grid.width_px / (2.0 * math.pi))
    if ratio > _PRESCALE_RATIO:  # the grid is coarser: area-average first to avoid aliasing
        nw, nh = max(8, int(round(w / ratio))), max(8, int(round(h / ratio)))
        sx, sy = nw / w, nh / h
        gray = cv2.resize(gray, (nw, nh), interpolation=cv2.INTER_AREA)
        f, cx, cy = f * sx, (cx + 0.5) * sx - 0.5, (cy + 0.5) * sy - 0.5
        h, w = nh, nw
    yaw, pitch = float(camera.yaw_in_robot_rad), float(camera.pitch_rad)
    maps = _camera_maps(grid, w, h, float(f), float(cx), float(cy), yaw, pitch, min_rows)
    if maps is None:
        return None
    first, r0, map_x, map_y = maps
    out = cv2.remap(gray, map_x, map_y, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return Strip(out, int(first % grid.width_px), int(r0), grid, False, source)


@functools.lru_cache(maxsize=32)
def _camera_maps(
    grid: Grid, w: int, h: int, f: float, cx: float, cy: float, yaw: float, pitch: float, min_rows: int
) -> tuple[int, int, np.ndarray, np.ndarray] | None:
    """``(first column, first row, map_x, map_y)`` of :func:`camera_strip`'s remap, or None when too small.

    A pure function of the camera's geometry and the grid, cached: a robot's cameras do not change
    between queries, and the compass and the correlation reproject the same views (the trigonometry
    over the strip's pixels costs several times the remap itself). The maps are read-only.
    """
    a_left = math.atan((cx + 0.5) / f)
    a_right = math.atan((cx - w + 0.5) / f)
    c_lo = (grid.azimuth_col0_rad - (yaw + a_left)) / grid.rad_per_px
    c_hi = (grid.azimuth_col0_rad - (yaw + a_right)) / grid.rad_per_px
    first, last = math.ceil(c_lo) + 1, math.floor(c_hi) - 1
    n = last - first + 1
    if n < 8:
        return None
    cols = first + np.arange(n)
    alpha = wrap_angle(grid.azimuth_col0_rad - cols * grid.rad_per_px - yaw)
    elev = grid.elevation_of_row(np.arange(grid.height_px))
    ca, sa = np.cos(alpha)[None, :], np.sin(alpha)[None, :]
    ce, se = np.cos(elev)[:, None], np.sin(elev)[:, None]
    x, y, z = ce * ca, ce * sa, np.broadcast_to(se, (elev.size, n))
    cp, sp = math.cos(pitch), math.sin(pitch)
    xc, zc = x * cp + z * sp, -x * sp + z * cp
    with np.errstate(divide="ignore", invalid="ignore"):
        u = cx - f * y / xc
        v = cy - f * zc / xc
    valid = (xc > 1e-6) & (u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1)
    rows_ok = valid.all(axis=1)
    run = _longest_run(rows_ok)
    if run is None or run[1] - run[0] < min_rows:
        return None
    r0, r1 = run
    map_x = np.ascontiguousarray(u[r0:r1], dtype=np.float32)
    map_y = np.ascontiguousarray(v[r0:r1], dtype=np.float32)
    map_x.setflags(write=False)
    map_y.setflags(write=False)
    return first, r0, map_x, map_y


def panorama_strip(panorama: Panorama, grid: Grid, *, source: str = "panorama") -> Strip | None:
    """Resample a query panorama onto ``grid`` (robot frame), keeping the rows it covers."""
    gray = to_gray(panorama.image_bgr)
    same = (
        panorama.width_px == grid.width_px
        and panorama.height_px == grid.height_px
        and math.isclose(panorama.fov_v_rad, grid.fov_v_rad)
        and math.isclose(panorama.azimuth_col0_rad, grid.azimuth_col0_rad)
    )
    if same:
        return Strip(gray, 0, 0, grid, True, source)
    hq, wq = gray.shape
    fq = 0.5 * hq / math.tan(0.5 * panorama.fov_v_rad)
    az0q = panorama.azimuth_col0_rad
    if wq > _PRESCALE_RATIO * grid.width_px:
        s = grid.width_px / wq
        nh = max(8, int(round(hq * s)))
        gray = cv2.resize(gray, (grid.width_px, nh), interpolation=cv2.INTER_AREA)
        # column u' ↔ original (u' + 0.5)/s − 0.5: shift column 0's azimuth accordingly
        az0q = az0q - (0.5 / s - 0.5) * 2.0 * math.pi / wq
        fq = fq * nh / hq
        hq, wq = gray.shape
    cols = np.arange(grid.width_px)
    az = grid.azimuth_of_column(cols)
    uq = np.mod((az0q - az) * wq / (2.0 * math.pi), wq)
    elev = grid.elevation_of_row(np.arange(grid.height_px))
    vq = 0.5 * hq - fq * np.tan(elev)
    rows_ok = (vq >= 0) & (vq <= hq - 1)
    run = _longest_run(rows_ok)
    if run is None or run[1] - run[0] < 8:
        return None
    r0, r1 = run
    padded = np.concatenate([gray, gray[:, :1]], axis=1)
    map_x = np.broadcast_to(uq[None, :], (r1 - r0, grid.width_px)).astype(np.float32)
    map_y = np.broadcast_to(vq[r0:r1, None], (r1 - r0, grid.width_px)).astype(np.float32)
    out = cv2.remap(padded, map_x, map_y, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return Strip(out, 0, int(r0), grid, True, source)


def _longest_run(mask: np.ndarray) -> tuple[int, int] | None:
    """[start, stop) of the longest run of True in a 1-D boolean array."""
    if not mask.any():
        return None
    padded = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(padded)
    starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
    k = int(np.argmax(stops - starts))
    return int(starts[k]), int(stops[k])

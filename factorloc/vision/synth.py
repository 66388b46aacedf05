"""The reference panorama re-rendered from a hypothesised query position (column-wise depth warp).

Used by the panorama correlation to remove parallax before correlating: a
query displaced by ``p`` (reference frame, metres) sees the surface behind
reference column ``u`` (azimuth ``az_u``, horizontal range ``D_u`` at the
horizon, from a :class:`~factorloc.vision.depth.DepthMap`) at the azimuth
``az'_u = atan2(D_u·sin az_u − p_y, D_u·cos az_u − p_x)`` and range ``r'_u``,
magnified vertically about the horizon by ``D_u / r'_u``. The warp is built
per target column: consecutive source columns on one surface (no depth jump)
span the target columns between their new positions, the nearest surface
wins where several overlap (occlusion), and disoccluded holes take the
nearest filled column. The output keeps the reference's orientation, so
correlating a query with it gives a parallax-free heading. Surfaces are
assumed vertical within a column (walls); low obstacles below the horizon
are warped with the depth at the horizon.
"""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from factorloc.vision.depth import DepthMap
from factorloc.vision.strips import Grid


def synthesize(
    gray: np.ndarray,
    grid: Grid,
    depth: DepthMap,
    position_xy_m: tuple[float, float],
    *,
    max_depth_jump: float = 0.1,
    columns: np.ndarray | None = None,
    padded: np.ndarray | None = None,
    horizon: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Warp the grey reference panorama (H×W float32) to a viewpoint at ``position_xy_m`` (reference frame).

    Parameters
    ----------
    gray
        The reference panorama, grey float32, on ``grid``.
    grid
        Its geometry.
    depth
        Ranges behind it (the horizon row is used).
    position_xy_m
        The hypothesised query position in the *reference robot's* frame (m).
    max_depth_jump
        Relative range change between neighbouring columns treated as a depth edge (not a surface).
    columns
        Optional boolean mask (W,) of the output columns to render (the others are left 0): the
        correlation renders only the columns its seeded window can reach. The per-column
        geometry (range, magnification) is always computed for all W columns.
    padded
        Optional ``gray`` with its first two columns appended (H×(W+2), :func:`wrap_padded`), when the caller
        keeps one (a reference's is the same for every query); built here otherwise.
    horizon
        Optional :func:`horizon_points` of ``grid`` and ``depth`` (the same for every query), built here otherwise.

    Returns
    -------
    (image, range_m, magnification)
        The warped H×W float32 panorama, the range (m) from the new viewpoint
        behind each of its columns (W,), and each column's magnification
        ``D / r'`` relative to the reference (W,).
    """
    h, w = gray.shape
    d, d_cos, d_sin = horizon_points(grid, depth) if horizon is None else horizon
    px, py = float(position_xy_m[0]), float(position_xy_m[1])
    x, y = d_cos - px, d_sin - py
    r_new = np.hypot(x, y)
    u_new = np.mod((grid.azimuth_col0_rad - np.arctan2(y, x)) / grid.rad_per_px, w)
    # segments between source columns i and i+1 (circular)
    i = np.arange(w)
    j = (i + 1) % w
    a = u_new[i]
    b = u_new[j]
    b = a + np.mod(b - a + w / 2.0, w) - w / 2.0  # the short way round
    jump = np.abs(d[i] - d[j]) > max_depth_jump * np.minimum(d[i], d[j]) + 0.02
    ok = (~jump) & (b > a) & (b - a < w / 4.0)
    first = np.ceil(a).astype(int)
    count = np.where(ok, np.floor(b).astype(int) - first + 1, 0).clip(min=0)
    seg = np.repeat(i, count)
    if seg.size == 0:
        return gray.copy(), d.copy(), np.ones(w)
    offs = np.arange(seg.size) - np.repeat(np.cumsum(count) - count, count)
    t = first[seg] + offs
    frac = (t - a[seg]) / (b[seg] - a[seg])
    src = seg + frac  # fractional source column (may reach w: wrapped by the padding below)
    rr = r_new[seg] + (r_new[j[seg]] - r_new[seg]) * frac
    dd = d[seg] + (d[j[seg]] - d[seg]) * frac
    tm = np.mod(t, w)
    order = np.lexsort((rr, tm))  # by target column, nearest first
    tm, src, rr, dd = tm[order], src[order], rr[order], dd[order]
    keep = np.concatenate([[True], tm[1:] != tm[:-1]])
    src_col = np.full(w, np.nan)
    ratio = np.full(w, np.nan)
    r_out = np.full(w, np.nan)
    src_col[tm[keep]] = src[keep]
    ratio[tm[keep]] = rr[keep] / dd[keep]
    r_out[tm[keep]] = rr[keep]
    holes = np.isnan(src_col)
    if holes.any():
        tiled = np.tile(holes, 3)
        _, (idx,) = ndimage.distance_transform_edt(tiled, return_indices=True)
        nearest = np.mod(idx[w : 2 * w], w)
        src_col, ratio, r_out = src_col[nearest], ratio[nearest], r_out[nearest]
    cols = np.arange(w) if columns is None else np.flatnonzero(columns)
    v = np.arange(h, dtype=np.float32)
    map_y = (v[:, None] - np.float32(0.5 * h)) * ratio[cols].astype(np.float32)[None, :]
    map_y += np.float32(0.5 * h)
    map_x = np.ascontiguousarray(np.broadcast_to(src_col[cols].astype(np.float32)[None, :], (h, cols.size)))
    if padded is None:
        padded = wrap_padded(gray)
    warped = cv2.remap(padded, map_x, map_y, cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    if columns is None:
        return warped, r_out, 1.0 / ratio
    out = np.zeros(gray.shape, dtype=gray.dtype)  # calloc'd: the pages of columns never rendered are never touched
    # the rendered columns are a few runs (one per view, two when it straddles column 0): slice copies, not a
    # fancy-indexed scatter of every pixel
    breaks = np.flatnonzero(np.diff(cols) != 1) + 1
    for lo, hi in zip(np.concatenate([[0], breaks]), np.concatenate([breaks, [cols.size]]), strict=True):
        out[:, cols[lo] : cols[hi - 1] + 1] = warped[:, lo:hi]
    return out, r_out, 1.0 / ratio


def wrap_padded(gray: np.ndarray) -> np.ndarray:
    """``gray`` (H×W) with its first two columns appended (H×(W+2)): the source :func:`synthesize` remaps from."""
    return np.concatenate([gray, gray[:, :2]], axis=1)


def horizon_points(grid: Grid, depth: DepthMap) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per reference column (W,): the range ``D`` at the horizon (m) and the point ``D·(cos az, sin az)`` (m, reference frame)."""
    az = np.asarray(grid.azimuth_of_column(np.arange(grid.width_px, dtype=np.float64)), dtype=np.float64)
    d = depth.range_at(az, np.zeros(grid.width_px)).astype(np.float64)
    return d, d * np.cos(az), d * np.sin(az)

"""Parallax correction of visual headings from the reference's depth and a position hypothesis.

A visual heading ``θ = az_ref − az_query`` is exact only when the query
stands where the reference was taken: from a position displaced by ``d``, a
point at range ``D`` is seen turned by up to ``atan(d/D)`` (tens of degrees
indoors at 1–2 m). When the reference carries a cloud or a scan, the point
behind a reference direction ``(az, el)`` is known, ``P = T_world_reference ·
D(az, el)·(cos az, sin az)``; given the query's world position ``p`` (a
position hypothesis, e.g. odometry), the query sees it along the world
bearing ``β = atan2(P − p)``, so the pair votes for the world heading
``θ = β − az_query`` (no parallax). A position error ``σ_p`` leaves a heading
error of about ``σ_p / |P − p|`` — that term enters the estimators' σ.

:class:`DepthMap` holds the horizontal range ``D`` on a coarse grid over the
reference panorama (rows = elevation, columns = azimuth): from a 3D cloud by
z-buffering the points (nearest wins) seen from the panorama's camera
height, from a 2D scan as one row valid for all elevations; empty cells take
the nearest filled one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from factorloc.errors import InputError
from factorloc.geometry import Pose2, wrap_angle
from factorloc.types import Reference
from factorloc.vision.strips import Grid


@dataclass(frozen=True, eq=False)
class DepthMap:
    """Horizontal range (m) behind the reference panorama's directions, on a coarse (rows × cols) grid."""

    range_m: np.ndarray
    grid: Grid
    T_world_reference: Pose2
    camera_height_m: float
    spread_m: np.ndarray | None = None
    #: Whether the ranges come from a planar scan (one row, read for every elevation) rather than a cloud.
    #: Right for walls (vertical, at every height where the scan cut them); wrong above and below what the
    #: scan plane cut (a wall above a low cabinet reads the cabinet's range, a shelf above the plane the wall's).
    planar: bool = False

    def _cell(self, azimuth_rad: np.ndarray, elevation_rad: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        rows, cols = self.range_m.shape
        az = np.asarray(azimuth_rad, dtype=np.float64)
        u = np.mod((self.grid.azimuth_col0_rad - az) / self.grid.rad_per_px, self.grid.width_px)
        c = np.minimum((u * cols / self.grid.width_px).astype(int), cols - 1)
        if rows == 1 or elevation_rad is None:
            r = np.full(c.shape, rows // 2)
        else:
            v = 0.5 * self.grid.height_px - self.grid.focal_v_px * np.tan(np.asarray(elevation_rad, dtype=np.float64))
            r = np.clip((v * rows / self.grid.height_px).astype(int), 0, rows - 1)
        return r, c

    def spread_at(self, azimuth_rad: np.ndarray, elevation_rad: np.ndarray | None = None) -> np.ndarray:
        """Range spread (m) around reference-frame directions: max − min over the 3×3 cells about each.

        Large at depth edges, where a direction's range is uncertain by about that much (the coarse
        cell may hold the near or the far surface); 0 when the map was built without it.
        """
        if self.spread_m is None:
            return np.zeros(np.shape(azimuth_rad))
        r, c = self._cell(azimuth_rad, elevation_rad)
        return self.spread_m[r, c]

    def range_at(self, azimuth_rad: np.ndarray, elevation_rad: np.ndarray | None = None) -> np.ndarray:
        """Horizontal range (m) behind reference-frame directions (azimuth, elevation; radians)."""
        r, c = self._cell(azimuth_rad, elevation_rad)
        return self.range_m[r, c]

    def world_points(self, azimuth_rad: np.ndarray, elevation_rad: np.ndarray | None = None) -> np.ndarray:
        """World-frame xy (N×2, m) of the points behind reference-frame directions."""
        return self.lookup(azimuth_rad, elevation_rad)[0]

    def lookup(
        self, azimuth_rad: np.ndarray, elevation_rad: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """:meth:`world_points`, :meth:`range_at` and :meth:`spread_at` of the same directions at once (one cell lookup)."""
        az = np.asarray(azimuth_rad, dtype=np.float64)
        r, c = self._cell(az, elevation_rad)
        d = self.range_m[r, c]
        spread = np.zeros(np.shape(azimuth_rad)) if self.spread_m is None else self.spread_m[r, c]
        points = self.T_world_reference.transform_points(np.column_stack([d * np.cos(az), d * np.sin(az)]))
        return points, d, spread

    def world_headings(
        self,
        az_ref_rad: np.ndarray,
        az_query_rad: np.ndarray,
        position_xy_m: tuple[float, float],
        elevation_rad: np.ndarray | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """Parallax-free world headings ``atan2(P − p) − az_query`` of pairs, and the ranges ``|P − p|`` (m)."""
        return headings_from_points(self.world_points(az_ref_rad, elevation_rad), position_xy_m, az_query_rad)


def headings_from_points(
    points_world_m: np.ndarray, position_xy_m: tuple[float, float] | np.ndarray, az_query_rad: np.ndarray | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """World headings ``atan2(P − p) − az_query`` (rad, wrapped; ``az_query`` omitted: the bearings of the points
    P (N×2, world frame, m) seen from ``p``) and the ranges ``|P − p|`` (m): what a robot at ``p`` would have to
    face for each point to appear at its query azimuth (parallax-free, :meth:`DepthMap.world_headings`)."""
    delta = np.asarray(points_world_m, dtype=np.float64) - np.asarray(position_xy_m, dtype=np.float64)[None, :]
    bearing = np.arctan2(delta[:, 1], delta[:, 0])
    if az_query_rad is not None:
        bearing = bearing - np.asarray(az_query_rad, dtype=np.float64)
    return np.asarray(wrap_angle(bearing)), np.hypot(delta[:, 0], delta[:, 1])


def depth_map(reference: Reference, grid: Grid, camera_height_m: float, shape: tuple[int, int] = (32, 360)) -> DepthMap | None:
    """The reference's depth behind its panorama, from ``reference.cloud`` (preferred) or ``reference.scan``.

    Parameters
    ----------
    reference
        Its cloud (N×3, robot frame, z up from the floor) or scan (N×2) gives the ranges.
    grid
        The reference panorama's grid.
    camera_height_m
        Height of the panorama's camera above the floor (m), to place cloud points in elevation.
    shape
        (rows, cols) of the coarse grid.

    Returns
    -------
    DepthMap or None
        None when the reference has neither, or fewer than 10 usable points.
    """
    rows, cols = shape
    if reference.cloud is not None and len(reference.cloud) >= 10:
        p = reference.cloud.points_m
        rng = np.hypot(p[:, 0], p[:, 1])
        az = np.arctan2(p[:, 1], p[:, 0])
        el = np.arctan2(p[:, 2] - camera_height_m, np.maximum(rng, 1e-6))
        v = 0.5 * grid.height_px - grid.focal_v_px * np.tan(np.clip(el, -1.5, 1.5))
        r_idx = np.floor(v * rows / grid.height_px).astype(int)
        planar = False
    elif reference.scan is not None and len(reference.scan) >= 10:
        p = reference.scan.points_m
        rng = np.hypot(p[:, 0], p[:, 1])
        az = np.arctan2(p[:, 1], p[:, 0])
        rows = 1
        r_idx = np.zeros(len(p), dtype=int)
        planar = True
    else:
        return None
    u = np.mod((grid.azimuth_col0_rad - az) / grid.rad_per_px, grid.width_px)
    c_idx = np.minimum((u * cols / grid.width_px).astype(int), cols - 1)
    keep = (r_idx >= 0) & (r_idx < rows) & (rng > 0.05)
    if keep.sum() < 10:
        return None
    out = np.full((rows, cols), np.inf)
    np.minimum.at(out, (r_idx[keep], c_idx[keep]), rng[keep])  # z-buffer: the nearest point wins
    # fill empty cells from the nearest filled one (columns treated as periodic)
    half = cols // 2
    padded = np.concatenate([out[:, cols - half :], out, out[:, :half]], axis=1)
    empty = ~np.isfinite(padded)
    _, (ri, ci) = ndimage.distance_transform_edt(empty, return_indices=True)
    filled = padded[ri, ci][:, half : half + cols]
    filled = np.ascontiguousarray(filled)
    filled.setflags(write=False)
    # range spread over each cell's 3×3 neighbourhood (columns periodic): the range uncertainty at depth edges
    wrapped = np.concatenate([filled[:, -1:], filled, filled[:, :1]], axis=1)
    spread = ndimage.maximum_filter(wrapped, size=3, mode="nearest") - ndimage.minimum_filter(wrapped, size=3, mode="nearest")
    spread = np.ascontiguousarray(spread[:, 1:-1])
    spread.setflags(write=False)
    return DepthMap(filled, grid, reference.T_world_reference, float(camera_height_m), spread, planar=planar)


def position_seed(hypotheses) -> tuple[tuple[float, float], float] | None:  # noqa: ANN001 - Hypotheses
    """``((x, y), σ)`` of the latest reliable position hypothesis (σ = the larger axis σ, m), or None."""
    h = hypotheses.position()
    if h is None:
        return None
    x, y, sx, sy, _ = h
    return (x, y), max(sx, sy)


def parallax_sigma(sigma_position_m: float, ranges_m: np.ndarray) -> float:
    """Heading σ (rad) a position σ leaves on bearings to points at ``ranges_m``: ``σ_p / median range``."""
    r = float(np.median(ranges_m)) if np.size(ranges_m) else math.inf
    return math.atan(sigma_position_m / max(r, 1e-3))


def uncorrected_parallax_sigma(
    hypotheses,  # noqa: ANN001 - Hypotheses
    depth: DepthMap | None,
    T_world_reference: Pose2,
    azimuth_rad: np.ndarray,
    unknown_position_sigma_m: float,
    default_range_m: float,
) -> float:
    """Heading σ (rad) from the parallax a heading estimate could *not* correct (0 when it was corrected).

    Without a position hypothesis the query is assumed within ``unknown_position_sigma_m``
    of the reference; with one but without reference depth, the hypothesised displacement
    from the reference plus its σ is used. The range is the median reference range behind
    ``azimuth_rad`` (reference frame) when depth is known, else ``default_range_m``.
    """
    pos = position_seed(hypotheses)
    if pos is not None and depth is not None:
        return 0.0
    if pos is None:
        offset = unknown_position_sigma_m
    else:
        offset = float(np.hypot(*(np.asarray(pos[0]) - T_world_reference.translation))) + pos[1]
    if depth is not None and np.size(azimuth_rad):
        ranges = depth.range_at(np.asarray(azimuth_rad, dtype=np.float64))
    else:
        ranges = np.array([default_range_m])
    return parallax_sigma(offset, ranges)


#: Steps of the worst-case search of :func:`spread_parallax_bound` over ``u ∈ [0, π)`` (0.5° apart).
_BOUND_STEPS = 360
#: Below this variance (dimensionless, of ``sin(2φ − u)``) the bearings are taken as coincident: rounding leaves a
#: variance that is 0 in theory at about 1e-17 (the bearings of one pixel column spread by 1e-6 rad give 4e-12).
_SPREAD_VARIANCE_TOLERANCE = 1e-14


def spread_parallax_bound(
    bearings_rad: np.ndarray, residuals_rad: np.ndarray, *, n_effective: int, confidence: float, band_rad: float = math.inf
) -> tuple[float, float]:
    """How far (rad) the mode of heading votes can be turned by a displacement its own residuals do not show.

    A displacement ``d`` (any direction ``ψ``) seen against points on one plane (any orientation ``α``, at a
    distance ``D``) turns the bearing of the point at ``φ`` by ``δ(φ) = (d/D) cos(φ − α) sin(φ − ψ)``, which is
    ``(d/2D)·[sin(2φ − u) + sin v]`` with ``u = α + ψ``, ``v = α − ψ``. The votes' mode (their mean) is off by
    ``mean δ`` while the residuals about it carry ``δ − mean δ``; for the given bearings ``φᵢ``::

        |mean δ| ≤ k · rms(δ − mean δ),   k = max_u (|M(u)| + 1) / S(u)

    with ``M(u)``, ``S(u)`` the mean and standard deviation of ``sin(2φᵢ − u)`` (``sin v = ±1`` is the worst
    case; that the plane faces the camera is not imposed, so the bound covers more scenes than it needs to).
    A 57° view with its bearings spread evenly gives ``k ≈ 13`` (a sideways step against a wall straight
    ahead: every bearing turns by nearly the same angle); bearings bunched in one direction give a larger
    ``k``, and ``inf`` when they coincide. Noise only adds to the residuals, so their rms bounds
    ``rms(δ − mean δ)``; it is taken at its one-sided upper confidence limit ``rms · √(n / χ²_n(1 − confidence))``
    (``n = n_effective − 1`` degrees of freedom: the mode took one). The residuals are those of the inliers, votes
    within ``band_rad`` of the mode: a spread wider than the band is cut to it, and its rms then says nothing about
    the parallax (a 360° view from 0.3 m away: every vote's parallax differs by degrees, the band keeps a slice of
    them). So the bound holds only while the band holds the spread's 3σ (``3 · rms_upper ≤ band_rad``), else inf.

    A model, not a theorem for every scene: it is first order in ``d/D`` (a parallax of tens of degrees can exceed
    it, by up to 2.2× on the simulated views of ``docs/calibration/vision.md``, where the bound itself is then tens
    of degrees), and points on a circle through both camera positions see one parallax (the inscribed-angle
    theorem) and show no spread at all. Indoors that is a wall curving around a camera standing at it.

    Parameters
    ----------
    bearings_rad
        (N,) directions of the matched points from the query (any common frame, rad).
    residuals_rad
        (N,) the inlier votes minus their mode (rad).
    n_effective
        The number of independent votes the residuals stand for (≥ 2).
    confidence
        Of the upper limit on the residuals' rms, in (0, 1).
    band_rad
        Half-width of the band that chose the inliers (rad; inf: the residuals were not cut).

    Returns
    -------
    (bound_rad, k)
        ``k · rms_upper`` and ``k`` (``inf`` for both when the bearings bound nothing; the bound alone is inf when
        the band may have cut the spread).
    """
    from factorloc.stats import chi2_quantile

    phi = np.asarray(bearings_rad, dtype=np.float64).ravel()
    e = np.asarray(residuals_rad, dtype=np.float64).ravel()
    if not (np.all(np.isfinite(phi)) and np.all(np.isfinite(e))):
        raise InputError("spread_parallax_bound: bearings_rad and residuals_rad must be finite")
    if not 0.0 < confidence < 1.0:
        raise InputError(f"spread_parallax_bound: confidence must be in (0, 1), got {confidence!r}")
    if phi.size < 2 or phi.size != e.size or n_effective < 2:
        return math.inf, math.inf
    s2, c2 = np.sin(2.0 * phi), np.cos(2.0 * phi)
    ms, mc = float(s2.mean()), float(c2.mean())
    vss, vcc = float(np.mean((s2 - ms) ** 2)), float(np.mean((c2 - mc) ** 2))
    vsc = float(np.mean((s2 - ms) * (c2 - mc)))
    u = np.arange(_BOUND_STEPS) * (math.pi / _BOUND_STEPS)
    cu, su = np.cos(u), np.sin(u)
    mean_u = np.abs(ms * cu - mc * su)
    var_u = vss * cu**2 + vcc * su**2 - 2.0 * vsc * su * cu
    # a variance that is 0 in theory (coincident bearings) comes out at ±1e-17: below the tolerance it bounds nothing
    if float(var_u.min()) <= _SPREAD_VARIANCE_TOLERANCE:
        return math.inf, math.inf
    k = float(np.max((mean_u + 1.0) / np.sqrt(var_u)))
    dof = int(n_effective) - 1
    rms = float(math.sqrt(np.mean(e**2)))
    upper = rms * math.sqrt(dof / chi2_quantile(1.0 - float(confidence), dof))
    if 3.0 * upper > band_rad:
        return math.inf, k
    return k * upper, k

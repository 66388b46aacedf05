"""Free space of 2D scans: the free range per bearing a sensor saw (:func:`polar_profile`), the share of a scan an
alignment puts into space the other sensor saw empty (:func:`free_space_violation`, :func:`alignment_violation`,
:func:`profile_and_violation`) and the fitness over what both sensors could see (:func:`overlap_fitness`).

All points are N×2 metres in their sensor's frame; the compiled kernels (numba) index without bounds checks, so
the public functions validate their inputs first.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from factorloc.errors import InputError
from factorloc.registration.nn import GRID_CELL_M, GRID_MAX_CELLS, build_grid, grid_nearest

#: Bearing bins of :func:`polar_profile` (0.5° each), and the widest gap between returns it fills (rad).
PROFILE_BINS = 720
PROFILE_MAX_GAP_RAD = 0.35
#: Free-space margins: a point closer than ``R − max(MARGIN_M, MARGIN_RATIO·R)`` to the sensor violates the free
#: range R of its bin, and one farther than ``R + max(MARGIN_M, MARGIN_RATIO·R)`` is hidden behind the return.
MARGIN_M = 0.15
MARGIN_RATIO = 0.05

__all__ = [
    "MARGIN_M",
    "MARGIN_RATIO",
    "PROFILE_BINS",
    "PROFILE_MAX_GAP_RAD",
    "alignment_violation",
    "free_space_violation",
    "overlap_fitness",
    "polar_profile",
    "profile_and_violation",
]


def polar_profile(
    points_m: np.ndarray, n_bins: int = PROFILE_BINS, gap_free_m: float = 0.0, max_gap_rad: float = PROFILE_MAX_GAP_RAD
) -> np.ndarray:
    """Free range per bearing bin seen from the sensor at the origin: (n_bins,) metres, NaN where unknown.

    Bin ``k`` covers bearings ``[-π + 2πk/n, -π + 2π(k+1)/n)``; its free range
    is the *shortest* return in it (conservative: space closer than every
    return of the bin was seen empty by the sensor). Bins without a return
    inside an angular gap narrower than ``max_gap_rad`` between returns (a
    doorway, a window, sparse returns, a beam past the sensor's range) are
    taken as free up to the nearer of the two returns bounding the gap, at
    most ``gap_free_m`` (when it is > 0); wider gaps (outside the field of
    view) stay unknown. Compiled (numba, a few µs for a laser scan).
    """
    pts = np.ascontiguousarray(np.asarray(points_m, dtype=np.float64))
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise InputError(f"points_m must be N×2, got shape {pts.shape}")
    if np.isnan(pts).any():
        raise InputError("points_m contains NaN values")
    n_bins = int(n_bins)
    if n_bins < 1:
        raise InputError(f"n_bins must be >= 1, got {n_bins!r}")
    return _profile(pts, n_bins, float(gap_free_m), _gap_bins(max_gap_rad, n_bins))


def _gap_bins(max_gap_rad: float, n_bins: int) -> int:
    """The widest gap :func:`polar_profile` fills, in bins."""
    return int(max_gap_rad / (2 * np.pi) * n_bins)


def _rigid(T) -> tuple[float, float, float, float]:  # noqa: ANN001 - a Pose2
    """``(cos θ, sin θ, x, y)`` of a pose: how the compiled functions take a rigid motion."""
    return math.cos(T.theta), math.sin(T.theta), T.x, T.y


@njit(cache=True, inline="always")
def _bin(x: float, y: float, n_bins: int) -> int:
    """Bin of a bearing: ``floor((atan2(y, x) + π) / 2π · n) mod n`` (bearing +π: the bin of −π)."""
    b = int(math.floor((math.atan2(y, x) + math.pi) / (2 * math.pi) * n_bins))
    return b - n_bins if b >= n_bins else b


@njit(cache=True)
def _profile(pts: np.ndarray, n_bins: int, gap_free_m: float, max_gap_bins: int) -> np.ndarray:  # noqa: C901, PLR0912 (one compiled loop nest)
    """:func:`polar_profile`, compiled (``max_gap_bins``: the widest gap filled, in bins)."""
    prof = np.full(n_bins, np.inf)
    if pts.shape[0] == 0:
        prof[:] = np.nan
        return prof
    for i in range(pts.shape[0]):
        b = _bin(pts[i, 0], pts[i, 1], n_bins)
        r = math.hypot(pts[i, 0], pts[i, 1])
        if r < prof[b]:
            prof[b] = r
    if gap_free_m > 0.0:
        first = last = -1
        n_occ = 0
        for b in range(n_bins):
            if prof[b] < np.inf:
                n_occ += 1
                last = b
                if first < 0:
                    first = b
        if 0 < n_occ < n_bins:
            # the nearest bin with a return after each bin (circularly), by a backward sweep
            nxt = np.empty(n_bins, np.int64)
            after = first
            for b in range(n_bins - 1, -1, -1):
                nxt[b] = after
                if prof[b] < np.inf:
                    after = b
            prev = last  # the nearest bin with a return before (circularly)
            for b in range(n_bins):
                if prof[b] < np.inf:
                    prev = b
                    continue
                gap = nxt[b] - prev - 1
                if gap < 0:
                    gap += n_bins
                if gap <= max_gap_bins:
                    prof[b] = min(prof[prev], prof[nxt[b]], gap_free_m)
    for b in range(n_bins):
        if prof[b] == np.inf:
            prof[b] = np.nan
    return prof


def free_space_violation(
    profile_m: np.ndarray, points_m: np.ndarray, margin_m: float = MARGIN_M, margin_ratio: float = MARGIN_RATIO
) -> float:
    """Fraction of ``points_m`` (N×2, in the profile's sensor frame) lying in space the sensor saw empty.

    A point at range ρ in a bin of free range R violates when
    ``ρ < R − max(margin_m, margin_ratio·R)``; points in bins without a return do not count.
    Aligning a scan to a *wrong* but similar place (another office of the
    same corridor) puts many of its points in the other scan's free space.
    """
    pts = np.ascontiguousarray(np.asarray(points_m, dtype=np.float64))
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise InputError(f"points_m must be N×2, got shape {pts.shape}")
    if len(pts) == 0:
        return 0.0
    if np.isnan(pts).any():
        raise InputError("points_m contains NaN values")
    prof = np.ascontiguousarray(np.asarray(profile_m, dtype=np.float64))
    if prof.ndim != 1 or len(prof) == 0:
        raise InputError(f"profile_m must be a non-empty 1-D array, got shape {prof.shape}")
    bad = _violations(prof, pts, False, 1.0, 0.0, 0.0, 0.0, float(margin_m), float(margin_ratio))
    return float(bad) / len(pts)


@njit(cache=True)
def _violations(
    prof: np.ndarray,
    pts: np.ndarray,
    moved: bool,
    c: float,
    s: float,
    tx: float,
    ty: float,
    margin_m: float,
    margin_ratio: float,
) -> int:
    """How many of ``pts`` (moved by ``(c, s, tx, ty)`` into the profile's frame first when ``moved``) violate
    the free space of ``prof`` (:func:`free_space_violation`)."""
    n_bins = len(prof)
    bad = 0
    for i in range(pts.shape[0]):
        x, y = pts[i, 0], pts[i, 1]
        if moved:
            x, y = x * c - y * s + tx, x * s + y * c + ty
        free = prof[_bin(x, y, n_bins)]
        if math.hypot(x, y) < free - max(margin_m, margin_ratio * free):  # NaN (no return) never compares true
            bad += 1
    return bad


def _check_scan_and_profile(points: np.ndarray, profile: np.ndarray | None, name: str) -> None:
    """InputError unless ``points`` is N×2 float64, finite, N ≥ 1 and ``profile`` (unless None) a non-empty 1-D
    float64 array (what the compiled free-space functions index without bounds checks)."""
    if not (isinstance(points, np.ndarray) and points.dtype == np.float64 and points.ndim == 2 and points.shape[1] == 2):
        raise InputError(f"{name} must be an N×2 float64 array, got {type(points).__name__} {np.shape(points)}")
    if len(points) == 0 or not np.isfinite(points).all():
        raise InputError(f"{name} must hold at least one point, all finite")
    if profile is not None and not (
        isinstance(profile, np.ndarray) and profile.dtype == np.float64 and profile.ndim == 1 and len(profile) >= 1
    ):
        raise InputError(f"the profile of {name} must be a non-empty 1-D float64 array, got shape {np.shape(profile)}")


def alignment_violation(
    profile_a: np.ndarray, points_a: np.ndarray, profile_b: np.ndarray, points_b: np.ndarray, T_a_b, *, validate: bool = True
) -> float:
    """Free-space violation of an alignment, the larger of the two directions (one compiled call).

    ``points_b`` (scan b, its sensor frame) moved by ``T_a_b`` into a's frame against ``profile_a``, and
    ``points_a`` moved by ``T_a_b⁻¹`` into b's frame against ``profile_b`` (:func:`free_space_violation`,
    default margins): N×2 float64 arrays of finite points (N ≥ 1) and profiles from :func:`polar_profile`
    (:class:`~factorloc.errors.InputError` otherwise, before the compiled code); ``T_a_b`` is a
    :class:`~factorloc.geometry.Pose2`. ``validate=False`` skips those checks: for a caller whose arrays passed
    them already (the ICP step's scans, validated when it aligned them); the compiled code does not bound-check.
    """
    if validate:
        _check_scan_and_profile(points_a, profile_a, "points_a")
        _check_scan_and_profile(points_b, profile_b, "points_b")
    return _alignment_violation(profile_a, points_b, *_rigid(T_a_b), profile_b, points_a, *_rigid(T_a_b.inverse()))


@njit(cache=True)
def _alignment_violation(
    prof_a: np.ndarray,
    pts_b: np.ndarray,
    c_ab: float,
    s_ab: float,
    x_ab: float,
    y_ab: float,
    prof_b: np.ndarray,
    pts_a: np.ndarray,
    c_ba: float,
    s_ba: float,
    x_ba: float,
    y_ba: float,
) -> float:
    v_b = _violations(prof_a, pts_b, True, c_ab, s_ab, x_ab, y_ab, MARGIN_M, MARGIN_RATIO) / pts_b.shape[0]
    v_a = _violations(prof_b, pts_a, True, c_ba, s_ba, x_ba, y_ba, MARGIN_M, MARGIN_RATIO) / pts_a.shape[0]
    return max(v_b, v_a)


def profile_and_violation(
    profile_a: np.ndarray, points_a: np.ndarray, points_b: np.ndarray, T_a_b, gap_free_m: float, *, validate: bool = True
) -> tuple[np.ndarray, float]:
    """Scan b's :func:`polar_profile` (default bins and gap width, ``gap_free_m``) and
    :func:`alignment_violation` of ``T_a_b`` with it, in one compiled call; the arrays and ``validate`` as there."""
    if validate:
        _check_scan_and_profile(points_a, profile_a, "points_a")
        _check_scan_and_profile(points_b, None, "points_b")
    return _profile_and_violation(
        profile_a,
        points_a,
        points_b,
        *_rigid(T_a_b),
        *_rigid(T_a_b.inverse()),
        PROFILE_BINS,
        float(gap_free_m),
        _gap_bins(PROFILE_MAX_GAP_RAD, PROFILE_BINS),
    )


@njit(cache=True)
def _profile_and_violation(
    prof_a: np.ndarray,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    c_ab: float,
    s_ab: float,
    x_ab: float,
    y_ab: float,
    c_ba: float,
    s_ba: float,
    x_ba: float,
    y_ba: float,
    n_bins: int,
    gap_free_m: float,
    max_gap_bins: int,
) -> tuple[np.ndarray, float]:
    prof_b = _profile(pts_b, n_bins, gap_free_m, max_gap_bins)
    v = _alignment_violation(prof_a, pts_b, c_ab, s_ab, x_ab, y_ab, prof_b, pts_a, c_ba, s_ba, x_ba, y_ba)
    return prof_b, v


def overlap_fitness(
    profile_a: np.ndarray,
    points_a: np.ndarray,
    profile_b: np.ndarray,
    points_b: np.ndarray,
    T_a_b,
    distance_m: float,
) -> tuple[float, int]:
    """Fitness over the points each scan's sensor could have seen, the smaller of the two directions, and that count.

    A point of one scan, put in the other sensor's frame (scan b by ``T_a_b``, scan a by its inverse), is
    *visible* to that sensor when its bearing lies in a bin with a return (a finite free range R of the
    other's ``profile``, :func:`polar_profile`) and it is not farther than ``R + max(0.15 m, 0.05 R)`` (not
    hidden behind what the sensor saw); it fits when a point of the other scan lies closer than
    ``distance_m`` (exact nearest neighbours on a grid, :func:`~factorloc.registration.nn.grid_nearest`).
    Returns ``(min(f_a, f_b), min(n_a, n_b))``, a direction without a visible point counting as (0, 0).
    Arrays as for :func:`alignment_violation`.
    """
    _check_scan_and_profile(points_a, profile_a, "points_a")
    _check_scan_and_profile(points_b, profile_b, "points_b")
    f1, n1, f2, n2 = _overlap_fitness(
        profile_a, points_a, points_b, *_rigid(T_a_b), profile_b, *_rigid(T_a_b.inverse()), float(distance_m)
    )
    return min(f1, f2), min(n1, n2)


@njit(cache=True)
def _visible_fit(
    prof: np.ndarray, pts: np.ndarray, c: float, s: float, tx: float, ty: float, other: np.ndarray, d: float
) -> tuple[float, int]:
    """One direction of :func:`overlap_fitness`: ``pts`` moved by ``(c, s, tx, ty)`` into the frame of ``prof``
    and of the points ``other``."""
    order, start, geo = build_grid(other[:, 0].copy(), other[:, 1].copy(), GRID_CELL_M, GRID_MAX_CELLS)
    grid_pts = other[order]
    n_bins = len(prof)
    n_vis = 0
    n_fit = 0
    d2 = d * d * (1.0 + 1e-9)
    for i in range(pts.shape[0]):
        x, y = pts[i, 0], pts[i, 1]
        x, y = x * c - y * s + tx, x * s + y * c + ty
        free = prof[_bin(x, y, n_bins)]
        if not (math.isfinite(free) and math.hypot(x, y) <= free + max(MARGIN_M, MARGIN_RATIO * free)):
            continue
        n_vis += 1
        best, k = grid_nearest(x, y, grid_pts, start, geo, d2)
        if k >= 0 and math.sqrt(best) < d:
            n_fit += 1
    if n_vis == 0:
        return 0.0, 0
    return n_fit / n_vis, n_vis


@njit(cache=True)
def _overlap_fitness(
    prof_a: np.ndarray,
    pts_a: np.ndarray,
    pts_b: np.ndarray,
    c_ab: float,
    s_ab: float,
    x_ab: float,
    y_ab: float,
    prof_b: np.ndarray,
    c_ba: float,
    s_ba: float,
    x_ba: float,
    y_ba: float,
    d: float,
) -> tuple[float, int, float, int]:
    f1, n1 = _visible_fit(prof_a, pts_b, c_ab, s_ab, x_ab, y_ab, pts_a, d)
    f2, n2 = _visible_fit(prof_b, pts_a, c_ba, s_ba, x_ba, y_ba, pts_b, d)
    return f1, n1, f2, n2

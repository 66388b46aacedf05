"""2D scan preparation: the patent's horizontal cut of a 3D cloud, voxel
downsampling, and line normals.

All points are N×2 (or N×3 for clouds) metres in the robot frame
(x forward, y left, z up from the floor).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from factorloc.errors import InputError
from factorloc.registration.nn import GRID_CELL_M, GRID_MAX_CELLS, KdTree2D, build_grid, grid_nearest, lift_2d
from factorloc.types import PointCloud, Scan

#: Bearing bins of :func:`polar_profile` (0.5° each), and the widest gap between returns it fills (rad).
PROFILE_BINS = 720
PROFILE_MAX_GAP_RAD = 0.35
#: Free-space margins: a point closer than ``R − max(MARGIN_M, MARGIN_RATIO·R)`` to the sensor violates the free
#: range R of its bin, and one farther than ``R + max(MARGIN_M, MARGIN_RATIO·R)`` is hidden behind the return.
MARGIN_M = 0.15
MARGIN_RATIO = 0.05

__all__ = [
    "ScanExtraction",
    "alignment_violation",
    "estimate_normals_2d",
    "extract_scan",
    "free_space_violation",
    "limit_count",
    "overlap_fitness",
    "polar_profile",
    "profile_and_violation",
    "voxel_downsample_2d",
]


@dataclass(frozen=True)
class ScanExtraction:
    """How a 2D scan is cut out of a 3D cloud (patent: a horizontal slice, projected).

    Parameters
    ----------
    min_height_m, max_height_m
        The height band kept (z above the floor, metres). The defaults drop
        the floor and the ceiling and keep a band that a depth camera at
        1.0 m with a 45° vertical field of view sees *at every range* from
        0.4 m on (±0.166 m): a wider band cuts furniture at heights that one
        view sees and another does not, and ICP then matches different
        outlines of the same object (measured: a 0.15–1.8 m band slid
        seeded ICP by up to 0.8 m in the simulated apartment).
    voxel_m
        Side of the 2D voxel grid: one point (the centroid) per occupied cell.
    max_points
        Upper bound on the scan size after downsampling (uniform subsampling
        with a fixed stride beyond it, deterministic).
    max_range_m
        Points farther than this from the sensor are dropped (0 = keep all).
    """

    min_height_m: float = 0.85
    max_height_m: float = 1.15
    voxel_m: float = 0.05
    max_points: int = 1500
    max_range_m: float = 0.0

    def __post_init__(self) -> None:
        if not self.max_height_m > self.min_height_m:
            raise InputError(f"ScanExtraction: max_height_m ({self.max_height_m}) must exceed min_height_m ({self.min_height_m})")
        if self.voxel_m < 0.0:
            raise InputError(f"ScanExtraction.voxel_m must be >= 0, got {self.voxel_m!r}")
        if self.max_points < 3:
            raise InputError(f"ScanExtraction.max_points must be >= 3, got {self.max_points!r}")
        if self.max_range_m < 0.0:
            raise InputError(f"ScanExtraction.max_range_m must be >= 0, got {self.max_range_m!r}")


def voxel_downsample_2d(points_m: np.ndarray, voxel_m: float) -> np.ndarray:
    """Replace the points of each occupied ``voxel_m`` square cell by their centroid.

    The output is ordered by cell (deterministic). ``voxel_m = 0`` returns a copy.
    """
    pts = np.asarray(points_m, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise InputError(f"points_m must be N×2, got shape {pts.shape}")
    if voxel_m <= 0.0 or len(pts) == 0:
        return pts.copy()
    cells = np.floor(pts / voxel_m).astype(np.int64)
    _, inverse, counts = np.unique(cells, axis=0, return_inverse=True, return_counts=True)
    inverse = inverse.ravel()
    sums = np.zeros((len(counts), 2))
    np.add.at(sums, inverse, pts)
    return sums / counts[:, None]


def limit_count(points_m: np.ndarray, max_points: int) -> np.ndarray:
    """Keep at most ``max_points`` points by a fixed-stride subsampling (deterministic)."""
    pts = np.asarray(points_m)
    if len(pts) <= max_points:
        return pts
    idx = np.round(np.linspace(0, len(pts) - 1, max_points)).astype(np.int64)
    return pts[idx]


def extract_scan(cloud: PointCloud, params: ScanExtraction = ScanExtraction()) -> Scan:
    """Cut a 2D scan out of a 3D cloud: height band → projection → voxel grid → bounded count.

    Missing returns (absent points) need no special handling: the cut only
    keeps what was measured. Raises :class:`~factorloc.errors.InputError`
    when fewer than 3 points remain in the band (no scan to match).
    """
    if not isinstance(cloud, PointCloud):
        raise InputError(f"cloud must be a PointCloud, got {type(cloud).__name__}")
    p = cloud.points_m
    keep = (p[:, 2] >= params.min_height_m) & (p[:, 2] <= params.max_height_m)
    xy = p[keep, :2]
    if params.max_range_m > 0.0:
        xy = xy[np.hypot(xy[:, 0], xy[:, 1]) <= params.max_range_m]
    xy = voxel_downsample_2d(xy, params.voxel_m)
    # angular order (as a laser would return them) so that the bounded subsampling is spread evenly
    xy = xy[np.argsort(np.arctan2(xy[:, 1], xy[:, 0]), kind="stable")]
    xy = limit_count(xy, params.max_points)
    if len(xy) < 3:
        raise InputError(
            f"cloud has {len(xy)} point(s) in the height band [{params.min_height_m}, {params.max_height_m}] m; "
            "need >= 3 for a scan"
        )
    return Scan(xy)


def estimate_normals_2d(
    points_m: np.ndarray,
    k: int = 7,
    max_radius_m: float = 0.5,
    tree: KdTree2D | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Line normals and their quality by PCA over the ``k`` nearest neighbours.

    For each point, the covariance of its neighbours within ``max_radius_m``
    (among its ``k`` nearest, itself included) is eigen-decomposed; the
    normal is the eigenvector of the smallest eigenvalue, oriented towards
    the sensor (origin). The quality is ``1 - λ_min/λ_max`` in [0, 1] (1 =
    perfectly straight); points with fewer than 3 neighbours get quality 0
    and a normal pointing at the sensor.

    The neighbours come from ``tree`` (a :class:`~factorloc.registration.nn.KdTree2D` on ``points_m``, built
    when not given); the PCA runs compiled (:func:`pca_normals`).

    Returns
    -------
    normals : (N, 2) unit vectors
    quality : (N,) in [0, 1]
    """
    pts = np.ascontiguousarray(np.asarray(points_m, dtype=np.float64))
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise InputError(f"points_m must be N×2, got shape {pts.shape}")
    n = len(pts)
    if n == 0:
        return np.zeros((0, 2)), np.zeros(0)
    if not np.isfinite(pts).all():
        raise InputError("points_m contains NaN or infinite values")
    if tree is None:
        tree = KdTree2D(pts)
        lifted = tree.lifted
    else:
        lifted = lift_2d(pts)
    kk = min(k, n)
    d, idx = tree.nearest_lifted(lifted, kk)
    return pca_normals(pts, d.reshape(n, kk), idx.reshape(n, kk), float(max_radius_m))


def pca_normals(pts: np.ndarray, d: np.ndarray, idx: np.ndarray, max_radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    """The PCA of :func:`estimate_normals_2d`: ``pts`` (N×2 float64), ``d``/``idx`` (N×k) the distances and
    indices of each point's k nearest neighbours (itself included), nearest first; returns (normals, quality).

    Per point, over its neighbours closer than ``max_radius_m``, relative to the point (no cancellation): the
    scatter ``S = Σ u uᵀ − (Σ u)(Σ u)ᵀ / n``, its eigenvalues ``(sxx + syy)/2 ± √(((sxx − syy)/2)² + sxy²)``
    and the line's direction ``φ = ½ atan2(2 sxy, sxx − syy)``; the normal ``(−sin φ, cos φ)`` faces the sensor
    at the origin.

    For k = 7 (``IcpParams.normal_k``'s default) the sums run compiled (:func:`_pca_sums`, :func:`_pca_finish`)
    in the order numpy's ``matmul``/``einsum`` add them on this platform, and ``φ`` comes from ``numpy.arctan2``,
    so that the normals are bit for bit those of the plain numpy form (:func:`_pca_numpy`, used for other k);
    ``tests/registration/test_scan2d.py`` checks it.
    """
    n, kk = d.shape
    normals = np.empty((n, 2))
    quality = np.empty(n)
    if kk != 7:
        return _pca_numpy(pts, d, idx, max_radius_m)
    sums = np.empty((6, n))  # cnt, sxx, syy, sxy, half_diff, root
    _pca_sums(pts, d, idx, max_radius_m, sums)
    phi = np.arctan2(sums[3], sums[4])
    phi *= 0.5
    _pca_finish(pts, sums, phi, normals, quality)
    return normals, quality


def _pca_numpy(pts: np.ndarray, d: np.ndarray, idx: np.ndarray, max_radius_m: float) -> tuple[np.ndarray, np.ndarray]:
    """:func:`pca_normals` in plain numpy (vectorized over the points)."""
    n, kk = d.shape
    vf = (d < max_radius_m).astype(np.float64)
    x, y = pts[:, 0], pts[:, 1]
    ux = x.take(idx)
    ux -= x[:, None]
    ux *= vf
    uy = y.take(idx)
    uy -= y[:, None]
    uy *= vf
    ones = np.ones(kk)
    cnt = vf @ ones
    sx, sy = ux @ ones, uy @ ones
    inv = 1.0 / np.maximum(cnt, 1.0)
    sxx = np.einsum("ij,ij->i", ux, ux) - sx * sx * inv
    syy = np.einsum("ij,ij->i", uy, uy) - sy * sy * inv
    sxy = np.einsum("ij,ij->i", ux, uy) - sx * sy * inv
    half_diff = 0.5 * (sxx - syy)
    root = np.sqrt(half_diff * half_diff + sxy * sxy)
    mean = 0.5 * (sxx + syy)
    lmax = mean + root
    lmin = mean - root
    phi = 0.5 * np.arctan2(sxy, half_diff)
    normals = np.empty((n, 2))
    np.sin(phi, out=normals[:, 0])
    normals[:, 0] *= -1.0
    np.cos(phi, out=normals[:, 1])
    quality = lmin / np.maximum(lmax, 1e-300)
    np.subtract(1.0, quality, out=quality)
    quality *= lmax > 0.0  # all neighbours at one spot: no line
    to_sensor = pts / -np.maximum(np.hypot(x, y), 1e-12)[:, None]
    poor = cnt < 3.0
    np.copyto(normals, to_sensor, where=poor[:, None])
    quality[poor] = 0.0
    normals *= np.where(np.einsum("ij,ij->i", normals, to_sensor) < 0.0, -1.0, 1.0)[:, None]  # face the sensor
    np.maximum(quality, 0.0, out=quality)  # rounding: λmin may come out slightly negative
    np.minimum(quality, 1.0, out=quality)
    return normals, quality


@njit(cache=True)
def _pca_sums(pts: np.ndarray, d: np.ndarray, idx: np.ndarray, max_radius_m: float, out: np.ndarray) -> None:
    """:func:`_pca_numpy`'s sums for k = 7, in numpy's order: ``u @ ones(7)`` adds ``((u0 + u2) + (u1 + u3)) +
    ((u4 + u5) + u6)`` (OpenBLAS's 4-lane dot product and its tail), ``einsum('ij,ij->i')`` two alternating
    accumulators ``(p0 + p2 + p4 + p6) + (p1 + p3 + p5)``. Rows of ``out``: cnt, sxx, syy, sxy, half_diff, root."""
    n = pts.shape[0]
    ux = np.zeros(7)
    uy = np.zeros(7)
    for i in range(n):
        x, y = pts[i, 0], pts[i, 1]
        cnt = 0.0
        for j in range(7):
            if d[i, j] < max_radius_m:
                cnt += 1.0
                ux[j] = pts[idx[i, j], 0] - x
                uy[j] = pts[idx[i, j], 1] - y
            else:
                ux[j] = 0.0
                uy[j] = 0.0
        sx = ((ux[0] + ux[2]) + (ux[1] + ux[3])) + ((ux[4] + ux[5]) + ux[6])
        sy = ((uy[0] + uy[2]) + (uy[1] + uy[3])) + ((uy[4] + uy[5]) + uy[6])
        exx = (ux[0] * ux[0] + ux[2] * ux[2] + ux[4] * ux[4] + ux[6] * ux[6]) + (ux[1] * ux[1] + ux[3] * ux[3] + ux[5] * ux[5])
        eyy = (uy[0] * uy[0] + uy[2] * uy[2] + uy[4] * uy[4] + uy[6] * uy[6]) + (uy[1] * uy[1] + uy[3] * uy[3] + uy[5] * uy[5])
        exy = (ux[0] * uy[0] + ux[2] * uy[2] + ux[4] * uy[4] + ux[6] * uy[6]) + (ux[1] * uy[1] + ux[3] * uy[3] + ux[5] * uy[5])
        inv = 1.0 / max(cnt, 1.0)
        sxx = exx - sx * sx * inv
        syy = eyy - sy * sy * inv
        sxy = exy - sx * sy * inv
        half_diff = 0.5 * (sxx - syy)
        out[0, i] = cnt
        out[1, i] = sxx
        out[2, i] = syy
        out[3, i] = sxy
        out[4, i] = half_diff
        out[5, i] = math.sqrt(half_diff * half_diff + sxy * sxy)


@njit(cache=True)
def _pca_finish(pts: np.ndarray, sums: np.ndarray, phi: np.ndarray, normals: np.ndarray, quality: np.ndarray) -> None:
    """:func:`_pca_numpy` after ``φ``: the normals, their orientation and quality, per point."""
    for i in range(pts.shape[0]):
        x, y = pts[i, 0], pts[i, 1]
        cnt, sxx, syy, root = sums[0, i], sums[1, i], sums[2, i], sums[5, i]
        mean = 0.5 * (sxx + syy)
        lmax = mean + root
        lmin = mean - root
        rng = max(math.hypot(x, y), 1e-12)
        tx, ty = x / -rng, y / -rng  # the unit vector towards the sensor
        if cnt < 3.0:
            nx, ny, q = tx, ty, 0.0
        else:
            nx, ny = -math.sin(phi[i]), math.cos(phi[i])
            q = 1.0 - lmin / max(lmax, 1e-300) if lmax > 0.0 else 0.0  # all neighbours at one spot: no line
            q = min(max(q, 0.0), 1.0)  # rounding: λmin may come out slightly negative
        if nx * tx + ny * ty < 0.0:  # face the sensor
            nx, ny = -nx, -ny
        normals[i, 0], normals[i, 1] = nx, ny
        quality[i] = q


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
def _profile(pts: np.ndarray, n_bins: int, gap_free_m: float, max_gap_bins: int) -> np.ndarray:
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


def alignment_violation(profile_a: np.ndarray, points_a: np.ndarray, profile_b: np.ndarray, points_b: np.ndarray, T_a_b) -> float:
    """Free-space violation of an alignment, the larger of the two directions (one compiled call).

    ``points_b`` (scan b, its sensor frame) moved by ``T_a_b`` into a's frame against ``profile_a``, and
    ``points_a`` moved by ``T_a_b⁻¹`` into b's frame against ``profile_b`` (:func:`free_space_violation`,
    default margins): N×2 float64 arrays of finite points (N ≥ 1) and profiles from :func:`polar_profile`
    (:class:`~factorloc.errors.InputError` otherwise, before the compiled code); ``T_a_b`` is a
    :class:`~factorloc.geometry.Pose2`.
    """
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
    profile_a: np.ndarray, points_a: np.ndarray, points_b: np.ndarray, T_a_b, gap_free_m: float
) -> tuple[np.ndarray, float]:
    """Scan b's :func:`polar_profile` (default bins and gap width, ``gap_free_m``) and
    :func:`alignment_violation` of ``T_a_b`` with it, in one compiled call; the arrays as there."""
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

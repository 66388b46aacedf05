"""2D scan preparation: the patent's horizontal cut of a 3D cloud, voxel
downsampling, and line normals (the free-space measures live in :mod:`~factorloc.registration.freespace` and
are re-exported here).

All points are N×2 (or N×3 for clouds) metres in the robot frame
(x forward, y left, z up from the floor).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit

from factorloc.errors import InputError
from factorloc.registration.freespace import (
    MARGIN_M,
    MARGIN_RATIO,
    PROFILE_BINS,
    PROFILE_MAX_GAP_RAD,
    alignment_violation,
    free_space_violation,
    overlap_fitness,
    polar_profile,
    profile_and_violation,
)
from factorloc.registration.nn import KdTree2D, lift_2d
from factorloc.types import PointCloud, Scan

__all__ = [
    "MARGIN_M",
    "MARGIN_RATIO",
    "PROFILE_BINS",
    "PROFILE_MAX_GAP_RAD",
    "ScanExtraction",
    "alignment_violation",
    "estimate_normals_2d",
    "extract_scan",
    "free_space_violation",
    "limit_count",
    "median_range_m",
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
    lo = cells.min(axis=0)
    span = cells.max(axis=0) - lo + 1
    if float(span[0]) * float(span[1]) < 2.0**62:
        # one int64 key per cell, in the (x, y) lexicographic order of the rows' unique: the same cells in the same
        # order, sorted in 1-D; bincount sums each cell's points in input order, as add.at does (the same bits)
        key = (cells[:, 0] - lo[0]) * span[1] + (cells[:, 1] - lo[1])
        _, inverse, counts = np.unique(key, return_inverse=True, return_counts=True)
        n = len(counts)
        sums = np.column_stack([np.bincount(inverse, pts[:, 0], n), np.bincount(inverse, pts[:, 1], n)])
    else:  # cells too far apart for one key
        _, inverse, counts = np.unique(cells, axis=0, return_inverse=True, return_counts=True)
        inverse = inverse.ravel()
        sums = np.zeros((len(counts), 2))
        np.add.at(sums, inverse, pts)
    return sums / counts[:, None]


def median_range_m(points_m: np.ndarray) -> float:
    """The median range (m) of N×2 points (N ≥ 1, finite) from their frame's origin: ``np.median(np.hypot(x, y))``
    in one compiled call (the same bits: the same hypot, the middle values selected exactly, and their mean as
    ``0.5·(a + b)``). Not validated: for points a caller has checked."""
    return float(_median_range(np.ascontiguousarray(points_m, dtype=np.float64)))


@njit(cache=True)
def _median_range(pts: np.ndarray) -> float:
    n = pts.shape[0]
    r = np.empty(n)
    for i in range(n):
        r[i] = math.hypot(pts[i, 0], pts[i, 1])
    k = n // 2
    part = np.partition(r, k)  # part[k] in place, the smaller values before it
    if n % 2:
        return part[k]
    return 0.5 * (part[:k].max() + part[k])


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

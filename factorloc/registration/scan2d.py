"""2D scan preparation: the patent's horizontal cut of a 3D cloud, voxel
downsampling, and line normals.

All points are N×2 (or N×3 for clouds) metres in the robot frame
(x forward, y left, z up from the floor).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from factorloc.errors import InputError
from factorloc.registration.nn import KdTree2D, lift_2d
from factorloc.types import PointCloud, Scan

__all__ = [
    "ScanExtraction",
    "estimate_normals_2d",
    "extract_scan",
    "free_space_violation",
    "limit_count",
    "polar_profile",
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
    is eigen-decomposed; the normal is the eigenvector of the smallest
    eigenvalue, oriented towards the sensor (origin). The quality is
    ``1 - λ_min/λ_max`` in [0, 1] (1 = perfectly straight); points with fewer
    than 3 neighbours get quality 0 and a normal pointing at the sensor.

    Returns
    -------
    normals : (N, 2) unit vectors
    quality : (N,) in [0, 1]
    """
    pts = np.asarray(points_m, dtype=np.float64)
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
    idx = idx.reshape(n, kk)
    # neighbours within the radius, relative to the point itself (no cancellation); the others weigh 0
    vf = (d.reshape(n, kk) < max_radius_m).astype(np.float64)
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
    # scatter Σ (u − ū)(u − ū)ᵀ = Σ u uᵀ − (Σ u)(Σ u)ᵀ / cnt
    sxx = np.einsum("ij,ij->i", ux, ux) - sx * sx * inv
    syy = np.einsum("ij,ij->i", uy, uy) - sy * sy * inv
    sxy = np.einsum("ij,ij->i", ux, uy) - sx * sy * inv
    # closed-form eigen-decomposition of the 2×2 symmetric [[sxx, sxy], [sxy, syy]]
    half_diff = 0.5 * (sxx - syy)
    root = np.sqrt(half_diff * half_diff + sxy * sxy)
    mean = 0.5 * (sxx + syy)
    lmax = mean + root
    lmin = mean - root
    # direction of the line (largest eigenvalue): angle φ = 0.5·atan2(2 sxy, sxx − syy); normal (−sin φ, cos φ)
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
    # face the sensor
    normals *= np.where(np.einsum("ij,ij->i", normals, to_sensor) < 0.0, -1.0, 1.0)[:, None]
    np.maximum(quality, 0.0, out=quality)  # rounding: λmin may come out slightly negative
    np.minimum(quality, 1.0, out=quality)
    return normals, quality


def polar_profile(points_m: np.ndarray, n_bins: int = 720, gap_free_m: float = 0.0, max_gap_rad: float = 0.35) -> np.ndarray:
    """Free range per bearing bin seen from the sensor at the origin: (n_bins,) metres, NaN where unknown.

    Bin ``k`` covers bearings ``[-π + 2πk/n, -π + 2π(k+1)/n)``; its free range
    is the *shortest* return in it (conservative: space closer than every
    return of the bin was seen empty by the sensor). Bins without a return
    inside an angular gap narrower than ``max_gap_rad`` between returns (a
    doorway, a window, sparse returns, a beam past the sensor's range) are
    taken as free up to the nearer of the two returns bounding the gap, at
    most ``gap_free_m`` (when it is > 0); wider gaps (outside the field of
    view) stay unknown.
    """
    pts = np.asarray(points_m, dtype=np.float64)
    prof = np.full(n_bins, np.inf)
    if len(pts) == 0:
        return np.full(n_bins, np.nan)
    np.minimum.at(prof, _bearing_bins(pts, n_bins), np.hypot(pts[:, 0], pts[:, 1]))
    if gap_free_m > 0.0:
        occ = np.flatnonzero(prof < np.inf)  # the bins with a return, increasing
        if 0 < len(occ) < n_bins:
            # for every bin, the nearest bin with a return before and after it (circularly)
            pos = np.searchsorted(occ, np.arange(n_bins))
            prev = occ.take(pos - 1)  # pos 0: the last one (wraps)
            nxt = occ.take(pos, mode="wrap")  # pos = len(occ): the first one
            gap = nxt - prev - 1
            gap[gap < 0] += n_bins
            fill = (gap <= int(max_gap_rad / (2 * np.pi) * n_bins)) & (prof == np.inf)
            bound = np.minimum(prof.take(prev), prof.take(nxt))
            np.minimum(bound, gap_free_m, out=bound)
            np.copyto(prof, bound, where=fill)
    prof[prof == np.inf] = np.nan
    return prof


def _bearing_bins(pts: np.ndarray, n_bins: int) -> np.ndarray:
    """Bin of each point's bearing: ``floor((atan2(y, x) + π) / 2π · n) mod n``."""
    b = np.floor((np.arctan2(pts[:, 1], pts[:, 0]) + np.pi) / (2 * np.pi) * n_bins).astype(np.int64)
    b[b >= n_bins] -= n_bins  # bearing +π: the bin of −π
    return b


def free_space_violation(
    profile_m: np.ndarray, points_m: np.ndarray, margin_m: float = 0.15, margin_ratio: float = 0.05
) -> float:
    """Fraction of ``points_m`` (N×2, in the profile's sensor frame) lying in space the sensor saw empty.

    A point at range ρ in a bin of free range R violates when
    ``ρ < R − max(margin_m, margin_ratio·R)``; points in bins without a return do not count.
    Aligning a scan to a *wrong* but similar place (another office of the
    same corridor) puts many of its points in the other scan's free space.
    """
    pts = np.asarray(points_m, dtype=np.float64)
    if len(pts) == 0:
        return 0.0
    prof = np.asarray(profile_m, dtype=np.float64)
    free = prof.take(_bearing_bins(pts, len(prof)))
    # a bin without a return (NaN) never compares true
    bad = np.hypot(pts[:, 0], pts[:, 1]) < free - np.maximum(margin_m, margin_ratio * free)
    return float(np.count_nonzero(bad)) / len(pts)

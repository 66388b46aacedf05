"""The ICP parameters and the prepared target scan of :func:`factorloc.registration.icp2d.align`.

:class:`IcpParams` holds what the compiled core reads (packed once into ``IcpParams._core``, indexed by the
``_P_*`` constants below); :func:`prepare_target` builds a target's KD-tree, PCA line normals and search grid
once per reference (:class:`PreparedScan`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from factorloc._validate import MAX_COORDINATE_M
from factorloc.errors import InputError
from factorloc.registration.nn import GRID_CELL_M, GRID_MAX_CELLS, KdTree2D, build_grid
from factorloc.registration.scan2d import pca_normals

__all__ = ["MAX_COORDINATE_M", "IcpParams", "PreparedScan", "check_coordinates", "prepare_target"]

# indices of IcpParams._core
_P_MAX_ITER, _P_MIN_GATE, _P_SHRINK, _P_CONV_T, _P_CONV_R, _P_FIT_D, _P_CAP, _P_QUALITY, _P_SP2, _P_SB2, _P_REASSOC = range(11)


@dataclass(frozen=True)
class IcpParams:
    """Parameters of :func:`align` (metres, radians).

    Parameters
    ----------
    max_iterations
        Gauss–Newton iterations at most.
    max_correspondence_m, min_correspondence_m, shrink
        The correspondence gate of iteration k is
        ``max(min_correspondence_m, max_correspondence_m · shrink^k)``.
    convergence_translation_m, convergence_rotation_rad
        Stop once the gate is at its minimum and an update is below both.
    fitness_distance_m
        A source point is an *inlier* (counts towards ``fitness``) when its
        nearest target point is closer than this after alignment.
    chamfer_cap_m
        Nearest-neighbour distances are truncated at this value in the
        Chamfer distance (so that the parts of the scans that do not overlap
        weigh a bounded amount).
    normal_k
        Neighbours of the PCA line normals of the target.
    normal_radius_m
        Radius of that neighbourhood (m).
    min_normal_quality
        Target points whose line fit quality (1 − λmin/λmax) is lower do not
        take part (corners, isolated returns).
    sigma_point_m, sigma_bearing_rad
        Noise model of a point at range ρ from its sensor (at the frame
        origin): ``σ² = sigma_point_m² + (sigma_bearing_rad·ρ)²``. A pair's
        residual variance is the sum of its two points'; the IRLS weights are
        multiplied by ``2·sigma_point_m² / σ²_pair`` (far, sparse returns weigh
        less) and the covariance estimators use ``σ²_pair``.
    reassociate_m
        At the smallest gate, the nearest neighbours are searched again only
        once the points have moved by more than this since the last search
        (0 = every iteration); in between, Gauss–Newton iterates on the same
        pairs. The final linearisation always uses fresh neighbours.
    """

    max_iterations: int = 40
    max_correspondence_m: float = 1.0
    min_correspondence_m: float = 0.2
    shrink: float = 0.6
    convergence_translation_m: float = 3e-4
    convergence_rotation_rad: float = 1e-4
    fitness_distance_m: float = 0.1
    chamfer_cap_m: float = 0.5
    normal_k: int = 7
    normal_radius_m: float = 0.5
    min_normal_quality: float = 0.5
    sigma_point_m: float = 0.01
    sigma_bearing_rad: float = 0.0
    reassociate_m: float = 0.0

    def __post_init__(self) -> None:
        if self.max_iterations < 1:
            raise InputError(f"IcpParams.max_iterations must be >= 1, got {self.max_iterations!r}")
        if not 0.0 < self.min_correspondence_m <= self.max_correspondence_m:
            raise InputError(
                "IcpParams needs 0 < min_correspondence_m <= max_correspondence_m, "
                f"got {self.min_correspondence_m!r}, {self.max_correspondence_m!r}"
            )
        if not 0.0 < self.shrink <= 1.0:
            raise InputError(f"IcpParams.shrink must be in (0, 1], got {self.shrink!r}")
        for name in ("fitness_distance_m", "chamfer_cap_m", "normal_radius_m"):
            if getattr(self, name) <= 0.0:
                raise InputError(f"IcpParams.{name} must be > 0, got {getattr(self, name)!r}")
        if self.normal_k < 3:
            raise InputError(f"IcpParams.normal_k must be >= 3, got {self.normal_k!r}")
        if not self.sigma_point_m > 0.0 or self.sigma_bearing_rad < 0.0:
            raise InputError(
                "IcpParams needs sigma_point_m > 0 and sigma_bearing_rad >= 0, "
                f"got {self.sigma_point_m!r}, {self.sigma_bearing_rad!r}"
            )
        if not self.reassociate_m >= 0.0:
            raise InputError(f"IcpParams.reassociate_m must be >= 0, got {self.reassociate_m!r}")
        if not 0.0 <= self.min_normal_quality < 1.0:
            raise InputError(f"IcpParams.min_normal_quality must be in [0, 1), got {self.min_normal_quality!r}")
        core = np.array(
            [
                self.max_iterations,
                self.min_correspondence_m,
                self.shrink,
                self.convergence_translation_m,
                self.convergence_rotation_rad,
                self.fitness_distance_m,
                self.chamfer_cap_m,
                self.min_normal_quality,
                self.sigma_point_m**2,
                self.sigma_bearing_rad**2,
                self.reassociate_m,
            ],
            dtype=np.float64,
        )
        core.setflags(write=False)
        # what the compiled core of align reads (_P_* indices): a plain attribute, not a dataclass field, so that
        # fields(), asdict() and the config's to_dict/from_dict see the parameters only
        object.__setattr__(self, "_core", core)


@njit(cache=True)
def _pack_target(
    pts: np.ndarray, normals: np.ndarray, quality: np.ndarray, ranges: np.ndarray, cell_m: float, max_cells: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:class:`PreparedScan`'s derived arrays in one compiled pass: ``n_ext``, ``c_ext``, ``range2_ext`` (with
    the zero row M), ``packed`` in the grid's cell order, and the grid (``order``, ``start``, ``geo``)."""
    m = pts.shape[0]
    n_ext = np.zeros((m + 1, 2))
    c_ext = np.zeros(m + 1)
    r2 = np.zeros(m + 1)
    for i in range(m):
        n_ext[i, 0] = normals[i, 0]
        n_ext[i, 1] = normals[i, 1]
        c_ext[i] = normals[i, 0] * pts[i, 0] + normals[i, 1] * pts[i, 1]
        r2[i] = ranges[i] ** 2
    order, start, geo = build_grid(pts[:, 0].copy(), pts[:, 1].copy(), cell_m, max_cells)
    packed = np.empty((m, 7))
    for k in range(m):
        i = order[k]
        packed[k, 0], packed[k, 1] = pts[i, 0], pts[i, 1]
        packed[k, 2], packed[k, 3] = normals[i, 0], normals[i, 1]
        packed[k, 4], packed[k, 5], packed[k, 6] = c_ext[i], r2[i], quality[i]
    return n_ext, c_ext, r2, packed, order, start, geo


@njit(cache=True)
def _prepare_core(
    pts: np.ndarray, normals: np.ndarray, quality: np.ndarray, cell_m: float, max_cells: int
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """:func:`prepare_target`'s work after the normals in one compiled call: the ranges and :func:`_pack_target`'s
    derived arrays and grid."""
    m = pts.shape[0]
    ranges = np.empty(m)
    for i in range(m):
        ranges[i] = math.hypot(pts[i, 0], pts[i, 1])
    n_ext, c_ext, r2, packed, order, start, geo = _pack_target(pts, normals, quality, ranges, cell_m, max_cells)
    return ranges, n_ext, c_ext, r2, packed, order, start, geo


@dataclass(frozen=True, eq=False)
class PreparedScan:
    """A target scan ready for ICP: points (M×2 m), unit line normals (M×2), their quality (M,), a KD-tree
    (:class:`~factorloc.registration.nn.KdTree2D`, which serves the normals; :func:`align` searches a grid) and the
    points' ranges (M,, m).

    The per-target terms of the residual are precomputed once (``n_ext``:
    the normals, ``c_ext``: ``nⱼ·pⱼ``, ``range2_ext``: squared ranges), each
    with one extra row at index M — the index a bounded KD-tree query returns
    for "no neighbour within the gate". The compiled core of :func:`align`
    reads ``packed`` (M, 7) ``[p_x, p_y, n_x, n_y, c, ρ², quality]`` in the cell
    order of the uniform grid ``grid_start``/``grid_geo``
    (:func:`~factorloc.registration.nn.build_grid`; ``grid_order`` maps a
    packed row to its point index), so that a search reads contiguous rows.
    """

    points_m: np.ndarray
    normals: np.ndarray
    quality: np.ndarray
    tree: KdTree2D
    ranges_m: np.ndarray
    n_ext: np.ndarray = field(init=False, repr=False)
    c_ext: np.ndarray = field(init=False, repr=False)
    range2_ext: np.ndarray = field(init=False, repr=False)
    packed: np.ndarray = field(init=False, repr=False)
    grid_order: np.ndarray = field(init=False, repr=False)
    grid_start: np.ndarray = field(init=False, repr=False)
    grid_geo: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        pts = np.ascontiguousarray(self.points_m, dtype=np.float64)
        m = len(pts) if pts.ndim == 2 else 0
        shapes = {"points_m": (m, 2), "normals": (m, 2), "quality": (m,), "ranges_m": (m,)}
        for name, shape in shapes.items():
            got = np.shape(getattr(self, name))
            if got != shape or m == 0:
                raise InputError(f"PreparedScan.{name} must have shape {shape} with M >= 1, got {got}")
        if not np.isfinite(pts).all():
            raise InputError("PreparedScan.points_m contains NaN or infinite values")
        n_ext, c_ext, r2, packed, order, start, geo = _pack_target(
            pts,
            np.ascontiguousarray(self.normals, dtype=np.float64),
            np.ascontiguousarray(self.quality, dtype=np.float64),
            np.ascontiguousarray(self.ranges_m, dtype=np.float64),
            GRID_CELL_M,
            GRID_MAX_CELLS,
        )
        for name, a in (
            ("n_ext", n_ext),
            ("c_ext", c_ext),
            ("range2_ext", r2),
            ("packed", packed),
            ("grid_order", order),
            ("grid_start", start),
            ("grid_geo", geo),
        ):
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    def __len__(self) -> int:
        return int(self.points_m.shape[0])

    def usable(self, min_normal_quality: float) -> np.ndarray:
        """(M+1,) bool: target points whose normal quality reaches the threshold; False at the no-neighbour index M."""
        ok = np.zeros(len(self.points_m) + 1, dtype=bool)
        ok[:-1] = self.quality >= min_normal_quality
        return ok


def prepare_target(points_m: np.ndarray, params: IcpParams = IcpParams()) -> PreparedScan:
    """Build the KD-tree, PCA line normals and search grid of a target scan (once per reference): one batched
    k-nearest-neighbour search of the tree, the compiled PCA (:func:`~factorloc.registration.scan2d.pca_normals`),
    then one compiled pass for the rest (:func:`_prepare_core`).

    Raises :class:`~factorloc.errors.InputError` on fewer than 3 points, non-finite points or coordinates
    beyond :data:`MAX_COORDINATE_M`.
    """
    pts = np.ascontiguousarray(np.asarray(points_m, dtype=np.float64))
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise InputError(f"target points_m must be N×2, got shape {pts.shape}")
    if len(pts) < 3:
        raise InputError(f"target scan needs >= 3 points, got {len(pts)}")
    check_coordinates("target points_m", pts)
    if pts is points_m and pts.flags.writeable:
        pts = pts.copy()  # the caller's array stays writable; ours is frozen
    tree = KdTree2D(pts)
    m = len(pts)
    kk = min(params.normal_k, m)
    d, idx = tree.nearest_lifted(tree.lifted, kk)
    normals, quality = pca_normals(pts, d.reshape(m, kk), idx.reshape(m, kk), float(params.normal_radius_m))
    out = (normals, quality) + _prepare_core(pts, normals, quality, GRID_CELL_M, GRID_MAX_CELLS)
    for a in (pts,) + out:
        a.setflags(write=False)
    normals, quality, ranges = out[:3]
    # the PreparedScan without its constructor's checks and packing: every array was made above from the checked points
    target = object.__new__(PreparedScan)
    for name, a in zip(
        (
            "points_m",
            "normals",
            "quality",
            "tree",
            "ranges_m",
            "n_ext",
            "c_ext",
            "range2_ext",
            "packed",
            "grid_order",
            "grid_start",
            "grid_geo",
        ),
        (pts, normals, quality, tree, ranges) + out[3:],
        strict=True,
    ):
        object.__setattr__(target, name, a)
    return target


# MAX_COORDINATE_M (from factorloc._validate, 1e9 m): the largest absolute point coordinate :func:`align` and
# :func:`prepare_target` accept — far beyond any scan, and small enough that squared ranges never overflow.


def check_coordinates(name: str, pts: np.ndarray) -> None:
    """InputError unless every coordinate is finite and within ±MAX_COORDINATE_M (one reduction)."""
    top = float(np.abs(pts).max())  # NaN propagates
    if not top <= MAX_COORDINATE_M:
        if not np.isfinite(pts).all():
            raise InputError(f"{name} contains NaN or infinite values")
        raise InputError(f"{name} has a coordinate of {top!r} m, beyond ±{MAX_COORDINATE_M:g} m")

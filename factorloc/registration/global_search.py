"""Global initialization: a two-level correlative scan matcher (Olson, "Real-time
correlative scan matching", ICRA 2009).

The reference scan is turned into likelihood fields ``F(c) = exp(−d(c)²/2σ²)``
(``d`` = distance from cell ``c`` to the nearest reference point, by a
Euclidean distance transform) at a coarse and a fine resolution. Every pose
``(t, θ)`` of a grid — translations within ``radius_m`` of a centre, headings
over the full circle (or a window) — is scored by the mean field value under
the rotated and translated query points. Because translations lie on the
field's own lattice, the cell of ``R_θ q + t`` is the cell of ``R_θ q`` plus
an integer offset, so all translations of one heading are scored by one
fancy-indexing gather (no interpolation, exact to the cell).

Level 1 scores the whole window coarsely; its best poses after non-maximum
suppression are re-scored on the fine field in a small neighbourhood. The
caller refines the survivors with ICP and judges ambiguity
(:mod:`factorloc.estimators.icp`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import ndimage

from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.registration.scan2d import voxel_downsample_2d

__all__ = [
    "Candidate",
    "GlobalSearchParams",
    "LikelihoodField",
    "build_field",
    "reference_fields",
    "score_lattice",
    "score_lattice_gather",
    "search",
]


@dataclass(frozen=True)
class GlobalSearchParams:
    """Parameters of the correlative search (metres, radians).

    Parameters
    ----------
    radius_m
        Half-width of the square translation window around the centre.
    max_range_m
        Query and reference points farther than this from their sensor are
        ignored by the search (long returns are sparse and noisy).
    coarse_resolution_m, coarse_sigma_m, coarse_angle_step_rad
        Level 1 lattice and field blur.
    fine_resolution_m, fine_sigma_m, fine_angle_step_rad
        Level 2 lattice and field blur; level 2 searches ± one coarse cell and
        ± one coarse angle step around each level-1 survivor.
    n_candidates
        How many poses the search returns (the best level-2 scores).
    n_coarse
        How many level-1 maxima survive non-maximum suppression and are
        re-scored on the fine level. Larger than ``n_candidates``: the coarse
        score ranks a partially overlapping true pose poorly, the fine score
        well (figures: ``docs/calibration/icp.md``).
    separation_m, separation_rad
        Two maxima closer than both are the same (suppression radius).
    """

    radius_m: float = 5.0
    max_range_m: float = 15.0
    coarse_resolution_m: float = 0.3
    coarse_sigma_m: float = 0.3
    coarse_angle_step_rad: float = math.radians(3.0)
    fine_resolution_m: float = 0.05
    fine_sigma_m: float = 0.08
    fine_angle_step_rad: float = math.radians(0.5)
    n_candidates: int = 10
    n_coarse: int = 120
    separation_m: float = 0.6
    separation_rad: float = math.radians(10.0)

    def __post_init__(self) -> None:
        for name in (
            "radius_m",
            "max_range_m",
            "coarse_resolution_m",
            "coarse_sigma_m",
            "coarse_angle_step_rad",
            "fine_resolution_m",
            "fine_sigma_m",
            "fine_angle_step_rad",
            "separation_m",
            "separation_rad",
        ):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"GlobalSearchParams.{name} must be > 0, got {v!r}")
        if self.n_candidates < 1:
            raise InputError(f"GlobalSearchParams.n_candidates must be >= 1, got {self.n_candidates!r}")
        if self.n_coarse < self.n_candidates:
            raise InputError(f"GlobalSearchParams.n_coarse must be >= n_candidates ({self.n_candidates}), got {self.n_coarse!r}")


@dataclass(frozen=True, eq=False)
class LikelihoodField:
    """A likelihood field on a square lattice: ``values[ix, iy]`` at ``origin_m + resolution_m·(ix, iy)`` (cell corner)."""

    values: np.ndarray
    origin_m: np.ndarray
    resolution_m: float


@dataclass(frozen=True)
class Candidate:
    """A pose of the query in the reference frame and its score (mean field value in [0, 1])."""

    T_reference_query: Pose2
    score: float


#: The most cells a likelihood field may have (about 20 bytes each while it is built: 320 MB), e.g. 200 m × 200 m
#: at the fine 5 cm; the search's own reference is cut to ``max_range_m + radius_m`` around its pose first.
MAX_FIELD_CELLS = 16_000_000


def build_field(points_m: np.ndarray, resolution_m: float, sigma_m: float, margin_m: float) -> LikelihoodField:
    """The likelihood field of reference points (N×2 m) with ``margin_m`` of zero-padded border.

    ``F = exp(−d²/2σ²)`` with ``d`` the Euclidean distance transform of the occupancy grid.
    """
    pts = np.asarray(points_m, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) == 0:
        raise InputError(f"build_field needs N×2 points with N >= 1, got shape {pts.shape}")
    lo = pts.min(axis=0) - margin_m
    hi = pts.max(axis=0) + margin_m
    cells = np.ceil((hi - lo) / resolution_m) + 1.0  # float: an absurd extent must not overflow an int first
    if not float(cells[0] * cells[1]) <= MAX_FIELD_CELLS:
        raise InputError(
            f"the reference points span {hi[0] - lo[0]:.3g} m × {hi[1] - lo[1]:.3g} m: a likelihood field at "
            f"{resolution_m:g} m would need {float(cells[0] * cells[1]):.3g} cells, more than {MAX_FIELD_CELLS:g}"
        )
    shape = (int(cells[0]), int(cells[1]))
    occ = np.ones(shape, dtype=bool)
    idx = np.floor((pts - lo) / resolution_m).astype(np.int64)
    occ[idx[:, 0], idx[:, 1]] = False
    d_cells = ndimage.distance_transform_edt(occ)
    # distance from a cell to the nearest occupied cell, in metres
    d = d_cells * resolution_m
    values = np.exp(-0.5 * (d / sigma_m) ** 2).astype(np.float32)
    values.setflags(write=False)
    return LikelihoodField(values, lo, float(resolution_m))


def _lattice_cells(
    field: LikelihoodField, query_m: np.ndarray, thetas: np.ndarray, t_lo: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(A, N) field cells of the rotated query points at translation offset (0, 0): ``floor((R_θ q + t_lo − origin)/res)``."""
    thetas = np.asarray(thetas, dtype=np.float64)
    c, s = np.cos(thetas), np.sin(thetas)
    t_lo = np.asarray(t_lo, dtype=np.float64)
    if t_lo.ndim == 1:
        tx, ty = np.full(len(thetas), t_lo[0]), np.full(len(thetas), t_lo[1])
    else:
        tx, ty = np.ascontiguousarray(t_lo[:, 0]), np.ascontiguousarray(t_lo[:, 1])
    q = np.asarray(query_m, dtype=np.float64)
    return _cells(
        np.ascontiguousarray(q[:, 0]),
        np.ascontiguousarray(q[:, 1]),
        c,
        s,
        tx,
        ty,
        float(field.origin_m[0]),
        float(field.origin_m[1]),
        float(field.resolution_m),
    )


@njit(cache=True)
def _cells(  # noqa: PLR0913
    qx: np.ndarray, qy: np.ndarray, c: np.ndarray, s: np.ndarray, tx: np.ndarray, ty: np.ndarray, ox: float, oy: float, res: float
) -> tuple[np.ndarray, np.ndarray]:
    """The kernel of :func:`_lattice_cells`: the same float64 operations in the same order as the numpy expression
    ``floor(((c·qx − s·qy) + tx − ox)/res + 1e-9)`` (and its y twin) it replaced, one (heading, point) at a time,
    without its (A, N) temporaries (no fused multiply-add: numba contracts none without ``fastmath``)."""
    n_a, n = len(c), len(qx)
    bx = np.empty((n_a, n), dtype=np.int64)
    by = np.empty((n_a, n), dtype=np.int64)
    for a in range(n_a):
        ca, sa, txa, tya = c[a], s[a], tx[a], ty[a]
        for k in range(n):
            rx = ca * qx[k] - sa * qy[k]
            ry = sa * qx[k] + ca * qy[k]
            bx[a, k] = np.int64(math.floor((rx + txa - ox) / res + 1e-9))
            by[a, k] = np.int64(math.floor((ry + tya - oy) / res + 1e-9))
    return bx, by


def score_lattice(
    field: LikelihoodField,
    query_m: np.ndarray,
    thetas: np.ndarray,
    t_lo: np.ndarray,
    n_steps: tuple[int, int],
    stride: int = 1,
) -> np.ndarray:
    """Scores (A, Kx, Ky) of poses ``(t_lo + res·(kx, ky), θ_a)``: mean field value under the query points.

    ``t_lo`` is one corner (2,) for every heading, or one per heading (A, 2).

    With ``stride`` s > 1 only every s-th translation is scored: (A, ⌈Kx/s⌉, ⌈Ky/s⌉) at ``kx, ky ∈ {0, s, 2s, …}``.

    For a query point in cell ``(bx, by)`` at translation offset ``(0, 0)``, the values at all offsets are the
    field's ``Kx × Ky`` window starting at that cell; cells outside the field count as 0. The compiled kernel
    adds each point's window into the heading's score plane (float32, points in order, then divided by N): the
    same sums, in the same order, as the gather of :func:`score_lattice_gather`, without the (A, N, Kx, Ky)
    array it builds (``benchmarks/bench_global_search.py`` times both on the laser logs).
    """
    bx, by = _lattice_cells(field, query_m, thetas, t_lo)
    kx, ky = n_steps
    return _window_means(field.values, bx, by, int(kx), int(ky), int(stride))


@njit(cache=True)
def _window_means(F: np.ndarray, bx: np.ndarray, by: np.ndarray, kx: int, ky: int, stride: int) -> np.ndarray:  # noqa: PLR0913
    """``out[a, i, j] = Σ_n F[bx[a,n] + i·s, by[a,n] + j·s] / N`` (float32, cells outside F count as 0).

    F is copied into a border of zeros one window wide, so that every window of a point that touches the field
    lies inside the copy, with its columns split by phase modulo the stride: every inner loop runs over
    contiguous cells of fixed length (it vectorizes); a point whose window misses the field adds nothing."""
    n_a, n = bx.shape
    h, w = F.shape
    nx = (kx + stride - 1) // stride
    ny = (ky + stride - 1) // stride
    # F in a border of zeros one window wide, the columns of each phase modulo the stride side by side:
    # ``phases[r, x, k]`` is the bordered field at row x, column r + k·s, so a window's strided columns are contiguous
    wp = (w + 2 * ky + stride - 1) // stride
    phases = np.zeros((stride, h + 2 * kx, wp), dtype=np.float32)
    for r in range(stride):
        for x in range(h):
            for k in range(wp):
                col = r + k * stride - ky
                if 0 <= col < w:
                    phases[r, x + kx, k] = F[x, col]
    out = np.zeros((n_a, nx, ny), dtype=np.float32)
    for a in range(n_a):
        for p in range(n):
            x0, y0 = bx[a, p] + kx, by[a, p] + ky
            if x0 <= 0 or x0 >= h + kx or y0 <= 0 or y0 >= w + ky:
                continue
            plane_of = phases[y0 % stride]
            k0 = y0 // stride
            for i in range(nx):
                row = plane_of[x0 + i * stride]
                acc = out[a, i]
                for j in range(ny):
                    acc[j] += row[k0 + j]
    count = np.float32(n)
    for a in range(n_a):
        for i in range(nx):
            for j in range(ny):
                out[a, i, j] = out[a, i, j] / count
    return out


def score_lattice_gather(
    field: LikelihoodField,
    query_m: np.ndarray,
    thetas: np.ndarray,
    t_lo: np.ndarray,
    n_steps: tuple[int, int],
    stride: int = 1,
) -> np.ndarray:
    """:func:`score_lattice` by one numpy gather of windows (a strided view of the zero-padded field): the
    reference the compiled kernel is tested and timed against."""
    F = field.values
    bx, by = _lattice_cells(field, query_m, thetas, t_lo)
    kx, ky = n_steps
    # a point whose whole window lies outside the field scores 0 at every offset: it reads an all-zero window
    # of the border, so that the padding stays within one window of the field whatever the coordinates
    # (a seed 10⁹ m away once asked for a 608 GiB pad)
    outside = (bx + kx <= 0) | (bx >= F.shape[0]) | (by + ky <= 0) | (by >= F.shape[1])
    if outside.any():
        bx = np.where(outside, -kx, bx)
        by = np.where(outside, -ky, by)
    px0, px1 = max(0, -int(bx.min())), max(0, int(bx.max()) + kx - F.shape[0])
    py0, py1 = max(0, -int(by.min())), max(0, int(by.max()) + ky - F.shape[1])
    if px0 or px1 or py0 or py1:
        F = np.pad(F, ((px0, px1), (py0, py1)))
    windows = np.lib.stride_tricks.sliding_window_view(F, (kx, ky))
    if stride > 1:
        windows = windows[:, :, ::stride, ::stride]
    return windows[bx + px0, by + py0].mean(axis=1)


#: Relative tolerance of the suppression radius: two maxima exactly ``separation_m`` apart (lattice offsets often
#: are, e.g. two coarse cells) are distinct whatever the rounding of their coordinates.
SEPARATION_RTOL = 1e-9


@njit(cache=True)
def _suppress(  # noqa: PLR0913
    a: np.ndarray,
    kx: np.ndarray,
    ky: np.ndarray,
    thetas: np.ndarray,
    resolution_m: float,
    separation_m: float,
    separation_rad: float,
    n_max: int,
) -> np.ndarray:
    """Greedy non-maximum suppression of lattice maxima given best first (heading index, cell offsets): the
    indices of the first ``n_max`` that lie no closer than ``separation_m`` in position *or* ``separation_rad``
    in heading to every one kept before them (distances in lattice offsets, compared with
    :data:`SEPARATION_RTOL`)."""
    limit_m2 = (separation_m * (1.0 - SEPARATION_RTOL)) ** 2
    limit_rad = separation_rad * (1.0 - SEPARATION_RTOL)
    two_pi = 2.0 * math.pi
    kept = np.empty(min(n_max, len(a)), dtype=np.int64)
    n_kept = 0
    for k in range(len(a)):
        if n_kept >= n_max:
            break
        same = False
        for m in range(n_kept):
            q = kept[m]
            dx = float(kx[k] - kx[q]) * resolution_m
            dy = float(ky[k] - ky[q]) * resolution_m
            if dx * dx + dy * dy >= limit_m2:
                continue
            d = abs(thetas[a[k]] - thetas[a[q]]) % two_pi
            if min(d, two_pi - d) < limit_rad:
                same = True
                break
        if not same:
            kept[n_kept] = k
            n_kept += 1
    return kept[:n_kept]


@njit(cache=True)
def _window_index(n: int, size: int, wrap: bool) -> np.ndarray:
    """(n, size) source index of each window cell along an axis of length n: offsets ``−(size // 2)`` …
    ``size − 1 − size // 2`` as ``scipy.ndimage.maximum_filter`` places them, beyond the ends the edge cell
    repeated (scipy's ``"nearest"``) or the axis wrapped (``"wrap"``)."""
    lo = -(size // 2)
    idx = np.empty((n, size), dtype=np.int64)
    for p in range(n):
        for o in range(size):
            m = p + lo + o
            if wrap:
                m %= n
            else:
                m = min(max(m, 0), n - 1)
            idx[p, o] = m
    return idx


@njit(cache=True)
def _max_along_rows(src: np.ndarray, size: int, out: np.ndarray) -> None:
    """``out[r, k]`` = the maximum of row ``r`` of the 2-D ``src`` over the window of :func:`_window_index` at
    ``k`` (not wrapped): each row padded with its edge cells, then ``size`` shifted maxima of the padded row."""
    n = src.shape[1]
    lo = -(size // 2)
    padded = np.empty(n + size - 1, dtype=src.dtype)
    for r in range(src.shape[0]):
        row, dst = src[r], out[r]
        for m in range(n + size - 1):
            padded[m] = row[min(max(m + lo, 0), n - 1)]
        for k in range(n):
            dst[k] = padded[k]
        for o in range(1, size):
            for k in range(n):
                dst[k] = max(dst[k], padded[k + o])


@njit(cache=True)
def _max_of_rows(src: np.ndarray, index: np.ndarray, out: np.ndarray) -> None:
    """``out[r]`` = the elementwise maximum of the rows ``src[index[r, o]]`` of the 2-D ``src``, over ``o``."""
    for r in range(out.shape[0]):
        dst = out[r]
        first = src[index[r, 0]]
        for k in range(dst.size):
            dst[k] = first[k]
        for o in range(1, index.shape[1]):
            row = src[index[r, o]]
            for k in range(dst.size):
                dst[k] = max(dst[k], row[k])


@njit(cache=True)
def _peaks(scores: np.ndarray, size_heading: int, size_cells: int, wrap: bool) -> np.ndarray:
    """Flat indices (ascending) of the positive local maxima of a (heading, x, y) score volume: the cells that
    equal the maximum of their ``size_heading × size_cells × size_cells`` window (placed, the heading axis wrapped
    when ``wrap`` and the cell axes clamped at the edges, as :func:`_window_index` says). The same cells as
    ``scores >= maximum_filter(scores, size, mode=(wrap|nearest, nearest, nearest)) & (scores > 0)``
    (comparisons only: no rounding to differ), by a running maximum along each axis in turn, every inner loop
    over contiguous cells."""
    n_a, n_x, n_y = scores.shape
    along_y = np.empty_like(scores)
    _max_along_rows(scores.reshape(n_a * n_x, n_y), size_cells, along_y.reshape(n_a * n_x, n_y))
    along_x = np.empty_like(scores)
    index_x = _window_index(n_x, size_cells, False)
    for i in range(n_a):
        _max_of_rows(along_y[i], index_x, along_x[i])
    window = along_y.reshape(n_a, n_x * n_y)  # reused
    _max_of_rows(along_x.reshape(n_a, n_x * n_y), _window_index(n_a, size_heading, wrap), window)
    flat_s, flat_m = scores.ravel(), window.ravel()
    found = np.empty(flat_s.size, dtype=np.int64)
    n = 0
    for k in range(flat_s.size):
        if flat_s[k] >= flat_m[k] and flat_s[k] > 0.0:
            found[n] = k
            n += 1
    return found[:n]


def _angle_grid(center: float, half_width: float, step: float) -> np.ndarray:
    if half_width >= math.pi:
        n = int(math.ceil(2.0 * math.pi / step))
        return center + np.arange(n) * (2.0 * math.pi / n)
    n = int(math.ceil(half_width / step))
    return center + np.arange(-n, n + 1) * step


def search(
    reference_m: np.ndarray,
    query_m: np.ndarray,
    params: GlobalSearchParams = GlobalSearchParams(),
    *,
    center_m: tuple[float, float] = (0.0, 0.0),
    heading_rad: float = 0.0,
    heading_half_width_rad: float = math.pi,
    fields: tuple[LikelihoodField, LikelihoodField] | None = None,
) -> list[Candidate]:
    """Candidate poses of the query scan in the reference frame, best first.

    Parameters
    ----------
    reference_m, query_m
        M×2 and N×2 points (metres), each in its own robot frame.
    params
        The search's lattice, windows and scoring (:class:`GlobalSearchParams`).
    center_m
        Centre of the translation window ``center ± params.radius_m`` (reference frame, m).
    heading_rad, heading_half_width_rad
        The heading window; the default searches the full circle.
    fields
        Precomputed (coarse, fine) fields of the reference (see :func:`reference_fields`).

    Returns
    -------
    list of Candidate
        Up to ``params.n_candidates`` distinct poses, sorted by fine score.
    """
    ref = np.asarray(reference_m, dtype=np.float64)
    qry = np.asarray(query_m, dtype=np.float64)
    if qry.ndim != 2 or qry.shape[1] != 2 or len(qry) < 3:
        raise InputError(f"query_m must be N×2 with N >= 3, got shape {qry.shape}")
    qry = qry[np.hypot(qry[:, 0], qry[:, 1]) <= params.max_range_m]
    if len(qry) < 3:
        raise InputError(f"query scan has {len(qry)} point(s) within {params.max_range_m} m; need >= 3")
    coarse, fine = reference_fields(ref, params) if fields is None else fields
    p = params
    center = np.asarray(center_m, dtype=np.float64)

    # level 1: coarse lattice over the whole window
    q1 = voxel_downsample_2d(qry, 0.5 * p.coarse_resolution_m)
    r1 = p.coarse_resolution_m
    n1 = int(math.ceil(p.radius_m / r1))
    t_lo = center - n1 * r1
    thetas = _angle_grid(heading_rad, heading_half_width_rad, p.coarse_angle_step_rad)
    scores = score_lattice(coarse, q1, thetas, t_lo, (2 * n1 + 1, 2 * n1 + 1))
    # local maxima of the score volume (heading × x × y) within the suppression radius, then a greedy
    # non-maximum suppression among them, best first: sorting only the peaks, not every pose
    sep_a = max(1, int(p.separation_rad // p.coarse_angle_step_rad))
    sep_t = max(1, int(p.separation_m // r1))
    size = (min(2 * sep_a + 1, len(thetas)), 2 * sep_t + 1, 2 * sep_t + 1)
    idx = _peaks(scores, size[0], size[1], heading_half_width_rad >= math.pi)
    idx = idx[np.argsort(scores.ravel()[idx], kind="stable")[::-1]]
    a1, kx1, ky1 = np.unravel_index(idx, scores.shape)
    keep = _suppress(a1, kx1, ky1, thetas, r1, p.separation_m, p.separation_rad, p.n_coarse)
    # the survivors (x_m, y_m, θ_rad), best first
    xyt = np.column_stack([t_lo[0] + kx1[keep] * r1, t_lo[1] + ky1[keep] * r1, thetas[a1[keep]]])

    # level 2: fine lattice around each survivor
    q2 = voxel_downsample_2d(qry, 0.5 * p.fine_resolution_m)
    r2 = p.fine_resolution_m
    n2 = int(math.ceil(r1 / r2))
    # 2a: every other fine cell and fine angle step over ± one coarse cell and step; 2b: the full fine lattice
    # within one (doubled) step of 2a's best — a quarter of the work of the full lattice, the same maxima. Every
    # survivor's headings are scored in one call (one corner per heading row)
    m = len(xyt)
    out: list[Candidate] = []
    if m:
        offs = _angle_grid(0.0, p.coarse_angle_step_rad, 2.0 * p.fine_angle_step_rad)
        th2 = (xyt[:, 2:3] + offs[None, :]).ravel()
        lo = np.repeat(xyt[:, :2] - n2 * r2, len(offs), axis=0)
        sc = score_lattice(fine, q2, th2, lo, (2 * n2 + 1, 2 * n2 + 1), stride=2).reshape(m, len(offs), -1)
        flat = sc.reshape(m, -1).argmax(axis=1)
        a, k = np.unravel_index(flat, sc.shape[1:])
        kx, ky = np.unravel_index(k, (n2 + 1, n2 + 1))
        best_th = xyt[:, 2] + offs[a]
        best_lo = xyt[:, :2] - n2 * r2 + 2 * r2 * np.stack([kx, ky], axis=1)
        offs3 = _angle_grid(0.0, p.fine_angle_step_rad, p.fine_angle_step_rad)
        th3 = (best_th[:, None] + offs3[None, :]).ravel()
        lo3 = np.repeat(best_lo - r2, len(offs3), axis=0)
        sc3 = score_lattice(fine, q2, th3, lo3, (3, 3)).reshape(m, -1)
        flat3 = sc3.argmax(axis=1)
        a3, k3 = np.unravel_index(flat3, (len(offs3), 9))
        kx3, ky3 = np.unravel_index(k3, (3, 3))
        best = sc3[np.arange(m), flat3]
        # best first, ties in survivor order (a stable sort), and Pose2s only for the ones returned
        for i in np.argsort(-best, kind="stable")[: p.n_candidates]:
            pose = Pose2(
                float(best_lo[i, 0] - r2 + kx3[i] * r2), float(best_lo[i, 1] - r2 + ky3[i] * r2), float(best_th[i] + offs3[a3[i]])
            )
            out.append(Candidate(pose, float(best[i])))
    return out


def reference_fields(
    reference_m: np.ndarray, params: GlobalSearchParams = GlobalSearchParams()
) -> tuple[LikelihoodField, LikelihoodField]:
    """The (coarse, fine) likelihood fields of a reference scan, points beyond ``max_range_m + radius_m`` dropped."""
    ref = np.asarray(reference_m, dtype=np.float64)
    if ref.ndim != 2 or ref.shape[1] != 2 or len(ref) < 3:
        raise InputError(f"reference_m must be N×2 with N >= 3, got shape {ref.shape}")
    reach = params.max_range_m + params.radius_m
    keep = np.hypot(ref[:, 0], ref[:, 1]) <= reach
    if not keep.any():
        raise InputError(f"no reference point lies within {reach:g} m of the reference pose: nothing to search against")
    ref = ref[keep]
    coarse = build_field(ref, params.coarse_resolution_m, params.coarse_sigma_m, 3.0 * params.coarse_sigma_m)
    fine = build_field(
        voxel_downsample_2d(ref, 0.5 * params.fine_resolution_m),
        params.fine_resolution_m,
        params.fine_sigma_m,
        3.0 * params.fine_sigma_m,
    )
    return coarse, fine

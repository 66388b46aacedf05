"""Nearest-neighbour search on 2D points, the innermost cost of ICP.

:class:`KdTree2D` answers ``query(points, k, distance_upper_bound)`` with
the semantics of :meth:`scipy.spatial.cKDTree.query` (distances ``inf`` and
index ``M`` where no neighbour lies closer than the bound). When the
``small_gicp`` package is importable its C++ KD-tree is used (points lifted
to z = :data:`LIFT_Z`): on 180-point laser scans a batched nearest-neighbour query takes
~12 µs against ~45–65 µs for ``cKDTree.query`` (``workers=1``), and a tree
builds in ~7 µs against ~25–33 µs — the call overhead, not the search,
dominates at these sizes. :meth:`KdTree2D.nearest_lifted` is the inner
loop's form: already-lifted queries, no bound, no copies (``batch_knn_search``
returns arrays; ``batch_nearest_neighbor_search`` returns Python lists whose
conversion cost as much as the search). Otherwise ``cKDTree`` is used; both
are exact, so the results are the same (up to ties between equidistant neighbours).
The tree serves the target's normals (:func:`~factorloc.registration.scan2d.estimate_normals_2d`),
built on its first query. (Those figures hold when the same scan is queried
again and again; with a new scan per call, a reference per relation, a tree and
its k = 7 query cost ~70–85 µs on this machine. A compiled search of the grid
below is ~25 µs cheaper there, but laser scans have many equidistant
neighbours, ~28 points per scan, whose order the tree picks: the normals'
sums then differ in the last bit, and Open3D's diverging runs on the loop
relations, fed these normals, change. So the tree stays.)

The compiled ICP core (:func:`factorloc.registration.icp2d.align`) searches a
uniform grid instead (:func:`build_grid`, :func:`grid_nearest`,
:func:`grid_nearest2`, numba): from inside compiled code a search costs
~40 ns per query (no call overhead at all), exact like the tree, bounded by a
radius (the ICP gate), and :func:`grid_nearest2` also returns the distance of
the second-nearest point, with which ICP keeps a neighbour without searching
while the points move less than half the gap.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from scipy.spatial import cKDTree

from factorloc.errors import InputError

try:  # optional accelerator, exact like cKDTree
    import small_gicp as _small_gicp
except ImportError:  # pragma: no cover - depends on the environment
    _small_gicp = None

__all__ = [
    "GRID_CELL_M",
    "GRID_MAX_CELLS",
    "LIFT_Z",
    "KdTree2D",
    "build_grid",
    "fast_backend",
    "grid_nearest",
    "lift_2d",
]


def fast_backend() -> bool:
    """Whether :class:`KdTree2D` uses small_gicp's KD-tree (else scipy's cKDTree)."""
    return _small_gicp is not None


LIFT_Z = 1.0
"""The z of the points lifted to 3D for small_gicp (the same for the tree and its queries, so distances are 2D).

1 rather than 0: ICP's residuals are then one row product ``[n_x, n_y, −n·p]·[q_x, q_y, 1]`` of the
lifted (homogeneous) query points it already holds for the search (:func:`factorloc.registration.icp2d.align`)."""


def lift_2d(points_m: np.ndarray) -> np.ndarray:
    """N×2 points lifted to the N×3 C-contiguous float64 ``[x, y, LIFT_Z]`` that :meth:`KdTree2D.nearest_lifted` takes."""
    out = np.empty((len(points_m), 3))
    out[:, :2] = points_m
    out[:, 2] = LIFT_Z
    return out


class KdTree2D:
    """Exact nearest neighbours among M 2D points (metres).

    Parameters
    ----------
    points_m
        M×2 points, M ≥ 1.
    backend
        ``"auto"`` (small_gicp when installed), ``"small_gicp"`` or ``"scipy"``.

    The backend's tree is built on the first query (the points are validated at construction).
    """

    def __init__(self, points_m: np.ndarray, backend: str = "auto") -> None:
        pts = np.ascontiguousarray(np.asarray(points_m, dtype=np.float64))
        if pts.ndim != 2 or pts.shape[1] != 2 or len(pts) == 0:
            raise InputError(f"KdTree2D needs M×2 points with M >= 1, got shape {pts.shape}")
        if backend not in ("auto", "small_gicp", "scipy"):
            raise InputError(f"KdTree2D backend must be 'auto', 'small_gicp' or 'scipy', got {backend!r}")
        if backend == "small_gicp" and _small_gicp is None:
            raise InputError("KdTree2D backend 'small_gicp' requested but the small_gicp package is not installed")
        self.n = len(pts)
        self._pts = pts
        self._lifted: np.ndarray | None = None
        self._scipy = backend == "scipy" or _small_gicp is None
        self._sg = None
        self._ck = None

    @property
    def lifted(self) -> np.ndarray:
        """The points lifted to 3D (M×3, z = :data:`LIFT_Z`), read-only (made on first use)."""
        if self._lifted is None:
            lifted = lift_2d(self._pts)
            lifted.setflags(write=False)
            self._lifted = lifted
        return self._lifted

    def _tree(self) -> None:
        """Build the backend's tree (on the first query: :func:`factorloc.registration.icp2d.prepare_target` makes
        a tree per reference that only the numpy reference implementations in the tests query)."""
        if self._scipy:
            self._ck = cKDTree(self._pts)
        else:
            self._sg = _small_gicp.KdTree(self.lifted, num_threads=1)

    @classmethod
    def from_lifted(cls, lifted: np.ndarray) -> KdTree2D:
        """A tree on points already lifted (M×3 C-contiguous float64, third column :data:`LIFT_Z`, M ≥ 1), as
        :func:`lift_2d` makes them: no validation, no copy (the caller must not modify them)."""
        self = cls.__new__(cls)
        self.n = len(lifted)
        self._pts = np.ascontiguousarray(lifted[:, :2])
        self._lifted = lifted
        self._scipy = _small_gicp is None
        self._sg = self._ck = None
        return self

    def nearest_lifted(self, lifted: np.ndarray, k: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` (≤ M) nearest neighbours of each of N points given lifted (N×3 C-contiguous float64, third
        column :data:`LIFT_Z`): ``(d, idx)``, distances (m, never ``inf``) and int64 indices, (N,) for ``k = 1``
        else (N, k).

        The inner loop's query (no bound, no validation, no copies beyond the result): about 12 µs for 180
        points against 180 with small_gicp. Same values as :meth:`query` without a bound.
        """
        if self._sg is None and self._ck is None:
            self._tree()
        if self._ck is not None:
            return self._ck.query(lifted[:, :2], k=k, workers=1)
        idx, d2 = self._sg.batch_knn_search(lifted, k, num_threads=1)
        if k == 1:
            return np.sqrt(d2.reshape(-1)), idx.reshape(-1).view(np.int64)
        return np.sqrt(d2), idx.view(np.int64)

    def __len__(self) -> int:
        return self.n

    def query(
        self, points_m: np.ndarray, k: int = 1, distance_upper_bound: float = np.inf, workers: int = 1
    ) -> tuple[np.ndarray, np.ndarray]:
        """Distances and indices of the ``k`` nearest neighbours of each of the N points (one thread; ``workers`` is
        accepted for cKDTree compatibility and ignored).

        Returns ``(d, idx)`` shaped (N,) for ``k = 1``, else (N, k), nearest
        first; a neighbour not closer than ``distance_upper_bound`` has
        ``d = inf`` and ``idx = M`` (cKDTree's convention).
        """
        x = np.asarray(points_m, dtype=np.float64)
        if self._sg is None and self._ck is None:
            self._tree()
        if self._ck is not None:
            return self._ck.query(x, k=k, distance_upper_bound=distance_upper_bound, workers=1)
        if len(x) == 0:
            shape = (0,) if k == 1 else (0, k)
            return np.zeros(shape), np.zeros(shape, dtype=np.int64)
        kk = min(k, self.n)
        idx_u, d2 = self._sg.batch_knn_search(lift_2d(x), kk, num_threads=1)  # (N, kk) uint64, float64 arrays
        idx = idx_u.view(np.int64)
        d = np.sqrt(d2)
        if k == 1:
            idx = idx.reshape(len(x))
            d = d.reshape(len(x))
        elif kk < k:  # fewer points than asked: pad like cKDTree
            idx = np.concatenate([idx, np.full((len(x), k - kk), self.n, dtype=np.int64)], axis=1)
            d = np.concatenate([d, np.full((len(x), k - kk), np.inf)], axis=1)
        miss = ~(d < distance_upper_bound) | (idx < 0)
        if miss.any():
            d[miss] = np.inf
            idx[miss] = self.n
        return d, idx


# --------------------------------------------------------------------------------------------------------------------
# uniform grid, compiled: the nearest-neighbour search of the ICP core (factorloc.registration.icp2d)
# --------------------------------------------------------------------------------------------------------------------
GRID_CELL_M = 0.5
"""Default cell side of :func:`build_grid` (m): the largest ICP search bound (the 0.5 m Chamfer cap), so that a
search reads at most 3×3 cells, mostly 2×2 (a 180-point laser scan puts a few points in a cell along its walls).
Measured on the Intel/ACES scans (``align`` per pair): 0.2 m ~15 % slower, 0.45–0.55 m best, 0.7 m no better."""

GRID_MAX_CELLS = 1 << 18
"""Largest cell count of a grid: wider scans get larger cells (the search stays exact, only slower), so that
memory stays bounded whatever the coordinates (2 MB of cell offsets at most)."""


@njit(cache=True)
def build_grid(x: np.ndarray, y: np.ndarray, cell_m: float, max_cells: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A uniform grid over M points (``x``, ``y``: (M,) m, finite, M ≥ 1) for :func:`grid_nearest`.

    Returns ``order`` (M,) int64, the point indices sorted by cell (within a cell by index); ``start``
    (G+1,) int64, the cell ``c = ix·gy + iy`` holds ``order[start[c]:start[c+1]]``; ``geo`` (7,) float64
    ``[x0, y0, h, gx, gy, slack, 1/h]``: origin, cell side (``cell_m`` doubled until ``gx·gy ≤ max_cells``),
    cell counts, a bound on the rounding of a point's cell (m) that the search adds to its distance bounds, and
    the inverse cell side (a point's cell is ``floor((x − x0)·(1/h))``, the same product in the build and the
    search).
    """
    m = len(x)
    xmin, xmax, ymin, ymax = x[0], x[0], y[0], y[0]
    for i in range(1, m):
        xmin = min(xmin, x[i])
        xmax = max(xmax, x[i])
        ymin = min(ymin, y[i])
        ymax = max(ymax, y[i])
    sx, sy = xmax - xmin, ymax - ymin
    h = cell_m
    while (sx / h + 1.0) * (sy / h + 1.0) > max_cells:
        h *= 2.0
    gx = min(int(sx / h) + 1, max_cells)
    gy = min(int(sy / h) + 1, max_cells)
    inv_h = 1.0 / h
    cell = np.empty(m, np.int64)
    start = np.zeros(gx * gy + 1, np.int64)
    for i in range(m):
        ix = min(max(int((x[i] - xmin) * inv_h), 0), gx - 1)
        iy = min(max(int((y[i] - ymin) * inv_h), 0), gy - 1)
        c = ix * gy + iy
        cell[i] = c
        start[c + 1] += 1
    for c in range(gx * gy):
        start[c + 1] += start[c]
    fill = start[:-1].copy()
    order = np.empty(m, np.int64)
    for i in range(m):
        order[fill[cell[i]]] = i
        fill[cell[i]] += 1
    geo = np.empty(7)
    geo[0], geo[1], geo[2], geo[3], geo[4] = xmin, ymin, h, gx, gy
    geo[5] = 1e-9 * (h + abs(xmin) + abs(ymin) + sx + sy)
    geo[6] = inv_h
    return order, start, geo


@njit(cache=True, inline="always")
def _search_box(qx: float, qy: float, geo: np.ndarray, bound2: float) -> tuple[bool, int, int, int, int, int, int]:
    """The cells a search of radius ``sqrt(bound2)`` around ``(qx, qy)`` may read (:func:`build_grid`'s ``geo``).

    Returns ``(inside, ix0, ix1, iy0, iy1, cx, cy)``: ``inside`` is false when the square of half-side
    ``sqrt(bound2) + slack`` misses the grid (also for NaN: nothing to find); the cell ranges are inclusive and
    clipped to the grid; ``(cx, cy)`` is the query's own cell, ``(-1, -1)`` when the query lies outside the grid.
    """
    x0, y0, slack, inv_h = geo[0], geo[1], geo[5], geo[6]
    gx, gy = int(geo[3]), int(geo[4])
    rad = math.sqrt(bound2) + slack
    fx0 = (qx - rad - x0) * inv_h
    fx1 = (qx + rad - x0) * inv_h
    fy0 = (qy - rad - y0) * inv_h
    fy1 = (qy + rad - y0) * inv_h
    if not (fx1 >= 0.0 and fy1 >= 0.0 and fx0 < gx and fy0 < gy):
        return False, 0, -1, 0, -1, -1, -1
    ix0 = int(math.floor(max(fx0, 0.0)))
    ix1 = min(int(math.floor(min(fx1, gx - 1.0))), gx - 1)
    iy0 = int(math.floor(max(fy0, 0.0)))
    iy1 = min(int(math.floor(min(fy1, gy - 1.0))), gy - 1)
    cx = int(math.floor(min(max((qx - x0) * inv_h, -1.0), float(gx))))
    cy = int(math.floor(min(max((qy - y0) * inv_h, -1.0), float(gy))))
    if not (0 <= cx < gx and 0 <= cy < gy):
        cx, cy = -1, -1
    return True, ix0, ix1, iy0, iy1, cx, cy


@njit(cache=True, inline="always")
def grid_nearest(qx: float, qy: float, pts: np.ndarray, start: np.ndarray, geo: np.ndarray, bound2: float) -> tuple[float, int]:
    """Exact nearest neighbour of ``(qx, qy)`` closer than ``sqrt(bound2)`` among the grid's points.

    ``pts`` (M, ≥2) holds the points in the grid's cell order (row k = point ``order[k]`` of
    :func:`build_grid`), ``start`` and ``geo`` as it returns them. Returns ``(d², k)`` with ``k`` the row
    in ``pts``, or ``(inf, -1)`` when no point is closer than the bound.

    Only the cells that meet the square of half-side ``sqrt(bound2) + slack`` around the query are read
    (2×2 cells at most for a bound under half a cell): the query's own cell first, then each other cell
    unless it lies farther than the best distance so far. Queries outside the grid, however far, cost
    one box test.
    """
    x0, y0, h, slack = geo[0], geo[1], geo[2], geo[5]
    gy = int(geo[4])
    inside, ix0, ix1, iy0, iy1, cx, cy = _search_box(qx, qy, geo, bound2)
    if not inside:
        return math.inf, -1
    best, bk = bound2, -1
    # the query's own cell first (when in the grid): its points are the likeliest nearest
    if cx >= 0:
        c = cx * gy + cy
        for k in range(start[c], start[c + 1]):
            dx = pts[k, 0] - qx
            dy = pts[k, 1] - qy
            d2 = dx * dx + dy * dy
            if d2 < best:
                best, bk = d2, k
    for ix in range(ix0, ix1 + 1):
        # distance from the query to the column of cells ix (minus the rounding slack), 0 inside
        ex = max(x0 + ix * h - qx, qx - (x0 + (ix + 1) * h), 0.0)
        ex = max(ex - slack, 0.0)
        ex2 = ex * ex
        if ex2 >= best:
            continue
        for iy in range(iy0, iy1 + 1):
            if ix == cx and iy == cy:
                continue
            ey = max(y0 + iy * h - qy, qy - (y0 + (iy + 1) * h), 0.0)
            ey = max(ey - slack, 0.0)
            if ex2 + ey * ey >= best:
                continue
            c = ix * gy + iy
            for k in range(start[c], start[c + 1]):
                dx = pts[k, 0] - qx
                dy = pts[k, 1] - qy
                d2 = dx * dx + dy * dy
                if d2 < best:
                    best, bk = d2, k
    if bk < 0:
        return math.inf, -1
    return best, bk


@njit(cache=True, inline="always")
def grid_nearest2(
    qx: float, qy: float, pts: np.ndarray, start: np.ndarray, geo: np.ndarray, bound2: float
) -> tuple[float, int, float]:
    """:func:`grid_nearest` that also returns ``second``: the squared distance of the second-nearest point, or
    ``bound2`` when there is none closer — a lower bound on the squared distance of every point but the nearest
    (of every point when none is found: ``(inf, -1, bound2)``).

    With it a caller can keep a nearest neighbour while the query moves by ``δ``: the point found stays the
    nearest as long as its distance is below ``sqrt(second) − δ``.
    """
    x0, y0, h, slack = geo[0], geo[1], geo[2], geo[5]
    gy = int(geo[4])
    inside, ix0, ix1, iy0, iy1, cx, cy = _search_box(qx, qy, geo, bound2)
    if not inside:
        return math.inf, -1, bound2
    best, bk, second = bound2, -1, bound2
    if cx >= 0:
        c = cx * gy + cy
        for k in range(start[c], start[c + 1]):
            dx = pts[k, 0] - qx
            dy = pts[k, 1] - qy
            d2 = dx * dx + dy * dy
            if d2 < best:
                second = best
                best, bk = d2, k
            elif d2 < second:
                second = d2
    for ix in range(ix0, ix1 + 1):
        ex = max(x0 + ix * h - qx, qx - (x0 + (ix + 1) * h), 0.0)
        ex = max(ex - slack, 0.0)
        ex2 = ex * ex
        if ex2 >= second:
            continue
        for iy in range(iy0, iy1 + 1):
            if ix == cx and iy == cy:
                continue
            ey = max(y0 + iy * h - qy, qy - (y0 + (iy + 1) * h), 0.0)
            ey = max(ey - slack, 0.0)
            if ex2 + ey * ey >= second:
                continue
            c = ix * gy + iy
            for k in range(start[c], start[c + 1]):
                dx = pts[k, 0] - qx
                dy = pts[k, 1] - qy
                d2 = dx * dx + dy * dy
                if d2 < best:
                    second = best
                    best, bk = d2, k
                elif d2 < second:
                    second = d2
    if bk < 0:
        return math.inf, -1, bound2
    return best, bk, second

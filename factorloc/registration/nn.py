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
"""

from __future__ import annotations

import numpy as np
from scipy.spatial import cKDTree

from factorloc.errors import InputError

try:  # optional accelerator, exact like cKDTree
    import small_gicp as _small_gicp
except ImportError:  # pragma: no cover - depends on the environment
    _small_gicp = None

__all__ = ["LIFT_Z", "KdTree2D", "fast_backend", "lift_2d"]


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
        self.lifted = lift_2d(pts)
        """The points lifted to 3D (M×3, z = :data:`LIFT_Z`), read-only."""
        self.lifted.setflags(write=False)
        self._sg = None
        self._ck = None
        if backend != "scipy" and _small_gicp is not None:
            self._sg = _small_gicp.KdTree(self.lifted, num_threads=1)
        else:
            self._ck = cKDTree(pts)

    @classmethod
    def from_lifted(cls, lifted: np.ndarray) -> KdTree2D:
        """A tree on points already lifted (M×3 C-contiguous float64, third column :data:`LIFT_Z`, M ≥ 1), as
        :func:`lift_2d` makes them: no validation, no copy (the caller must not modify them)."""
        self = cls.__new__(cls)
        self.n = len(lifted)
        self.lifted = lifted
        self._sg = self._ck = None
        if _small_gicp is not None:
            self._sg = _small_gicp.KdTree(lifted, num_threads=1)
        else:
            self._ck = cKDTree(lifted[:, :2])
        return self

    def nearest_lifted(self, lifted: np.ndarray, k: int = 1) -> tuple[np.ndarray, np.ndarray]:
        """The ``k`` (≤ M) nearest neighbours of each of N points given lifted (N×3 C-contiguous float64, third
        column :data:`LIFT_Z`): ``(d, idx)``, distances (m, never ``inf``) and int64 indices, (N,) for ``k = 1``
        else (N, k).

        The inner loop's query (no bound, no validation, no copies beyond the result): about 12 µs for 180
        points against 180 with small_gicp. Same values as :meth:`query` without a bound.
        """
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

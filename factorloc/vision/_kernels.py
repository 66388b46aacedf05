"""Compiled (numba) inner loop of the compass's descriptor matching; imported on first use (``import factorloc`` stays cheap).

:func:`two_nearest_in_window` is the windowed half of :func:`factorloc.vision.keypoints.match` (L2) in one pass:
the same float32 operations, in the same order, as the NumPy expression it replaces (the mask of
:func:`~factorloc.vision.keypoints.circular_abs_diff`, the squared norms added, ``argmin`` and the second minimum),
without its Nq×Nr temporaries. Compiled without fast-math: every operation rounds as NumPy's does.
"""

from __future__ import annotations

from factorloc.jit import configure

configure()

import numpy as np  # noqa: E402
from numba import njit  # noqa: E402


@njit(cache=True)
def two_nearest_in_window(
    d2: np.ndarray,
    ref_sq_norms: np.ndarray,
    az_ref: np.ndarray,
    az_query: np.ndarray,
    reach: np.float32,
    two_pi: np.float32,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per query row: the allowed reference column of the smallest ``d2 + ‖r‖²``, that value and the second smallest.

    ``d2`` (Nq×Nr float32) is ``−2 q·r``; ``az_ref`` (Nr,) and ``az_query`` (Nq,, the window's offset added) float32
    azimuths (rad); a pair is allowed when ``|x − 2π·rint(x/2π)| ≤ reach`` with ``x = az_ref − az_query`` (float32).
    A row without an allowed column gives column 0 and two infinities; ties keep the first column (as ``argmin``).
    """
    nq, nr = d2.shape
    best_j = np.zeros(nq, dtype=np.int64)
    best = np.full(nq, np.inf, dtype=np.float32)
    second = np.full(nq, np.inf, dtype=np.float32)
    row = np.empty(nr, dtype=np.float32)
    inf = np.float32(np.inf)
    for i in range(nq):
        b = az_query[i]
        for j in range(nr):  # branch-free: vectorized
            x = az_ref[j] - b
            x = x - two_pi * np.rint(x / two_pi)
            row[j] = d2[i, j] + ref_sq_norms[j] if abs(x) <= reach else inf
        lo = inf
        nx = inf
        k = 0
        for j in range(nr):
            v = row[j]
            if v < lo:
                nx = lo
                lo = v
                k = j
            elif v < nx:
                nx = v
        best_j[i] = k
        best[i] = lo
        second[i] = nx
    return best_j, best, second

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

_LANES = 16


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
    npad = ((nr + _LANES - 1) // _LANES) * _LANES
    row = np.empty(npad, dtype=np.float32)
    inf = np.float32(np.inf)
    row[nr:] = inf
    lo = np.empty(_LANES, dtype=np.float32)
    nx = np.empty(_LANES, dtype=np.float32)
    kk = np.empty(_LANES, dtype=np.int64)
    for i in range(nq):
        b = az_query[i]
        for j in range(nr):  # branch-free: vectorized
            x = az_ref[j] - b
            x = x - two_pi * np.rint(x / two_pi)
            row[j] = d2[i, j] + ref_sq_norms[j] if abs(x) <= reach else inf
        # the two smallest per lane (column j in lane j mod 16; selects, no branches), then merged: the smallest
        # value, its first column, and the second smallest of the row (a tie with the smallest counts) — the
        # values and the column a sequential scan finds
        lo[:] = inf
        nx[:] = inf
        kk[:] = 0
        for j0 in range(0, npad, _LANES):
            for lane in range(_LANES):
                v = row[j0 + lane]
                c = v < lo[lane]
                nx[lane] = lo[lane] if c else (v if v < nx[lane] else nx[lane])
                kk[lane] = j0 + lane if c else kk[lane]
                lo[lane] = v if c else lo[lane]
        ls = 0
        for lane in range(1, _LANES):
            if lo[lane] < lo[ls] or (lo[lane] == lo[ls] and kk[lane] < kk[ls]):
                ls = lane
        s2 = nx[ls]
        for lane in range(_LANES):
            if lane != ls and lo[lane] < s2:
                s2 = lo[lane]
        best_j[i] = kk[ls] if lo[ls] < inf else 0
        best[i] = lo[ls]
        second[i] = s2
    return best_j, best, second


# ---------------------------------------------------------------------------------------------------------------
# 2D resection (factorloc.vision.resection): the minimal 3-bearing solver, MSAC scoring, the refinement on the
# inliers and the rival optima, compiled. The same algorithm as the NumPy reference of
# :func:`factorloc.vision.resection.ransac` (``compiled=False``), not the same rounding: the cubic is solved in closed
# form (then polished by Newton) instead of as a companion-matrix eigenproblem, the 3×3 systems by LU with partial
# pivoting written out, the sums in index order, atan2 / sin / cos from the C library. No fast-math.

_PI = np.pi
_TWO_PI = 2.0 * np.pi
_SQRT3_2 = 0.5 * np.sqrt(3.0)


@njit(cache=True)
def _wrap(x: float) -> float:
    """``mod(x + π, 2π) − π`` with π mapped to −π: :func:`factorloc.geometry.wrap_angle`'s arithmetic."""
    y = (x + _PI) % _TWO_PI - _PI
    return -_PI if y >= _PI else y


@njit(cache=True)
def _cubic_real_roots(a: float, b: float, c: float, out: np.ndarray) -> None:
    """Real roots of ``t³ + a t² + b t + c`` into ``out`` (3,), NaN where none (a complex pair).

    Closed form (Cardano with the stable choice of cube root for one real root, the trigonometric form for three),
    each simple root polished by two Newton steps. A complex pair whose imaginary part is at most
    ``1e-7 · max(1, |real part|)`` counts as a (double) real root, as the companion eigenvalues of the NumPy
    reference do.
    """
    out[:] = np.nan
    a3 = a / 3.0
    p = b - a * a3
    q = 2.0 * a3 * a3 * a3 - a3 * b + c
    disc = 0.25 * q * q + p * p * p / 27.0
    n = 0
    polish = np.zeros(3, dtype=np.bool_)
    if disc > 0.0:
        s = np.cbrt(0.5 * abs(q) + np.sqrt(disc))
        big = -s if q >= 0.0 else s
        small = -p / (3.0 * big)
        out[0] = big + small - a3
        polish[0] = True
        n = 1
        re = -0.5 * (big + small) - a3
        im = _SQRT3_2 * abs(big - small)
        if im <= 1e-7 * max(1.0, abs(re)):
            out[1] = re
            out[2] = re
            n = 3
    elif p == 0.0:
        out[0] = -a3  # a triple root (q = 0 too)
        n = 1
    else:
        m = 2.0 * np.sqrt(-p / 3.0)
        arg = 3.0 * q / (p * m)
        arg = min(1.0, max(-1.0, arg))
        phi = np.arccos(arg) / 3.0
        for k in range(3):
            out[k] = m * np.cos(phi - _TWO_PI * k / 3.0) - a3
            polish[k] = True
        n = 3
    for k in range(n):
        if not polish[k]:
            continue
        t = out[k]
        for _ in range(2):
            f = ((t + a) * t + b) * t + c
            fp = (3.0 * t + 2.0 * a) * t + b
            if fp == 0.0:
                break
            t_new = t - f / fp
            f_new = ((t_new + a) * t_new + b) * t_new + c
            if not abs(f_new) <= abs(f):
                break
            t = t_new
        out[k] = t


@njit(cache=True)
def _set_rows(
    pts: np.ndarray,
    b: np.ndarray,
    idx: np.ndarray,
    alpha: np.ndarray,
    beta: np.ndarray,
    px: np.ndarray,
    py: np.ndarray,
    bb: np.ndarray,
) -> tuple[float, float]:
    """The constraint rows α (θ = 0) and β (θ = π/2) of a minimal set's bearings, their points and azimuths; returns
    the largest |coordinate| and the smallest max-norm gap between two of the three points."""
    big = 0.0
    for i in range(3):
        j = idx[i]
        px[i] = pts[j, 0]
        py[i] = pts[j, 1]
        bb[i] = b[j]
        big = max(big, abs(px[i]), abs(py[i]))
        sb, cb = np.sin(bb[i]), np.cos(bb[i])
        alpha[i, 0] = -sb
        alpha[i, 1] = cb
        alpha[i, 2] = px[i] * sb - py[i] * cb
        beta[i, 0] = -cb
        beta[i, 1] = -sb
        beta[i, 2] = px[i] * cb + py[i] * sb
    gap = min(
        max(abs(px[0] - px[1]), abs(py[0] - py[1])),
        max(abs(px[0] - px[2]), abs(py[0] - py[2])),
        max(abs(px[1] - px[2]), abs(py[1] - py[2])),
    )
    return big, gap


@njit(cache=True)
def _triple(u: np.ndarray, v: np.ndarray, w: np.ndarray) -> float:
    """``u · (v × w)``."""
    c0 = v[1] * w[2] - v[2] * w[1]
    c1 = v[2] * w[0] - v[0] * w[2]
    c2 = v[0] * w[1] - v[1] * w[0]
    return u[0] * c0 + u[1] * c1 + u[2] * c2


@njit(cache=True)
def _position_at(
    th: float, alpha: np.ndarray, beta: np.ndarray, px: np.ndarray, py: np.ndarray, bb: np.ndarray
) -> tuple[bool, float, float]:
    """(x, y) of a minimal set at heading θ by the 2×2 normal equations of its rows ``cos θ·α + sin θ·β``, and
    whether the system is regular and every point lies ahead along its bearing (cheirality)."""
    c, s = np.cos(th), np.sin(th)
    m00 = m01 = m11 = v0 = v1 = 0.0
    for i in range(3):
        r0 = c * alpha[i, 0] + s * beta[i, 0]
        r1 = c * alpha[i, 1] + s * beta[i, 1]
        r2 = -(c * alpha[i, 2] + s * beta[i, 2])
        m00 += r0 * r0
        m01 += r0 * r1
        m11 += r1 * r1
        v0 += r0 * r2
        v1 += r1 * r2
    det2 = m00 * m11 - m01 * m01
    if not abs(det2) > 1e-12:
        return False, 0.0, 0.0
    x = (m11 * v0 - m01 * v1) / det2
    y = (m00 * v1 - m01 * v0) / det2
    if not (np.isfinite(x) and np.isfinite(y)):
        return False, x, y
    for i in range(3):
        phi = th + bb[i]
        if not (px[i] - x) * np.cos(phi) + (py[i] - y) * np.sin(phi) > 0.0:
            return False, x, y
    return True, x, y


@njit(cache=True)
def _msac(
    pts: np.ndarray, b: np.ndarray, cb: np.ndarray, sb: np.ndarray, x: float, y: float, th: float, threshold: float
) -> tuple[float, int]:
    """``Σ min(r², threshold²)`` and the inlier count ``|r| ≤ threshold`` of all bearings at pose (x, y, θ).

    ``r = wrap(atan2(P − p) − θ − b)`` is computed only for the bearings that may be inliers: a bearing whose
    angle to its point, from the rotated direction ``(cos(θ + b), sin(θ + b))`` (``cb``, ``sb`` = cos b, sin b),
    exceeds the threshold by more than 1 % in tangent (or lies behind) adds ``threshold²`` and no inlier — what
    the exact residual gives it — without an atan2 (the rounding of the test is ~1e-15, far inside the 1 %).
    """
    thr2 = threshold * threshold
    fast = threshold < 1.0
    tan_far = np.tan(threshold) * 1.01
    ct, st = np.cos(th), np.sin(th)
    total = 0.0
    count = 0
    for i in range(pts.shape[0]):
        dx = pts[i, 0] - x
        dy = pts[i, 1] - y
        if fast:
            ux = ct * cb[i] - st * sb[i]
            uy = st * cb[i] + ct * sb[i]
            along = ux * dx + uy * dy
            across = abs(ux * dy - uy * dx)
            if along <= 0.0 or across > tan_far * along:
                total += thr2
                continue
        r = _wrap(np.arctan2(dy, dx) - th - b[i])
        total += min(r * r, thr2)
        count += abs(r) <= threshold
    return total, count


@njit(cache=True)
def resection_hypotheses(
    pts: np.ndarray, b: np.ndarray, sets: np.ndarray, threshold: float
) -> tuple[np.ndarray, np.ndarray, int, np.ndarray]:
    """Poses of K minimal 3-bearing sets, each scored on all N bearings (MSAC) — one RANSAC batch.

    ``pts`` (N, 2) world points (m), ``b`` (N,) robot-frame azimuths (rad), ``sets`` (K, 3) indices, ``threshold``
    (rad). Returns ``(cand (M, 3), cost (M,), best_count, special (K,))``: the M valid candidates ``(x, y, θ)`` in
    the order of the reference's ``solve_minimal(...).reshape(-1, 3)`` (set by set; the cubic's roots, then each
    + π), their truncated squared residual sums ``Σ min(r², threshold²)``, the largest inlier count
    (``|r| ≤ threshold``) among them, and the sets whose cubic has (nearly) no t³ term (θ ≈ ±π/2 a root; left
    to the caller, which solves those rare sets with the reference solver).
    """
    k_sets = sets.shape[0]
    cand = np.empty((6 * k_sets, 3))
    cost = np.empty(6 * k_sets)
    special = np.zeros(k_sets, dtype=np.bool_)
    m = 0
    best_count = 0
    alpha = np.empty((3, 3))
    beta = np.empty((3, 3))
    roots = np.empty(3)
    thetas = np.empty(6)
    px = np.empty(3)
    py = np.empty(3)
    bb = np.empty(3)
    cb = np.cos(b)
    sb = np.sin(b)
    for k in range(k_sets):
        big, gap = _set_rows(pts, b, sets[k], alpha, beta, px, py, bb)
        # det(cα + sβ) = k0 c³ + k1 c² s + k2 c s² + k3 s³ (multilinear in the rows), each term a triple product
        a0, a1, a2, b0, b1, b2 = alpha[0], alpha[1], alpha[2], beta[0], beta[1], beta[2]
        k0 = _triple(a0, a1, a2)
        k1 = _triple(b0, a1, a2) + _triple(a0, b1, a2) + _triple(a0, a1, b2)
        k2 = _triple(a0, b1, b2) + _triple(b0, a1, b2) + _triple(b0, b1, a2)
        k3 = _triple(b0, b1, b2)
        scale = max(abs(k3), abs(k2), abs(k1), abs(k0))
        # two bearings to one point leave a one-parameter family of poses: no candidate
        if not (scale > 0.0 and gap > 1e-9 * (1.0 + big)):
            continue
        if not abs(k3) > 1e-9 * scale:
            special[k] = True
            continue
        _cubic_real_roots(k2 / k3, k1 / k3, k0 / k3, roots)
        for i in range(3):
            thetas[i] = np.arctan(roots[i])
            thetas[i + 3] = thetas[i] + _PI
        for jc in range(6):
            th = thetas[jc]
            if not np.isfinite(th):
                continue
            ok, x, y = _position_at(th, alpha, beta, px, py, bb)
            if not ok:
                continue
            th_w = _wrap(th)
            total, count = _msac(pts, b, cb, sb, x, y, th_w, threshold)
            cand[m, 0] = x
            cand[m, 1] = y
            cand[m, 2] = th_w
            cost[m] = total
            m += 1
            best_count = max(best_count, count)
    return cand[:m], cost[:m], best_count, special


@njit(cache=True)
def three_smallest(keys: np.ndarray) -> np.ndarray:
    """Per row of ``keys`` (K, N ≥ 3): the columns of its three smallest values, in ascending order of value (equal
    values in ascending column order) — ``np.argsort(keys, axis=1, kind="stable")[:, :3]`` in one pass."""
    k, n = keys.shape
    out = np.empty((k, 3), dtype=np.int64)
    for r in range(k):
        a0 = a1 = a2 = np.inf
        i0 = i1 = i2 = 0
        for j in range(n):
            v = keys[r, j]
            if v < a2:
                if v < a1:
                    a2, i2 = a1, i1
                    if v < a0:
                        a1, i1 = a0, i0
                        a0, i0 = v, j
                    else:
                        a1, i1 = v, j
                else:
                    a2, i2 = v, j
        out[r, 0] = i0
        out[r, 1] = i1
        out[r, 2] = i2
    return out


@njit(cache=True)
def _solve3(h: np.ndarray, g: np.ndarray, out: np.ndarray) -> bool:
    """``out = h⁻¹ g`` for a 3×3 ``h`` by LU with partial pivoting (as LAPACK's gesv); False on a zero pivot."""
    a = h.copy()
    x = g.copy()
    for col in range(3):
        piv = col
        for r in range(col + 1, 3):
            if abs(a[r, col]) > abs(a[piv, col]):
                piv = r
        if a[piv, col] == 0.0:
            return False
        if piv != col:
            for c in range(3):
                t = a[col, c]
                a[col, c] = a[piv, c]
                a[piv, c] = t
            t = x[col]
            x[col] = x[piv]
            x[piv] = t
        for r in range(col + 1, 3):
            f = a[r, col] / a[col, col]
            for c in range(col + 1, 3):
                a[r, c] -= f * a[col, c]
            x[r] -= f * x[col]
    for r in range(2, -1, -1):
        acc = x[r]
        for c in range(r + 1, 3):
            acc -= a[r, c] * out[c]
        out[r] = acc / a[r, r]
    return True


@njit(cache=True)
def _inv3(h: np.ndarray, out: np.ndarray) -> bool:
    """``out = h⁻¹`` (3×3) column by column with :func:`_solve3`; False when singular."""
    e = np.zeros(3)
    col = np.empty(3)
    for j in range(3):
        e[:] = 0.0
        e[j] = 1.0
        if not _solve3(h, e, col):
            return False
        out[:, j] = col
    return True


@njit(cache=True)
def _normal_masked(
    pts: np.ndarray, b: np.ndarray, w: np.ndarray, mask: np.ndarray, state: np.ndarray, h: np.ndarray, g: np.ndarray
) -> float:
    """Weighted Gauss–Newton normal matrix ``h = Σ w JᵀJ`` and gradient ``g = Σ w Jᵀr`` of the masked bearings'
    angular residuals at ``state``; returns ``Σ w r²``."""
    h[:] = 0.0
    g[:] = 0.0
    ss = 0.0
    for i in range(pts.shape[0]):
        if not mask[i]:
            continue
        dx = pts[i, 0] - state[0]
        dy = pts[i, 1] - state[1]
        r2 = max(dx * dx + dy * dy, 1e-12)
        res = _wrap(np.arctan2(dy, dx) - state[2] - b[i])
        j0 = dy / r2
        j1 = -(dx / r2)
        wi = w[i]
        h[0, 0] += wi * j0 * j0
        h[0, 1] += wi * j0 * j1
        h[0, 2] -= wi * j0
        h[1, 1] += wi * j1 * j1
        h[1, 2] -= wi * j1
        h[2, 2] += wi
        g[0] += wi * j0 * res
        g[1] += wi * j1 * res
        g[2] -= wi * res
        ss += wi * res * res
    h[1, 0] = h[0, 1]
    h[2, 0] = h[0, 2]
    h[2, 1] = h[1, 2]
    return ss


@njit(cache=True)
def resection_refine(
    pts: np.ndarray,
    b: np.ndarray,
    w: np.ndarray,
    mask: np.ndarray,
    start: np.ndarray,
    sigma_floor: float,
    iterations: int,
) -> tuple[bool, np.ndarray, np.ndarray, float, float]:
    """Gauss–Newton on the masked bearings from ``start`` (x, y, θ): :func:`factorloc.vision.resection.refine`
    without its jackknife. Returns ``(ok, state (3,), covariance (3, 3), σ̂, condition)``; ``ok`` False when
    fewer than 3 bearings, a singular or non-finite step, or a normal matrix singular in double precision
    (smallest eigenvalue ≤ 1e-12 × the largest)."""
    state = start.copy()
    cov = np.full((3, 3), np.nan)
    n = 0
    for i in range(mask.shape[0]):
        n += mask[i]
    if n < 3:
        return False, state, cov, np.nan, np.nan
    h = np.empty((3, 3))
    g = np.empty(3)
    step = np.empty(3)
    for _ in range(iterations):
        _normal_masked(pts, b, w, mask, state, h, g)
        if not _solve3(h, -g, step):
            return False, state, cov, np.nan, np.nan
        big = 0.0
        for j in range(3):
            if not np.isfinite(step[j]):
                return False, state, cov, np.nan, np.nan
            state[j] += step[j]
            big = max(big, abs(step[j]))
        if big < 1e-10:
            break
    ss = _normal_masked(pts, b, w, mask, state, h, g)
    h_inv = np.empty((3, 3))
    if not _inv3(h, h_inv):
        return False, state, cov, np.nan, np.nan
    ev_h = np.linalg.eigvalsh(h)
    if not np.all(np.isfinite(h_inv)) or not ev_h[0] > 1e-12 * ev_h[2]:
        return False, state, cov, np.nan, np.nan
    sigma_hat = np.sqrt(ss / max(n - 3, 1))
    s = max(sigma_hat, sigma_floor)
    r = np.empty(n)
    k = 0
    for i in range(mask.shape[0]):
        if mask[i]:
            dx = pts[i, 0] - state[0]
            dy = pts[i, 1] - state[1]
            r[k] = np.sqrt(max(dx * dx + dy * dy, 1e-12))
            k += 1
    r_med = np.median(r)
    scaled = h.copy()
    for i in range(3):
        for j in range(3):
            scaled[i, j] *= (r_med if i < 2 else 1.0) * (r_med if j < 2 else 1.0)
    ev = np.linalg.eigvalsh(scaled)
    condition = ev[2] / ev[0] if ev[0] > 0.0 else np.inf
    cov = s * s * h_inv
    state[2] = _wrap(state[2])
    return True, state, cov, sigma_hat, condition


@njit(cache=True)
def _inliers_at(pts: np.ndarray, b: np.ndarray, state: np.ndarray, threshold: float, out: np.ndarray) -> int:
    count = 0
    for i in range(pts.shape[0]):
        r = _wrap(np.arctan2(pts[i, 1] - state[1], pts[i, 0] - state[0]) - state[2] - b[i])
        out[i] = abs(r) <= threshold
        count += out[i]
    return count


@njit(cache=True)
def resection_best(
    pts: np.ndarray,
    b: np.ndarray,
    w: np.ndarray,
    cand: np.ndarray,
    cost: np.ndarray,
    threshold: float,
    min_inliers: int,
    sigma_floor: float,
    rivals: int,
    distinct_m: float,
    distinct_rad: float,
) -> tuple[bool, np.ndarray, np.ndarray, np.ndarray, float, float, int]:
    """The best MSAC hypothesis refined on its inliers (re-selected from the refined pose, up to three rounds),
    then the support of the best *different* local optimum among the next-best ``rivals`` hypotheses.

    The steps of :func:`factorloc.vision.resection.ransac` after the sampling. Returns
    ``(ok, state, covariance, inliers (N,), σ̂, condition, runner_up)``.
    """
    n = pts.shape[0]
    need = max(3, min_inliers)
    best = int(np.argmin(cost))
    inl = np.empty(n, dtype=np.bool_)
    again = np.empty(n, dtype=np.bool_)
    cnt = _inliers_at(pts, b, cand[best], threshold, inl)
    state = cand[best].copy()
    cov = np.full((3, 3), np.nan)
    sigma_hat = np.nan
    condition = np.nan
    for _ in range(3):
        if cnt < need:
            return False, state, cov, inl, sigma_hat, condition, 0
        ok, st, cv, sh, cd = resection_refine(pts, b, w, inl, state, sigma_floor, 20)
        if not ok:
            return False, state, cov, inl, sigma_hat, condition, 0
        state, cov, sigma_hat, condition = st, cv, sh, cd
        cnt2 = _inliers_at(pts, b, state, threshold, again)
        same = True
        for i in range(n):
            if again[i] != inl[i]:
                same = False
                break
        if same:
            break
        inl[:] = again
        cnt = cnt2
    return (
        True,
        state,
        cov,
        inl,
        sigma_hat,
        condition,
        _rival_support(pts, b, w, cand, cost, state, cov, threshold, rivals, need, distinct_m, distinct_rad),
    )


@njit(cache=True)
def _d2_from(pose: np.ndarray, x: float, y: float, th: float, info: np.ndarray, e: np.ndarray) -> float:
    """Squared Mahalanobis distance of (x, y, θ) from ``pose`` under the information matrix ``info`` (θ wrapped)."""
    e[0] = x - pose[0]
    e[1] = y - pose[1]
    e[2] = _wrap(th - pose[2])
    d2 = 0.0
    for i in range(3):
        for j in range(3):
            d2 += e[i] * info[i, j] * e[j]
    return d2


@njit(cache=True)
def _step_rivals(pts: np.ndarray, b: np.ndarray, w: np.ndarray, masks: np.ndarray, states: np.ndarray, steps: int) -> bool:
    """``steps`` Gauss–Newton steps of every rival state on its own masked bearings (``+1e-12 I`` on the normal
    matrix); False on a zero pivot (the reference's batched solve then raises)."""
    h = np.empty((3, 3))
    g = np.empty(3)
    step = np.empty(3)
    for _ in range(steps):
        for r in range(states.shape[0]):
            _normal_masked(pts, b, w, masks[r], states[r], h, g)
            for j in range(3):
                h[j, j] += 1e-12
            if not _solve3(h, g, step):
                return False
            for j in range(3):
                states[r, j] -= step[j]
    return True


@njit(cache=True)
def _rival_support(
    pts: np.ndarray,
    b: np.ndarray,
    w: np.ndarray,
    cand: np.ndarray,
    cost: np.ndarray,
    pose: np.ndarray,
    cov: np.ndarray,
    threshold: float,
    rivals: int,
    need: int,
    distinct_m: float,
    distinct_rad: float,
) -> int:
    """Inlier count of the best different local optimum among the next-best hypotheses (6 Gauss–Newton steps
    each on its own inliers), else 0: :func:`factorloc.vision.resection._rival_support`."""
    info = np.empty((3, 3))
    if not _inv3(cov, info):
        return 0
    m = cand.shape[0]
    order = np.argsort(cost, kind="mergesort")
    picks = np.empty(rivals, dtype=np.int64)
    n_picks = 0
    e = np.empty(3)
    for idx in range(m):
        if n_picks >= rivals:
            break
        k = order[idx]
        if _d2_from(pose, cand[k, 0], cand[k, 1], cand[k, 2], info, e) > 11.83:
            picks[n_picks] = k
            n_picks += 1
    if n_picks == 0:
        return 0
    n = pts.shape[0]
    states = np.empty((n_picks, 3))
    masks = np.empty((n_picks, n), dtype=np.bool_)
    enough = np.empty(n_picks, dtype=np.bool_)
    for r in range(n_picks):
        states[r] = cand[picks[r]]
        enough[r] = _inliers_at(pts, b, states[r], threshold, masks[r]) >= need
    if not _step_rivals(pts, b, w, masks, states, 6):
        return 0
    best = 0
    scratch = np.empty(n, dtype=np.bool_)
    for r in range(n_picks):
        st = states[r]
        if not (enough[r] and np.isfinite(st[0]) and np.isfinite(st[1]) and np.isfinite(st[2])):
            continue
        if _d2_from(pose, st[0], st[1], st[2], info, e) <= 11.83:
            continue  # converged back to the result: the same optimum
        if np.hypot(e[0], e[1]) <= distinct_m and abs(e[2]) <= distinct_rad:
            continue  # a hair away: the same optimum, refined on a slightly different inlier set
        best = max(best, _inliers_at(pts, b, st, threshold, scratch))
    return best


# ---------------------------------------------------------------------------------------------------------------
# Heading votes (factorloc.vision.keypoints): circular support and the densest mode, compiled. The same steps as
# the NumPy reference (``compiled=False``): wrap, sort, the sorted array extended by ±2π, two binary searches per
# vote; the mode's circular mean summed in index order (NumPy sums pairwise), sin / cos from the C library.


@njit(cache=True)
def circular_support(votes: np.ndarray, band: float) -> np.ndarray:
    """For each vote (rad), how many votes (itself included) lie within ``±band`` of it on the circle (≤ n)."""
    n = votes.shape[0]
    v = np.empty(n)
    for i in range(n):
        v[i] = _wrap(votes[i])
    s = np.sort(v)
    ext = np.empty(3 * n)
    for i in range(n):
        ext[i] = s[i] - _TWO_PI
        ext[n + i] = s[i]
        ext[2 * n + i] = s[i] + _TWO_PI
    lo = np.searchsorted(ext, v - band, side="left")
    hi = np.searchsorted(ext, v + band, side="right")
    out = np.empty(n, dtype=np.int64)
    for i in range(n):
        out[i] = min(hi[i] - lo[i], n)
    return out


@njit(cache=True)
def circular_support_rows(votes: np.ndarray, band: float) -> np.ndarray:
    """:func:`circular_support` of every row of an m×n array of votes (m×n counts)."""
    m, n = votes.shape
    out = np.empty((m, n), dtype=np.int64)
    for r in range(m):
        out[r] = circular_support(np.ascontiguousarray(votes[r]), band)
    return out


@njit(cache=True)
def _band_mask(v: np.ndarray, theta: float, band: float, out: np.ndarray) -> int:
    count = 0
    for i in range(v.shape[0]):
        out[i] = abs(_wrap(v[i] - theta)) <= band
        count += out[i]
    return count


@njit(cache=True)
def vote_mode(votes: np.ndarray, band: float, iterations: int) -> tuple[float, np.ndarray, int]:
    """The densest mode of heading votes, its inliers and the largest support further than 3 bands from it:
    :func:`factorloc.vision.keypoints.vote_consensus` (n ≥ 1)."""
    n = votes.shape[0]
    support = circular_support(votes, band)
    theta = votes[int(np.argmax(support))]
    inliers = np.empty(n, dtype=np.bool_)
    count = _band_mask(votes, theta, band, inliers)
    for _ in range(iterations):
        if count == 0:
            break
        s = 0.0
        c = 0.0
        for i in range(n):
            if inliers[i]:
                d = _wrap(votes[i] - theta)
                s += np.sin(d)
                c += np.cos(d)
        theta = _wrap(theta + np.arctan2(s / count, c / count))
        count = _band_mask(votes, theta, band, inliers)
    runner_up = 0
    for i in range(n):
        if abs(_wrap(votes[i] - theta)) > 3.0 * band:
            runner_up = max(runner_up, support[i])
    return theta, inliers, runner_up

"""Planar pose from bearings to known points: 2D resection (minimal 3-bearing solver, RANSAC, Gauss–Newton).

*Beyond the patent* (WO 2015/158682 gives its virtual compass a heading θ only): when the reference carries
depth (its scan's wall outline or its cloud), each keypoint match between the reference panorama and a query
view is a *bearing* from the query robot to a point whose world position is known. Three or more such bearings
fix the robot's whole planar pose (x, y, θ); two fix θ once the position is known.

Model (world frame, metres and radians): the robot at ``(x, y)`` with heading θ sees the point ``P_i`` at the
robot-frame azimuth ``b_i`` (counter-clockwise from the robot's x axis), up to an angular error ε_i::

    atan2(P_i,y − y, P_i,x − x) − θ = b_i + ε_i,   ε_i ~ N(0, σ² / w_i)

with relative weights ``w_i`` (1 by default) and one unknown scale σ.

* :func:`solve_minimal` — all poses that fit three bearings exactly. The constraint
  ``(P_i − p) × u(θ + b_i) = 0`` is linear in ``(x, y, 1)`` with rows linear in ``(cos θ, sin θ)``; the 3×3
  determinant vanishing is a homogeneous cubic in ``(cos θ, sin θ)``, i.e. a cubic in ``tan θ`` (solved as a
  companion-matrix eigenproblem, batched). Each root gives ``(x, y)`` by linear least squares; only poses that
  see every point *in front* along its bearing are kept (cheirality).
* :func:`refine` — Gauss–Newton on the angular residuals; covariance ``σ̂² (JᵀWJ)⁻¹`` with the residual variance
  ``σ̂² = Σ w_i r_i² / (n − 3)`` (the residuals' own scatter, so the depth map's errors are covered as far as
  they show in the residuals).
* :func:`ransac` — hypotheses from random minimal sets (a fixed seed: the result does not depend on the
  machine), scored by the truncated squared residual (MSAC), the best one refined on its inliers.
* :func:`heading_given_position` — two or more bearings and a known position give θ (circular mean).

References: the three-point resection problem (Snellius–Pothenot); RANSAC (Fischler & Bolles 1981, who
introduced it on this very problem); MSAC scoring (Torr & Zisserman 2000).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from factorloc.errors import InputError
from factorloc.geometry import Pose2, wrap_angle

__all__ = [
    "Resection",
    "bearing_residuals",
    "heading_given_position",
    "ransac",
    "refine",
    "solve_minimal",
]


@dataclass(frozen=True, eq=False)
class Resection:
    """A robot pose from bearings, with its covariance and the bearings it rests on.

    Parameters
    ----------
    pose
        The robot's world pose ``T_world_robot`` (x, y in m; θ in rad).
    covariance
        3×3 covariance of ``(x, y, θ)`` (m², rad²), world frame: ``σ̂² (JᵀWJ)⁻¹`` with ``σ̂`` the residual σ
        (at least ``sigma_floor_rad`` when one was given).
    inliers
        Boolean mask over the input bearings the pose was refined on.
    residual_sigma_rad
        ``σ̂``: the weighted RMS angular residual of the inliers with n − 3 degrees of freedom (before any floor).
    condition
        Condition number of ``D JᵀWJ D`` with ``D = diag(r̄, r̄, 1)`` and ``r̄`` the inliers' median range (the
        position columns made dimensionless): large when the bearings cannot separate a turn from a shift
        (all points on one narrow far wall, or the robot on the circle through the points).
    runner_up
        RANSAC only: the inlier count of the best-supported *different* local optimum found (see ``rivals`` of
        :func:`ransac`); 0 when none.
    """

    pose: Pose2
    covariance: np.ndarray
    inliers: np.ndarray
    residual_sigma_rad: float
    condition: float
    runner_up: int = 0

    @property
    def n_inliers(self) -> int:
        """How many bearings the pose rests on."""
        return int(np.count_nonzero(self.inliers))

    @property
    def sigma_theta_rad(self) -> float:
        """The heading's marginal σ (rad)."""
        return float(math.sqrt(max(self.covariance[2, 2], 0.0)))

    @property
    def sigma_position_m(self) -> float:
        """The position's largest σ (m): √ of the largest eigenvalue of the 2×2 position block."""
        return float(math.sqrt(max(np.linalg.eigvalsh(self.covariance[:2, :2])[-1], 0.0)))


def _inputs(points_xy_m: np.ndarray, bearings_rad: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    pts = np.asarray(points_xy_m, dtype=np.float64)
    b = np.asarray(bearings_rad, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise InputError(f"resection points_xy_m must be N×2, got shape {pts.shape}")
    if b.shape != (len(pts),):
        raise InputError(f"resection bearings_rad must have one bearing per point ({len(pts)}), got shape {b.shape}")
    if not (np.all(np.isfinite(pts)) and np.all(np.isfinite(b))):
        raise InputError("resection points_xy_m and bearings_rad must be finite")
    return pts, b


def bearing_residuals(points_xy_m: np.ndarray, bearings_rad: np.ndarray, pose: Pose2) -> np.ndarray:
    """Angular residuals ``atan2(P − p) − θ − b`` (rad, wrapped to [−π, π)) of bearings seen from ``pose``."""
    pts, b = _inputs(points_xy_m, bearings_rad)
    d = pts - np.array([pose.x, pose.y])
    return np.asarray(wrap_angle(np.arctan2(d[:, 1], d[:, 0]) - pose.theta - b), dtype=np.float64)


def _rows(pts: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The constraint rows at θ = 0 (α) and θ = π/2 (β): row(θ) = cos θ·α + sin θ·β (shapes (..., 3))."""
    sb, cb = np.sin(b), np.cos(b)
    px, py = pts[..., 0], pts[..., 1]
    alpha = np.stack([-sb, cb, px * sb - py * cb], axis=-1)
    beta = np.stack([-cb, -sb, px * cb + py * sb], axis=-1)
    return alpha, beta


def solve_minimal(points_xy_m: np.ndarray, bearings_rad: np.ndarray) -> np.ndarray:
    """Every pose that sees three points exactly along three bearings (batched).

    Parameters
    ----------
    points_xy_m
        (K, 3, 2) or (3, 2): the points (world frame, m) of K minimal sets.
    bearings_rad
        (K, 3) or (3,): their robot-frame azimuths (rad).

    Returns
    -------
    np.ndarray
        (K, 6, 3) (or (6, 3)) candidate poses ``(x, y, θ)``; rows that are not solutions (complex roots,
        points behind the robot, a singular set, two of the three points coincident) are NaN. Up to three
        roots of the cubic, each with θ and θ + π.
    """
    pts = np.asarray(points_xy_m, dtype=np.float64)
    b = np.asarray(bearings_rad, dtype=np.float64)
    single = pts.ndim == 2
    if single:
        pts, b = pts[None], b[None]
    if pts.shape[1:] != (3, 2) or b.shape != pts.shape[:2]:
        raise InputError(f"solve_minimal needs (K, 3, 2) points and (K, 3) bearings, got {pts.shape} and {b.shape}")
    k = len(pts)
    alpha, beta = _rows(pts, b)
    a0, a1, a2 = alpha[:, 0], alpha[:, 1], alpha[:, 2]
    b0, b1, b2 = beta[:, 0], beta[:, 1], beta[:, 2]

    def cross(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return np.stack(
            [
                u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1],
                u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2],
                u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0],
            ],
            axis=1,
        )

    def dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
        return u[:, 0] * v[:, 0] + u[:, 1] * v[:, 1] + u[:, 2] * v[:, 2]

    # det(cα + sβ) = k0 c³ + k1 c² s + k2 c s² + k3 s³ (multilinearity of the determinant in its rows), each
    # determinant a triple product det(u, v, w) = u·(v × w)
    aa, ba, ab, bb = cross(a1, a2), cross(b1, a2), cross(a1, b2), cross(b1, b2)
    k0 = dot(a0, aa)
    k1 = dot(b0, aa) + dot(a0, ba) + dot(a0, ab)
    k2 = dot(a0, bb) + dot(b0, ab) + dot(b0, ba)
    k3 = dot(b0, bb)
    coeffs = np.stack([k3, k2, k1, k0], axis=1)  # in t = tan θ, highest power first
    scale = np.max(np.abs(coeffs), axis=1)
    thetas = np.full((k, 3), np.nan)
    # two bearings to one point (a keypoint SIFT reports twice, with two orientations, matched twice) leave a
    # one-parameter family of poses: the cubic vanishes identically and its "roots" would be rounding noise
    gap = np.min(np.stack([np.abs(pts[:, i] - pts[:, j]).max(axis=1) for i, j in ((0, 1), (0, 2), (1, 2))]), axis=0)
    ok = (scale > 0.0) & (gap > 1e-9 * (1.0 + np.abs(pts).max(axis=(1, 2))))
    lead = np.abs(k3) > 1e-9 * np.where(ok, scale, 1.0)
    regular = ok & lead
    if np.any(regular):
        c = coeffs[regular] / coeffs[regular, :1]
        companion = np.zeros((int(regular.sum()), 3, 3))
        companion[:, 0, :] = -c[:, 1:]
        companion[:, 1, 0] = 1.0
        companion[:, 2, 1] = 1.0
        roots = np.linalg.eigvals(companion)
        real = np.abs(roots.imag) <= 1e-7 * np.maximum(1.0, np.abs(roots.real))
        thetas[regular] = np.where(real, np.arctan(roots.real), np.nan)
    for i in np.flatnonzero(ok & ~lead):  # θ = ±π/2 is (nearly) a root: rare, solved one by one
        r = np.roots(coeffs[i])
        r = r[np.abs(r.imag) <= 1e-7 * np.maximum(1.0, np.abs(r.real))].real
        vals = list(np.arctan(r)) + [math.pi / 2]
        thetas[i, : min(3, len(vals))] = vals[:3]
    cand = np.concatenate([thetas, thetas + math.pi], axis=1)  # (K, 6): the cubic is in tan θ, so θ and θ + π
    c, s = np.cos(cand)[:, :, None], np.sin(cand)[:, :, None]  # (K, 6, 1)
    # the rows c·α + s·β of the three bearings (K, 6, 3): A = their first two columns, rhs = −the third;
    # (x, y) by the 2×2 normal equations AᵀA (x, y) = Aᵀ rhs
    r0 = c * alpha[:, None, :, 0] + s * beta[:, None, :, 0]
    r1 = c * alpha[:, None, :, 1] + s * beta[:, None, :, 1]
    r2 = -(c * alpha[:, None, :, 2] + s * beta[:, None, :, 2])
    m00, m01, m11 = (r0 * r0).sum(axis=2), (r0 * r1).sum(axis=2), (r1 * r1).sum(axis=2)
    v0, v1 = (r0 * r2).sum(axis=2), (r1 * r2).sum(axis=2)
    det2 = m00 * m11 - m01 * m01
    good = np.isfinite(cand) & (np.abs(det2) > 1e-12)
    safe = np.where(good, det2, 1.0)
    x = (m11 * v0 - m01 * v1) / safe
    y = (m00 * v1 - m01 * v0) / safe
    # cheirality: each point lies ahead along its bearing, not behind
    phi = cand[:, :, None] + b[:, None, :]
    ahead = (pts[:, None, :, 0] - x[..., None]) * np.cos(phi) + (pts[:, None, :, 1] - y[..., None]) * np.sin(phi)
    good &= np.all(ahead > 0.0, axis=2)
    out = np.where(good[..., None], np.stack([x, y, np.asarray(wrap_angle(cand))], axis=-1), np.nan)
    return out[0] if single else out


def _normal(pts: np.ndarray, b: np.ndarray, w: np.ndarray, state: np.ndarray) -> tuple[np.ndarray, ...]:
    d = pts - state[:2]
    dx, dy = d[:, 0], d[:, 1]
    r2 = np.maximum(dx * dx + dy * dy, 1e-12)
    res = np.asarray(wrap_angle(np.arctan2(dy, dx) - state[2] - b), dtype=np.float64)
    jac = np.empty((len(d), 3))
    np.divide(dy, r2, out=jac[:, 0])
    np.divide(dx, r2, out=jac[:, 1])
    np.negative(jac[:, 1], out=jac[:, 1])
    jac[:, 2] = -1.0
    jw = (jac * w[:, None]).T
    return res, jac, jw @ jac, jw @ res, np.sqrt(r2)


def refine(
    points_xy_m: np.ndarray,
    bearings_rad: np.ndarray,
    initial: Pose2,
    *,
    weights: np.ndarray | None = None,
    sigma_floor_rad: float = 0.0,
    iterations: int = 20,
    jackknife: bool = False,
    groups: np.ndarray | None = None,
    compiled: bool = True,
) -> Resection | None:
    """Gauss–Newton least squares of the angular residuals from ``initial``, with the residual-variance covariance.

    Parameters
    ----------
    points_xy_m, bearings_rad
        N ≥ 3 known points (world frame, N×2, m) and the robot-frame azimuths they are seen at (rad).
    initial
        Starting pose (e.g. a minimal solution).
    weights
        Relative weights ``w_i`` (N,), 1 by default: ``σ(ε_i)² = σ² / w_i``.
    sigma_floor_rad
        Lower bound on the residual σ used in the covariance (0: none; exact bearings then give a zero covariance).
    iterations
        Gauss–Newton iterations at most (stops after a step below 1e-10).
    jackknife
        Also compute the leave-one-bearing-out jackknife covariance ``(n−1)/n Σ Δ_i Δ_iᵀ`` (``Δ_i`` the
        one-step change of the pose when bearing i is left out, ``(H − w_i J_iᵀJ_i)⁻¹ J_iᵀ w_i r_i``) and scale
        the covariance up until it covers it in every direction (by the largest generalized eigenvalue): a few
        bearings with high leverage (false matches that happen to fit, coarse ranges) make a confident but wrong
        pose that the curvature does not reveal, their influence does.
    groups
        With ``jackknife``: integer labels (N,) of bearings that are left out together (delete-a-group jackknife,
        ``(g−1)/g Σ Δ_g Δ_gᵀ``), e.g. points close together in the world, so that two false matches on one
        object cannot hide each other's leverage. None: each bearing is its own group.
    compiled
        Run the Gauss–Newton iterations, the covariance and the condition number in the compiled kernel
        :func:`factorloc.vision._kernels.resection_refine` (the default; the jackknife stays in NumPy); False: the
        NumPy reference. The same algorithm, rounded differently (sums in index order, a written-out 3×3 LU).

    Returns
    -------
    Resection or None
        None when fewer than 3 bearings or the normal matrix is singular.
    """
    pts, b = _inputs(points_xy_m, bearings_rad)
    n = len(pts)
    if n < 3:
        return None
    w = np.ones(n) if weights is None else np.asarray(weights, dtype=np.float64)
    if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w < 0.0):
        raise InputError(f"resection weights must be {n} finite values >= 0, got shape {w.shape}")
    state = np.array([initial.x, initial.y, initial.theta], dtype=np.float64)
    if compiled:
        from factorloc.vision._kernels import resection_refine

        ok, state, cov, sigma_hat, condition = resection_refine(
            pts, b, np.ascontiguousarray(w), np.ones(n, dtype=bool), state, float(sigma_floor_rad), int(iterations)
        )
        if not ok:
            return None
        sigma_hat, condition = float(sigma_hat), float(condition)
        if jackknife and n > 3:
            res, jac, h, _, _ = _normal(pts, b, w, state)
            cov = _jackknifed(cov, res, jac, h, w, n, groups)
            if cov is None:
                return None
        return Resection(
            Pose2(float(state[0]), float(state[1]), float(state[2])), cov, np.ones(n, dtype=bool), sigma_hat, condition
        )
    for _ in range(iterations):
        res, jac, h, g, _ = _normal(pts, b, w, state)
        try:
            step = np.linalg.solve(h, -g)
        except np.linalg.LinAlgError:
            return None
        if not np.all(np.isfinite(step)):
            return None
        state = state + step
        if np.max(np.abs(step)) < 1e-10:  # quadratic convergence: the state is now exact to ~1e-20
            break
    res, jac, h, g, r = _normal(pts, b, w, state)
    try:
        h_inv = np.linalg.inv(h)
    except np.linalg.LinAlgError:
        return None
    ev_h = np.linalg.eigvalsh(h)
    if not np.all(np.isfinite(h_inv)) or not ev_h[0] > 1e-12 * ev_h[-1]:
        return None  # singular in double precision: some direction of the pose is not determined
    dof = max(n - 3, 1)
    sigma_hat = float(math.sqrt(float(np.sum(w * res**2)) / dof))
    s = max(sigma_hat, sigma_floor_rad)
    r_med = float(np.median(r))
    dmat = np.diag([r_med, r_med, 1.0])
    ev = np.linalg.eigvalsh(dmat @ h @ dmat)
    condition = float(ev[-1] / ev[0]) if ev[0] > 0.0 else math.inf
    cov = s * s * h_inv
    if jackknife and n > 3:
        cov = _jackknifed(cov, res, jac, h, w, n, groups)
        if cov is None:
            return None
    pose = Pose2(float(state[0]), float(state[1]), float(wrap_angle(state[2])))
    return Resection(pose, cov, np.ones(n, dtype=bool), sigma_hat, condition)


def _jackknifed(
    cov: np.ndarray, res: np.ndarray, jac: np.ndarray, h: np.ndarray, w: np.ndarray, n: int, groups: np.ndarray | None
) -> np.ndarray | None:
    """``cov`` scaled up until it covers the delete-a-group jackknife covariance (see :func:`refine`); None when
    the covariance is not positive definite."""
    labels = np.arange(n) if groups is None else np.asarray(groups)
    if labels.shape != (n,):
        raise InputError(f"resection groups must have one label per bearing ({n}), got shape {labels.shape}")
    uniq, inverse = np.unique(labels, return_inverse=True)
    g = len(uniq)
    if g >= 2:
        wr = jac * (w * res)[:, None]  # J_iᵀ w_i r_i per bearing
        gj = np.zeros((g, 3))
        np.add.at(gj, inverse, wr)
        outer = w[:, None, None] * jac[:, :, None] * jac[:, None, :]
        gh = np.zeros((g, 3, 3))
        np.add.at(gh, inverse, outer)
        try:
            delta = np.linalg.solve(h[None] - gh, gj[:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:
            delta = np.full((g, 3), np.inf)  # leaving a group out makes the pose undetermined
        if np.all(np.isfinite(delta)):
            cov_jk = (g - 1) / g * delta.T @ delta
            try:
                chol = np.linalg.cholesky(cov)
                m = np.linalg.solve(chol, np.linalg.solve(chol, cov_jk).T)  # L⁻¹ C_jk L⁻ᵀ
                cov = cov * max(1.0, float(np.linalg.eigvalsh(0.5 * (m + m.T))[-1]))
            except np.linalg.LinAlgError:
                return None
        else:
            cov = cov * np.inf
    return cov


def ransac(
    points_xy_m: np.ndarray,
    bearings_rad: np.ndarray,
    threshold_rad: float,
    *,
    weights: np.ndarray | None = None,
    hypotheses: int = 256,
    confidence: float = 0.999,
    min_inliers: int = 3,
    sigma_floor_rad: float = 0.0,
    rivals: int = 6,
    distinct_m: float = 0.1,
    distinct_rad: float = math.radians(1.0),
    seed: int = 0,
    compiled: bool = True,
) -> Resection | None:
    """Robust resection: minimal 3-bearing hypotheses (MSAC), the best one refined on its inliers.

    Parameters
    ----------
    points_xy_m, bearings_rad
        N known points (world frame, m) and their robot-frame azimuths (rad); some pairs may be false matches.
    threshold_rad
        A bearing is an inlier of a pose when its angular residual is at most this (rad).
    weights
        Relative weights for the refinement (see :func:`refine`); the scoring ignores them.
    hypotheses
        The most random minimal sets drawn (fixed ``seed``: the same sets on every machine), in batches of 64.
    confidence
        Drawing stops after the batch where ``N ≥ log(1 − confidence) / log(1 − ε³)`` sets were drawn, ε the
        best hypothesis's inlier ratio so far (the standard RANSAC count; an all-inlier set drawn with that
        probability).
    min_inliers
        Fewest inliers for a result.
    sigma_floor_rad
        See :func:`refine`.
    rivals
        How many of the next-best hypotheses are refined (each on its own inliers) to look for a *different*
        local optimum: one further than a squared Mahalanobis distance of 11.83 (3 dof ≈ 3σ... under the result's
        covariance) gives :attr:`Resection.runner_up` its inlier count (two poses that both explain the
        bearings: a narrow view of far points, look-alike textures).
    distinct_m, distinct_rad
        ... and further than ``distinct_m`` in position or ``distinct_rad`` in heading (a rival refined on a slightly
        different inlier set lands a hair from a very precise result: the same optimum).
    seed
        Seed of the sampler.
    compiled
        Score the hypotheses, refine and search the rivals in the compiled kernels of
        :mod:`factorloc.vision._kernels` (the default); False runs the NumPy reference of the same algorithm. The
        two draw the same minimal sets; they differ in rounding only (the compiled cubic is solved in closed form,
        its 3×3 systems by a written-out LU, its sums in index order), so a pose agrees to ~1e-12 and a decision
        differs only where a hypothesis's inlier test or cost ties within rounding.

    Returns
    -------
    Resection or None
        None when fewer than ``max(3, min_inliers)`` bearings agree on any pose.
    """
    pts, b = _inputs(points_xy_m, bearings_rad)
    n = len(pts)
    if n < max(3, min_inliers):
        return None
    if not threshold_rad > 0.0:
        raise InputError(f"resection threshold_rad must be > 0, got {threshold_rad!r}")
    if not 0.0 < confidence < 1.0:
        raise InputError(f"resection confidence must be in (0, 1), got {confidence!r}")
    if compiled:
        return _ransac_compiled(
            pts,
            b,
            threshold_rad,
            weights,
            hypotheses,
            confidence,
            min_inliers,
            sigma_floor_rad,
            rivals,
            distinct_m,
            distinct_rad,
            seed,
        )
    rng = np.random.default_rng(seed)
    cands, costs, drawn = [], [], 0
    while drawn < hypotheses:  # batches of 64 minimal sets, until enough for `confidence` at the best inlier ratio
        k = min(64, hypotheses - drawn)
        sets = _minimal_sets(rng, k, n, False)
        drawn += k
        c = solve_minimal(pts[sets], b[sets]).reshape(-1, 3)
        c = c[np.all(np.isfinite(c), axis=1)]
        if not len(c):
            continue
        d = pts[None, :, :] - c[:, None, :2]
        r = np.asarray(wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - c[:, 2:3] - b[None, :]))
        cands.append(c)
        costs.append(np.minimum(r**2, threshold_rad**2).sum(axis=1))  # MSAC
        ratio = float((np.abs(r) <= threshold_rad).sum(axis=1).max()) / n
        p_good = ratio**3  # a minimal set of inliers only
        if p_good >= 1.0 or (p_good > 1e-12 and drawn >= math.log1p(-confidence) / math.log1p(-p_good)):
            break
    if not cands:
        return None
    cand, cost = np.concatenate(cands), np.concatenate(costs)
    d = pts[None, :, :] - cand[None, np.argmin(cost), :2]
    best_res = np.asarray(wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - cand[np.argmin(cost), 2] - b[None, :]))[0]
    best = int(np.argmin(cost))
    inl = np.abs(best_res) <= threshold_rad
    result = None
    for _ in range(3):  # refine on the inliers, re-select them from the refined pose, once or twice more
        if int(inl.sum()) < max(3, min_inliers):
            return None
        start = result.pose if result is not None else Pose2(*cand[best])
        w = None if weights is None else np.asarray(weights, dtype=np.float64)[inl]
        fit = refine(pts[inl], b[inl], start, weights=w, sigma_floor_rad=sigma_floor_rad, compiled=False)
        if fit is None:
            return None
        result = fit
        again = np.abs(bearing_residuals(pts, b, fit.pose)) <= threshold_rad
        if np.array_equal(again, inl):
            break
        inl = again
    assert result is not None
    p = result.pose
    runner_up = _rival_support(pts, b, weights, cand, cost, result, threshold_rad, rivals, min_inliers, distinct_m, distinct_rad)
    return Resection(p, result.covariance, inl, result.residual_sigma_rad, result.condition, runner_up)


def _minimal_sets(rng: np.random.Generator, k: int, n: int, compiled: bool) -> np.ndarray:
    """k random minimal sets of 3 distinct indices of n, the same on both paths: per set, n uniform keys drawn
    and the indices of the 3 smallest, in ascending order of key (compiled: one pass,
    :func:`factorloc.vision._kernels.three_smallest`; reference: a stable argsort)."""
    keys = rng.random((k, n))
    if n <= 3:
        return np.tile(np.arange(3), (k, 1))
    if compiled:
        from factorloc.vision._kernels import three_smallest

        return three_smallest(keys)
    return np.argsort(keys, axis=1, kind="stable")[:, :3]


def _ransac_compiled(
    pts: np.ndarray,
    b: np.ndarray,
    threshold_rad: float,
    weights: np.ndarray | None,
    hypotheses: int,
    confidence: float,
    min_inliers: int,
    sigma_floor_rad: float,
    rivals: int,
    distinct_m: float,
    distinct_rad: float,
    seed: int,
) -> Resection | None:
    """:func:`ransac` with its scoring, refinement and rival search compiled (:mod:`factorloc.vision._kernels`)."""
    from factorloc.vision import _kernels as kr

    n = len(pts)
    rng = np.random.default_rng(seed)
    cands, costs, drawn = [], [], 0
    thr = float(threshold_rad)
    while drawn < hypotheses:  # as the reference: batches of 64, the standard count at the best inlier ratio
        k = min(64, hypotheses - drawn)
        sets = _minimal_sets(rng, k, n, True)
        drawn += k
        c, cost, count, special = kr.resection_hypotheses(pts, b, sets, thr)
        if np.any(special):  # θ ≈ ±π/2 a root of the cubic (rare): the reference solver, appended after the batch
            extra = solve_minimal(pts[sets[special]], b[sets[special]]).reshape(-1, 3)
            extra = extra[np.all(np.isfinite(extra), axis=1)]
            if len(extra):
                d = pts[None, :, :] - extra[:, None, :2]
                r = np.asarray(wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - extra[:, 2:3] - b[None, :]))
                c = np.concatenate([c, extra])
                cost = np.concatenate([cost, np.minimum(r**2, thr**2).sum(axis=1)])
                count = max(count, int((np.abs(r) <= thr).sum(axis=1).max()))
        if not len(c):
            continue
        cands.append(c)
        costs.append(cost)
        p_good = (count / n) ** 3
        if p_good >= 1.0 or (p_good > 1e-12 and drawn >= math.log1p(-confidence) / math.log1p(-p_good)):
            break
    if not cands:
        return None
    cand = cands[0] if len(cands) == 1 else np.concatenate(cands)
    cost = costs[0] if len(costs) == 1 else np.concatenate(costs)
    w = np.ones(n) if weights is None else np.ascontiguousarray(weights, dtype=np.float64)
    if w.shape != (n,) or not np.all(np.isfinite(w)) or np.any(w < 0.0):
        raise InputError(f"resection weights must be {n} finite values >= 0, got shape {w.shape}")
    ok, state, cov, inl, sigma_hat, condition, runner_up = kr.resection_best(
        pts, b, w, cand, cost, thr, int(min_inliers), float(sigma_floor_rad), int(rivals), float(distinct_m), float(distinct_rad)
    )
    if not ok:
        return None
    return Resection(
        Pose2(float(state[0]), float(state[1]), float(state[2])), cov, inl, float(sigma_hat), float(condition), int(runner_up)
    )


def _rival_support(
    pts: np.ndarray,
    b: np.ndarray,
    weights: np.ndarray | None,
    cand: np.ndarray,
    cost: np.ndarray,
    result: Resection,
    threshold_rad: float,
    rivals: int,
    min_inliers: int,
    distinct_m: float,
    distinct_rad: float,
) -> int:
    """Inlier count of the best different local optimum among the next-best hypotheses (refined), else 0."""
    p = result.pose
    try:
        info = np.linalg.inv(result.covariance)
    except np.linalg.LinAlgError:
        return 0

    def d2(x: float, y: float, th: float) -> float:
        e = np.array([x - p.x, y - p.y, float(wrap_angle(th - p.theta))])
        return float(e @ info @ e)

    e = cand - np.array([p.x, p.y, p.theta])
    e[:, 2] = np.asarray(wrap_angle(e[:, 2]))
    far = np.einsum("ki,ij,kj->k", e, info, e) > 11.83
    order = np.argsort(cost)
    picks = order[far[order]][:rivals]
    if not len(picks):
        return 0
    w_all = np.ones(len(pts)) if weights is None else np.asarray(weights, dtype=np.float64)
    state = np.array(cand[picks], dtype=np.float64)  # (R, 3): the rivals, refined together

    def residuals(st: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        d = pts[None, :, :] - st[:, None, :2]
        r2 = np.maximum(d[..., 0] ** 2 + d[..., 1] ** 2, 1e-12)
        res = np.asarray(wrap_angle(np.arctan2(d[..., 1], d[..., 0]) - st[:, 2:3] - b[None, :]))
        return d, r2, res

    _, _, res = residuals(state)
    mask = np.abs(res) <= threshold_rad  # each rival's own inliers
    enough = mask.sum(axis=1) >= max(3, min_inliers)
    wm = mask * w_all[None, :]
    for _ in range(6):  # a few Gauss–Newton steps on its own inliers: where does each hypothesis lead?
        d, r2, res = residuals(state)
        jac = np.stack([d[..., 1] / r2, -d[..., 0] / r2, -np.ones_like(r2)], axis=-1)  # (R, n, 3)
        jw = jac * wm[..., None]
        h = np.matmul(jw.transpose(0, 2, 1), jac) + 1e-12 * np.eye(3)
        g = np.matmul(jw.transpose(0, 2, 1), res[..., None])[..., 0]
        try:
            state = state - np.linalg.solve(h, g[:, :, None])[:, :, 0]
        except np.linalg.LinAlgError:
            return 0
    _, _, res = residuals(state)
    support = (np.abs(res) <= threshold_rad).sum(axis=1)
    best = 0
    for k in np.flatnonzero(enough & np.all(np.isfinite(state), axis=1)):
        x, y, th = state[k]
        if d2(x, y, th) <= 11.83:
            continue  # converged back to the result: the same optimum
        if math.hypot(x - p.x, y - p.y) <= distinct_m and abs(float(wrap_angle(th - p.theta))) <= distinct_rad:
            continue  # a hair away: the same optimum, refined on a slightly different inlier set
        best = max(best, int(support[k]))
    return best


def heading_given_position(
    points_xy_m: np.ndarray, bearings_rad: np.ndarray, position_xy_m: tuple[float, float]
) -> tuple[float, float]:
    """θ from N ≥ 2 bearings to known points seen from a known position.

    Each bearing gives ``θ_i = atan2(P_i − p) − b_i``; θ is their circular mean and its σ the circular
    standard deviation over √N (rad; the spread of the θ_i, so it covers their noise but not an
    error of the given position).

    Raises
    ------
    InputError
        With fewer than two bearings.
    """
    pts, b = _inputs(points_xy_m, bearings_rad)
    if len(pts) < 2:
        raise InputError(f"heading_given_position needs >= 2 bearings, got {len(pts)}")
    d = pts - np.asarray(position_xy_m, dtype=np.float64)
    th = np.arctan2(d[:, 1], d[:, 0]) - b
    c, s = float(np.mean(np.cos(th))), float(np.mean(np.sin(th)))
    theta = math.atan2(s, c)
    resid = np.asarray(wrap_angle(th - theta))
    sigma = float(math.sqrt(float(np.sum(resid**2)) / (len(th) - 1)) / math.sqrt(len(th)))
    return float(theta), sigma

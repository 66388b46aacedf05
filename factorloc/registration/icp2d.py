"""2D point-to-line ICP with a robust kernel and a shrinking correspondence gate.

The source (query) points ``q_i`` are aligned to the target (reference)
points ``p_j`` with their line normals ``n_j`` by minimising

    E(T) = Σ_i w_i ρ( n_jᵀ (R q_i + t − p_j) )            (point-to-line, Censi 2008 "PL-ICP"; Chen & Medioni 1992)

over ``T = (t, θ)`` by iteratively reweighted Gauss–Newton, re-associating
each ``q_i`` to its nearest target point at every iteration. A step never
moves the points by more than the current gate (a trust region: with few or
nearly collinear points the Gauss–Newton step can otherwise jump metres). Pairs farther
apart than a gate ``d_k`` are rejected; the gate shrinks geometrically from
``max_correspondence_m`` to ``min_correspondence_m`` so that a seed off by a
few decimetres still converges and the final fit ignores outliers.

Parametrisation. The increment ``δ = (dx, dy, dθ)`` moves the source
*origin* by ``(dx, dy)`` and rotates the source about its origin by ``dθ``:
``q' ← R(dθ)(q' − t) + t + (dx, dy)``. The Jacobian of a residual is then
``J_i = [n_x, n_y, nᵀ·perp(q'_i − t)]`` with ``perp(v) = (−v_y, v_x)``, so
that the 3×3 Hessian ``H = Σ w_i J_iᵀJ_i`` is directly the information of
the source pose (x, y, θ) in the target frame — the covariance of the
position of the query robot needs no further Jacobian.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from factorloc.errors import InputError
from factorloc.geometry import Pose2, rot2
from factorloc.registration.kernels import Cauchy, RobustKernel
from factorloc.registration.scan2d import estimate_normals_2d

__all__ = ["IcpParams", "IcpResult", "PreparedScan", "align", "prepare_target"]


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
    normal_k, normal_radius_m
        Neighbourhood of the PCA line normals of the target.
    min_normal_quality
        Target points whose line fit quality (1 − λmin/λmax) is lower do not
        take part (corners, isolated returns).
    sigma_point_m, sigma_bearing_rad
        Noise model of a point at range ρ from its sensor (at the frame
        origin): ``σ² = sigma_point_m² + (sigma_bearing_rad·ρ)²``. A pair's
        residual variance is the sum of its two points'; the IRLS weights are
        multiplied by ``2·sigma_point_m² / σ²_pair`` (far, sparse returns weigh
        less) and the covariance estimators use ``σ²_pair``.
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
        if not 0.0 <= self.min_normal_quality < 1.0:
            raise InputError(f"IcpParams.min_normal_quality must be in [0, 1), got {self.min_normal_quality!r}")


@dataclass(frozen=True, eq=False)
class PreparedScan:
    """A target scan ready for ICP: points (M×2 m), unit line normals (M×2), their quality (M,), a KD-tree."""

    points_m: np.ndarray
    normals: np.ndarray
    quality: np.ndarray
    tree: cKDTree
    ranges_m: np.ndarray

    def __len__(self) -> int:
        return int(self.points_m.shape[0])


def prepare_target(points_m: np.ndarray, params: IcpParams = IcpParams()) -> PreparedScan:
    """Build the KD-tree and PCA line normals of a target scan (once per reference)."""
    pts = np.ascontiguousarray(np.asarray(points_m, dtype=np.float64))
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise InputError(f"target points_m must be N×2, got shape {pts.shape}")
    if len(pts) < 3:
        raise InputError(f"target scan needs >= 3 points, got {len(pts)}")
    if not np.all(np.isfinite(pts)):
        raise InputError("target points_m contains NaN or infinite values")
    tree = cKDTree(pts)
    normals, quality = estimate_normals_2d(pts, params.normal_k, params.normal_radius_m, tree)
    ranges = np.hypot(pts[:, 0], pts[:, 1])
    for a in (pts, normals, quality, ranges):
        a.setflags(write=False)
    return PreparedScan(pts, normals, quality, tree, ranges)


@dataclass(frozen=True, eq=False)
class IcpResult:
    """The outcome of :func:`align`.

    Attributes
    ----------
    T_target_source
        The source (query) pose in the target (reference) frame.
    iterations, converged
        Gauss–Newton iterations run; whether the update fell below the thresholds.
    fitness
        Fraction of source points with a target point within ``fitness_distance_m`` (Open3D's definition).
    rmse_m
        RMS point-to-line residual of the inliers.
    chamfer_m
        Symmetric truncated Chamfer distance of the aligned scans:
        ``½ (mean_i min(d(q_i, P), c) + mean_j min(d(p_j, Q), c))``.
    n_inliers
        Number of correspondences used at the solution.
    hessian
        3×3 ``Σ w_i J_iᵀ J_i`` at the solution (x, y, θ of the source in the target frame).
    jacobians, residuals_m, weights, variances_m2
        The per-correspondence ``J_i`` (K×3), residuals (K,), IRLS weights (K,) and
        pair noise variances (K,) at the solution, for the covariance
        estimators of :mod:`factorloc.registration.covariance`.
    """

    T_target_source: Pose2
    iterations: int
    converged: bool
    fitness: float
    rmse_m: float
    chamfer_m: float
    n_inliers: int
    hessian: np.ndarray
    jacobians: np.ndarray
    residuals_m: np.ndarray
    weights: np.ndarray
    variances_m2: np.ndarray


def _linearize(
    target: PreparedScan,
    q: np.ndarray,
    t: np.ndarray,
    gate: float,
    kernel: RobustKernel,
    params: IcpParams,
    var_src: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    d, j = target.tree.query(q, k=1, distance_upper_bound=gate)
    ok = np.isfinite(d)
    j = j[ok]
    ok_idx = np.nonzero(ok)[0]
    good = target.quality[j] >= params.min_normal_quality
    j = j[good]
    src_idx = ok_idx[good]
    qi = q[src_idx]
    n = target.normals[j]
    r = np.einsum("ij,ij->i", n, qi - target.points_m[j])
    v = qi - t
    J = np.column_stack([n[:, 0], n[:, 1], n[:, 1] * v[:, 0] - n[:, 0] * v[:, 1]])
    var = var_src[src_idx] + params.sigma_point_m**2 + (params.sigma_bearing_rad * target.ranges_m[j]) ** 2
    w = kernel.weight(r) * (2.0 * params.sigma_point_m**2 / var)
    return J, r, w, var


def align(
    target: PreparedScan,
    source_points_m: np.ndarray,
    T_init: Pose2,
    params: IcpParams = IcpParams(),
    kernel: RobustKernel | None = None,
) -> IcpResult:
    """Align ``source_points_m`` (N×2, source frame) to ``target`` starting from ``T_init`` (source in target frame).

    Returns the refined pose with fitness, RMSE, Chamfer distance and the
    linearisation at the solution. Never fails silently: when fewer than 3
    correspondences exist the result has ``n_inliers < 3``, ``converged =
    False`` and a zero Hessian; the caller judges reliability.
    """
    src = np.asarray(source_points_m, dtype=np.float64)
    if src.ndim != 2 or src.shape[1] != 2:
        raise InputError(f"source_points_m must be N×2, got shape {src.shape}")
    if len(src) < 3:
        raise InputError(f"source scan needs >= 3 points, got {len(src)}")
    if not isinstance(T_init, Pose2):
        raise InputError(f"T_init must be a Pose2, got {type(T_init).__name__}")
    kernel = Cauchy(0.05) if kernel is None else kernel
    rho_rms = float(np.sqrt(np.mean(np.sum(src * src, axis=1))))
    var_src = params.sigma_point_m**2 + (params.sigma_bearing_rad * np.hypot(src[:, 0], src[:, 1])) ** 2
    theta = T_init.theta
    t = np.array([T_init.x, T_init.y])
    converged = False
    it = 0
    gate = params.max_correspondence_m
    for it in range(1, params.max_iterations + 1):
        gate = max(params.min_correspondence_m, params.max_correspondence_m * params.shrink ** (it - 1))
        q = src @ rot2(theta).T + t
        J, r, w, _ = _linearize(target, q, t, gate, kernel, params, var_src)
        if len(r) < 3:
            break
        Jw = J * w[:, None]
        H = Jw.T @ J
        g = Jw.T @ r
        try:
            delta = -np.linalg.solve(H + 1e-9 * np.eye(3), g)
        except np.linalg.LinAlgError:
            break
        # trust region: no step longer than the correspondence gate (a point moves at most ~gate)
        step = math.hypot(delta[0], delta[1]) + abs(delta[2]) * rho_rms
        if step > gate:
            delta = delta * (gate / step)
        # apply: rotate about the source origin t, then translate
        theta += delta[2]
        t = t + delta[:2]
        if (
            gate <= params.min_correspondence_m
            and math.hypot(delta[0], delta[1]) < params.convergence_translation_m
            and abs(delta[2]) < params.convergence_rotation_rad
        ):
            converged = True
            break
    T = Pose2(float(t[0]), float(t[1]), float(theta))
    q = src @ rot2(T.theta).T + np.array([T.x, T.y])
    J, r, w, var = _linearize(target, q, np.array([T.x, T.y]), params.min_correspondence_m, kernel, params, var_src)
    H = (J * w[:, None]).T @ J if len(r) else np.zeros((3, 3))
    d_src, _ = target.tree.query(q, k=1)
    inl = d_src < params.fitness_distance_m
    fitness = float(np.mean(inl))
    if len(r):
        rin = r[np.abs(r) < params.fitness_distance_m]
        rmse = float(np.sqrt(np.mean(rin**2))) if len(rin) else float("inf")
    else:
        rmse = float("inf")
    d_tgt, _ = cKDTree(q).query(target.points_m, k=1)
    cap = params.chamfer_cap_m
    chamfer = 0.5 * (float(np.mean(np.minimum(d_src, cap))) + float(np.mean(np.minimum(d_tgt, cap))))
    for a in (H, J, r, w, var):
        a.setflags(write=False)
    return IcpResult(
        T_target_source=T,
        iterations=it,
        converged=converged and len(r) >= 3,
        fitness=fitness,
        rmse_m=rmse,
        chamfer_m=chamfer,
        n_inliers=int(len(r)),
        hessian=H,
        jacobians=J,
        residuals_m=r,
        weights=w,
        variances_m2=var,
    )

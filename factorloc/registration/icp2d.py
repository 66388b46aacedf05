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
from dataclasses import dataclass, field

import numpy as np

from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.registration.kernels import Cauchy, RobustKernel
from factorloc.registration.nn import LIFT_Z, KdTree2D
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


@dataclass(frozen=True, eq=False)
class PreparedScan:
    """A target scan ready for ICP: points (M×2 m), unit line normals (M×2), their quality (M,), a KD-tree
    (:class:`~factorloc.registration.nn.KdTree2D`).

    The per-target terms of the residual are precomputed once (``n_ext``:
    the normals, ``c_ext``: ``nⱼ·pⱼ``, ``range2_ext``: squared ranges), each
    with one extra row at index M — the index the KD-tree returns for "no
    neighbour within the gate" — so that one gather serves every iteration.
    ``lifted`` holds the points lifted to 3D for the KD-tree
    (:data:`~factorloc.registration.nn.LIFT_Z`), ``rows`` (2, M+1, 3) the
    coefficients that turn a lifted query point ``[q_x, q_y, 1]`` into the
    residual ``nⱼ·q − cⱼ`` (``rows[1]``) and the rotation Jacobian about the
    target origin ``n_y q_x − n_x q_y`` (``rows[0]``), and ``normals_t`` (2, M+1) the
    normals as rows: what :func:`align` gathers per association.
    """

    points_m: np.ndarray
    normals: np.ndarray
    quality: np.ndarray
    tree: KdTree2D
    ranges_m: np.ndarray
    n_ext: np.ndarray = field(init=False, repr=False)
    c_ext: np.ndarray = field(init=False, repr=False)
    range2_ext: np.ndarray = field(init=False, repr=False)
    lifted: np.ndarray = field(init=False, repr=False)
    rows: np.ndarray = field(init=False, repr=False)
    normals_t: np.ndarray = field(init=False, repr=False)
    _usable: dict = field(init=False, repr=False, default_factory=dict)

    def __post_init__(self) -> None:
        m = len(self.points_m)
        nx, ny = self.normals[:, 0], self.normals[:, 1]
        n_ext = np.zeros((m + 1, 2))
        n_ext[:m] = self.normals
        c_ext = np.zeros(m + 1)
        c_ext[:m] = nx * self.points_m[:, 0] + ny * self.points_m[:, 1]
        r2 = np.zeros(m + 1)
        r2[:m] = self.ranges_m**2
        rows = np.zeros((2, m + 1, 3))
        rows[0, :m, 0] = ny
        rows[0, :m, 1] = -nx
        rows[1, :m, :2] = self.normals
        rows[1, :, 2] = -c_ext
        normals_t = np.ascontiguousarray(n_ext.T)
        lifted = np.empty((m, 3))
        lifted[:, :2] = self.points_m
        lifted[:, 2] = LIFT_Z
        for name, a in (
            ("n_ext", n_ext),
            ("c_ext", c_ext),
            ("range2_ext", r2),
            ("lifted", lifted),
            ("rows", rows),
            ("normals_t", normals_t),
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

    def _usable_weights(self, min_normal_quality: float) -> tuple[np.ndarray, np.ndarray]:
        """:meth:`usable` and the same as 0/1 floats, cached per threshold (read-only)."""
        got = self._usable.get(min_normal_quality)
        if got is None:
            ok = self.usable(min_normal_quality)
            okf = ok.astype(np.float64)
            ok.setflags(write=False)
            okf.setflags(write=False)
            got = self._usable[min_normal_quality] = (ok, okf)
        return got


def prepare_target(points_m: np.ndarray, params: IcpParams = IcpParams()) -> PreparedScan:
    """Build the KD-tree and PCA line normals of a target scan (once per reference)."""
    pts = np.ascontiguousarray(np.asarray(points_m, dtype=np.float64))
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise InputError(f"target points_m must be N×2, got shape {pts.shape}")
    if len(pts) < 3:
        raise InputError(f"target scan needs >= 3 points, got {len(pts)}")
    if not np.isfinite(pts).all():
        raise InputError("target points_m contains NaN or infinite values")
    if pts is points_m and pts.flags.writeable:
        pts = pts.copy()  # the caller's array stays writable; ours is frozen
    tree = KdTree2D(pts)
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
    jj: np.ndarray,
    tx: float,
    ty: float,
    kernel: RobustKernel,
    params: IcpParams,
    var_src: np.ndarray | None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Jacobians (K×3), residuals (K,), IRLS weights (K,) and pair variances (K,) of the pairs ``q_i ↔ p_{jj_i}``.

    ``q`` (K×2 or K×3 lifted) are the paired source points in the target
    frame, ``jj`` their target indices, ``(tx, ty)`` the source origin.
    ``var_src`` (K,) the source points' noise variances, or None when the
    noise model is the same for every pair (``sigma_bearing_rad = 0``): the
    pair variance is then ``2·sigma_point_m²`` and the weight factor 1.
    """
    n = target.n_ext.take(jj, axis=0)
    nx, ny = n[:, 0], n[:, 1]
    qx, qy = q[:, 0], q[:, 1]
    J = np.empty((len(jj), 3))
    J[:, :2] = n
    # r = n·q − n·p ; third Jacobian column nᵀ·perp(q − t) = n_y (q_x − t_x) − n_x (q_y − t_y)
    r = nx * qx + ny * qy - target.c_ext.take(jj)
    J[:, 2] = ny * (qx - tx) - nx * (qy - ty)
    w = kernel.weight(r)
    sp2 = params.sigma_point_m**2
    if var_src is None:
        return J, r, w, np.full(len(jj), sp2 + sp2)
    var = var_src + sp2 + params.sigma_bearing_rad**2 * target.range2_ext.take(jj)
    w = w * (2.0 * sp2 / var)
    return J, r, w, var


def align(
    target: PreparedScan,
    source_points_m: np.ndarray,
    T_init: Pose2,
    params: IcpParams = IcpParams(),
    kernel: RobustKernel | None = None,
    max_correspondence_m: float | None = None,
) -> IcpResult:
    """Align ``source_points_m`` (N×2, source frame) to ``target`` starting from ``T_init`` (source in target frame).

    ``max_correspondence_m``, when given, replaces ``params.max_correspondence_m``
    (the first gate; it must be ≥ ``params.min_correspondence_m``): a
    per-call gate (e.g. from the seed's σ) without building an
    :class:`IcpParams` per call (``dataclasses.replace`` and its validation
    cost ~6 µs, as much as a Gauss–Newton iteration).

    Returns the refined pose with fitness, RMSE, Chamfer distance and the
    linearisation at the solution. Never fails silently: when fewer than 3
    correspondences exist the result has ``n_inliers < 3``, ``converged =
    False`` and a zero Hessian; the caller judges reliability. Raises
    :class:`~factorloc.errors.InputError` on a malformed or non-finite source.

    Cost. The iteration works on the source points lifted to homogeneous
    ``[x, y, 1]`` (N×3, one matrix product per iteration moves them and
    they are the KD-tree's query as they are). A search (``KdTree2D.nearest_lifted``,
    one batched small_gicp query) gathers, per source point, the target's
    residual coefficients (``PreparedScan.rows``) into a (2, N, 3) array;
    each Gauss–Newton iteration is then one ``einsum`` for the residuals and
    the rotation Jacobians, the kernel's weights and one (4×N)·(N×4) product
    for the Hessian and gradient, whose rotation is moved from the target
    origin to the source origin (``J_source = J_target · T``,
    ``T = [[1, 0, t_y], [0, 1, −t_x], [0, 0, 1]]``, ``H ← Tᵀ H T``,
    ``g ← Tᵀ g``) in scalar arithmetic. After convergence one more search
    serves the final linearisation, the fitness and the source half of the
    Chamfer distance, and a tree on the aligned source the target half.
    """
    src = np.asarray(source_points_m, dtype=np.float64)
    if src.ndim != 2 or src.shape[1] != 2:
        raise InputError(f"source_points_m must be N×2, got shape {src.shape}")
    n_src = len(src)
    if n_src < 3:
        raise InputError(f"source scan needs >= 3 points, got {n_src}")
    if not isinstance(T_init, Pose2):
        raise InputError(f"T_init must be a Pose2, got {type(T_init).__name__}")
    src_h = np.empty((n_src, 3))
    src_h[:, :2] = src
    src_h[:, 2] = LIFT_Z
    if not np.isfinite(src_h).all():
        raise InputError("source_points_m contains NaN or infinite values")
    kernel = Cauchy(0.05) if kernel is None else kernel
    usable, usable_f = target._usable_weights(params.min_normal_quality)
    tree = target.tree
    rows_t, normals_t = target.rows, target.normals_t
    m_tgt = len(target)
    src_r2 = src[:, 0] * src[:, 0] + src[:, 1] * src[:, 1]
    rho_rms = math.sqrt(float(src_r2.mean()))
    rho_max = math.sqrt(float(src_r2.max()))
    sp2 = params.sigma_point_m**2
    sb2 = params.sigma_bearing_rad**2
    var_src = None if params.sigma_bearing_rad == 0.0 else sp2 + sb2 * src_r2
    theta = T_init.theta
    tx, ty = T_init.x, T_init.y
    converged = False
    it = 0
    min_gate = params.min_correspondence_m
    max_gate, shrink, reassociate_m = params.max_correspondence_m, params.shrink, params.reassociate_m
    if max_correspondence_m is not None:
        if not max_correspondence_m >= min_gate:
            raise InputError(
                f"max_correspondence_m must be >= params.min_correspondence_m ({min_gate!r}), got {max_correspondence_m!r}"
            )
        max_gate = float(max_correspondence_m)
    conv_t, conv_r = params.convergence_translation_m, params.convergence_rotation_rad
    A = np.zeros((3, 3))  # homogeneous motion: [x, y, 1] @ A = [R (x, y) + t, 1]
    A[2, 2] = 1.0
    Z = np.empty((4, n_src))  # rows: n_x, n_y, rotation Jacobian about the target origin, residual
    rows = w_pair = None
    moved = math.inf  # largest point motion since the last association (m)
    last_gate = -1.0
    for it in range(1, params.max_iterations + 1):
        gate = max(min_gate, max_gate * shrink ** (it - 1))
        c, s = math.cos(theta), math.sin(theta)
        A[0, 0] = c
        A[0, 1] = s
        A[1, 0] = -s
        A[1, 1] = c
        A[2, 0] = tx
        A[2, 1] = ty
        q3 = src_h @ A
        if gate != last_gate or moved > reassociate_m:
            # one batched KD-tree query; every source point takes part, those without a usable target point within
            # the gate with weight 0
            d, j = tree.nearest_lifted(q3)
            w_pair = usable_f.take(j)
            w_pair *= d < gate
            if np.count_nonzero(w_pair) < 3:
                break
            if var_src is not None:
                w_pair *= 2.0 * sp2 / (var_src + sp2 + sb2 * target.range2_ext.take(j))
            rows = rows_t.take(j, axis=1)
            normals_t.take(j, axis=1, out=Z[:2])
            moved, last_gate = 0.0, gate
        np.einsum("kij,ij->ki", rows, q3, out=Z[2:])
        w = kernel.weight(Z[3])
        w *= w_pair
        (b00, b01, b02, g0), (_, b11, b12, g1), (_, _, b22, g2), _ = ((Z * w) @ Z.T).tolist()
        # rotation about the source origin t: J_source = J_target · T, T = [[1, 0, t_y], [0, 1, −t_x], [0, 0, 1]]
        h02 = b00 * ty - b01 * tx + b02
        h12 = b01 * ty - b11 * tx + b12
        h22 = h02 * ty - h12 * tx + (b02 * ty - b12 * tx + b22)
        g2 = g0 * ty - g1 * tx + g2
        h00 = b00 + 1e-9
        h11 = b11 + 1e-9
        h22 += 1e-9
        h01 = b01
        # δ = −H⁻¹ g for the symmetric 3×3 H (cofactors)
        c00 = h11 * h22 - h12 * h12
        c01 = h02 * h12 - h01 * h22
        c02 = h01 * h12 - h02 * h11
        det = h00 * c00 + h01 * c01 + h02 * c02
        if not abs(det) > 1e-300 or not math.isfinite(det):
            break
        c11 = h00 * h22 - h02 * h02
        c12 = h01 * h02 - h00 * h12
        c22 = h00 * h11 - h01 * h01
        dx = -(c00 * g0 + c01 * g1 + c02 * g2) / det
        dy = -(c01 * g0 + c11 * g1 + c12 * g2) / det
        dth = -(c02 * g0 + c12 * g1 + c22 * g2) / det
        # trust region: no step longer than the correspondence gate (a point moves at most ~gate)
        step = math.hypot(dx, dy) + abs(dth) * rho_rms
        if step > gate:
            f = gate / step
            dx, dy, dth = dx * f, dy * f, dth * f
        # apply: rotate about the source origin t, then translate
        theta += dth
        tx += dx
        ty += dy
        moved += math.hypot(dx, dy) + abs(dth) * rho_max
        if gate <= min_gate and math.hypot(dx, dy) < conv_t and abs(dth) < conv_r:
            converged = True
            break
    T = Pose2(tx, ty, theta)
    c, s = math.cos(T.theta), math.sin(T.theta)
    A[0, 0] = c
    A[0, 1] = s
    A[1, 0] = -s
    A[1, 1] = c
    A[2, 0] = tx
    A[2, 1] = ty
    q3 = src_h @ A
    cap = params.chamfer_cap_m
    d_src, j = tree.nearest_lifted(q3)
    # the final linearisation: fresh neighbours at the smallest gate
    sel = np.flatnonzero(usable.take(j) & (d_src < min_gate))
    J, r, w, var = _linearize(
        target, q3.take(sel, axis=0), j.take(sel), tx, ty, kernel, params, None if var_src is None else var_src.take(sel)
    )
    H = (J.T * w) @ J
    fitness = float(np.count_nonzero(d_src < params.fitness_distance_m)) / n_src
    rin = r[np.abs(r) < params.fitness_distance_m]
    rmse = math.sqrt(float(rin @ rin) / len(rin)) if len(rin) else math.inf
    d_tgt, _ = KdTree2D.from_lifted(q3).nearest_lifted(target.lifted)
    chamfer = 0.5 * (float(np.minimum(d_src, cap).sum()) / n_src + float(np.minimum(d_tgt, cap).sum()) / m_tgt)
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

"""Fusion without hard gates: every reliable estimate enters with a robust noise model.

The consistency gate (:mod:`factorloc.gating`) makes a yes/no decision per
estimate. Here nothing is rejected: each reliable estimate becomes the same
unary factor(s) as in :mod:`factorloc.fusion.graph`, but its Gaussian noise
model is wrapped in an M-estimator (``gtsam.noiseModel.Robust``), so that a
residual of whitened size r costs ρ(r) instead of r²/2:

* ``gaussian``: no kernel at all — plain least squares over every reliable
  estimate, the reference that shows what gates and kernels are for;
* Huber (k): quadratic up to k σ, linear beyond — an outlier still pulls, with bounded influence;
* Cauchy (k): ρ = k²/2 · log(1 + r²/k²) — the influence of a far outlier vanishes;
* GNC (Yang et al., *Graduated Non-Convexity*, RA-L 2020) with the truncated
  least squares loss, via ``gtsam.GncLMOptimizer``: starts convex and
  graduates to the non-convex loss, so it does not depend on the starting
  point; outliers end with weight 0.

Robust costs are non-convex: Huber/Cauchy are solved from each estimate's
value as a starting point and the lowest-cost solution is kept (a handful of
estimates, so this is cheap). The covariance is GTSAM's marginal at the
solution, with the robust weights of the final iteration (an outlier that was
down-weighted contributes little information).

The strategy is both a :class:`~factorloc.fusion.base.FusionStrategy`
(:meth:`fuse` on a list of estimates) and a
:class:`~factorloc.fusion.base.SequentialStrategy` without memory
(:meth:`update` takes the step reports and fuses *every* estimate its
estimator judged reliable, bypassing the consistency gate) — the evaluation
uses the latter, so that the comparison with hard gating is fair.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import gtsam
import numpy as np

from factorloc.errors import ConfigError
from factorloc.fusion.base import Fused, check_estimates, fusion_errors, mark_undetermined, undetermined_components
from factorloc.fusion.graph import POSE_KEY, GraphFusion, _body_covariance, noise_model
from factorloc.fusion.sequential import reliable_estimates
from factorloc.geometry import Pose2, rotate_covariance
from factorloc.types import Component, Estimate, Query, StepReport

KERNELS = ("gaussian", "huber", "cauchy", "gnc")

#: Default kernel widths, in σ of the whitened residual.
DEFAULT_K = {"gaussian": 1.0, "huber": 1.345, "cauchy": 2.3849, "gnc": 3.0}


def _robust(noise: gtsam.noiseModel.Base, kernel: str, k: float) -> gtsam.noiseModel.Base:
    est = gtsam.noiseModel.mEstimator.Huber.Create(k) if kernel == "huber" else gtsam.noiseModel.mEstimator.Cauchy.Create(k)
    return gtsam.noiseModel.Robust.Create(est, noise)


_noise = noise_model


def robust_factors_for(estimate: Estimate, kernel: str, k: float, key: int = POSE_KEY) -> list[gtsam.NonlinearFactor]:
    """The unary factor(s) of :func:`factorloc.fusion.graph.factors_for`, with robust noise models.

    For ``kernel="gnc"`` and ``"gaussian"`` the plain Gaussian factors are returned (GNC applies its own loss).
    """
    from factorloc.fusion.graph import factors_for

    if kernel in ("gnc", "gaussian"):
        return factors_for(estimate, key)
    v, cov = estimate.values, estimate.covariance
    if estimate.kind == "heading":
        return [gtsam.PoseRotationPrior2D(key, gtsam.Rot2(float(v[0])), _robust(_noise(cov), kernel, k))]
    if estimate.kind == "position":
        return [gtsam.PoseTranslationPrior2D(key, np.array(v[:2]), _robust(_noise(cov), kernel, k))]
    if estimate.has_cross_covariance:
        body_cov = rotate_covariance(cov, -float(v[2]))
        return [gtsam.PriorFactorPose2(key, gtsam.Pose2(*map(float, v)), _robust(_noise(body_cov), kernel, k))]
    return [
        gtsam.PoseTranslationPrior2D(key, np.array(v[:2]), _robust(_noise(cov[:2, :2]), kernel, k)),
        gtsam.PoseRotationPrior2D(key, gtsam.Rot2(float(v[2])), _robust(_noise(cov[2:, 2:]), kernel, k)),
    ]


class RobustGraphFusion:
    """Single-pose factor graph with robust kernels and no consistency gate.

    Parameters
    ----------
    kernel
        ``"huber"``, ``"cauchy"``, ``"gnc"`` (truncated least squares by graduated non-convexity)
        or ``"gaussian"`` (no kernel: least squares over every reliable estimate, no gate).
    k
        Kernel width in σ (default: 1.345 Huber, 2.385 Cauchy — 95 % efficiency —, 3 for GNC's inlier threshold).
    trust_verdicts
        True (default): :meth:`update` fuses the estimates their estimator judged reliable.
        False: every estimate the steps produced enters, the unreliable ones too (the kernel alone
        decides): e.g. a visual heading whose peak fell just short of its threshold.
    """

    def __init__(self, kernel: str = "cauchy", k: float | None = None, *, trust_verdicts: bool = True) -> None:
        if kernel not in KERNELS:
            raise ConfigError(f"RobustGraphFusion.kernel must be one of {KERNELS}, got {kernel!r}")
        kk = DEFAULT_K[kernel] if k is None else float(k)
        if not (math.isfinite(kk) and kk > 0):
            raise ConfigError(f"RobustGraphFusion.k must be a positive number of σ, got {k!r}")
        self.kernel = kernel
        self.k = kk
        self.trust_verdicts = bool(trust_verdicts)
        self.name = ("ungated_gaussian" if kernel == "gaussian" else f"robust_{kernel}") + ("" if trust_verdicts else "_all")

    # --- FusionStrategy -------------------------------------------------------------------
    def fuse(self, estimates: Sequence[Estimate]) -> Fused:
        """The robust fused pose; a GTSAM failure is a :class:`~factorloc.errors.FusionError` naming the estimates."""
        ests = check_estimates(estimates)
        with fusion_errors(ests, self.name):
            return self._fuse(ests)

    def _fuse(self, ests: list[Estimate]) -> Fused:
        undetermined = undetermined_components(ests)
        graph = gtsam.NonlinearFactorGraph()
        for e in ests:
            for f in robust_factors_for(e, self.kernel, self.k):
                graph.add(f)
        # anchor what nothing measures exactly as GraphFusion does
        _, plain_initial, _ = GraphFusion().build(ests)
        start0 = plain_initial.atPose2(POSE_KEY)
        if Component.X in undetermined:
            graph.add(gtsam.PoseTranslationPrior2D(POSE_KEY, np.array([start0.x(), start0.y()]), _noise(np.eye(2))))
        if Component.THETA in undetermined:
            graph.add(gtsam.PoseRotationPrior2D(POSE_KEY, gtsam.Rot2(start0.theta()), _noise(np.eye(1))))
        if self.kernel == "gnc":
            result, graph = self._gnc(graph, start0)
        else:
            result = self._multistart(graph, ests, start0)
        pose = Pose2.from_gtsam(result.atPose2(POSE_KEY))
        cov = mark_undetermined(rotate_covariance(_body_covariance(graph, result), pose.theta), undetermined)
        return Fused(pose, cov, undetermined)

    def _starts(self, ests: list[Estimate], start0: gtsam.Pose2) -> list[gtsam.Pose2]:
        starts = [start0]
        for e in ests:
            if e.kind == "full":
                starts.append(gtsam.Pose2(*map(float, e.values)))
            elif e.kind == "position":
                starts.append(gtsam.Pose2(float(e.values[0]), float(e.values[1]), start0.theta()))
            else:
                starts.append(gtsam.Pose2(start0.x(), start0.y(), float(e.values[0])))
        return starts

    def _multistart(self, graph: gtsam.NonlinearFactorGraph, ests: list[Estimate], start0: gtsam.Pose2) -> gtsam.Values:
        params = gtsam.GaussNewtonParams()
        params.setRelativeErrorTol(1e-12)
        params.setAbsoluteErrorTol(1e-14)
        params.setMaxIterations(50)
        best, best_err = None, math.inf
        for s in self._starts(ests, start0):
            values = gtsam.Values()
            values.insert(POSE_KEY, s)
            result = gtsam.GaussNewtonOptimizer(graph, values, params).optimize()
            err = graph.error(result)
            if err < best_err - 1e-12:
                best, best_err = result, err
        return best

    def _gnc(self, graph: gtsam.NonlinearFactorGraph, start0: gtsam.Pose2) -> tuple[gtsam.Values, gtsam.NonlinearFactorGraph]:
        """GNC-TLS solution and the graph of its inliers (for the marginal covariance)."""
        values = gtsam.Values()
        values.insert(POSE_KEY, start0)
        params = gtsam.GncLMParams()
        params.setLossType(gtsam.GncLossType.TLS)
        opt = gtsam.GncLMOptimizer(graph, values, params)
        # inlier threshold on the squared whitened residual: k² (k σ)
        opt.setInlierCostThresholds(self.k**2)
        result = opt.optimize()
        weights = np.asarray(opt.getWeights())
        kept = gtsam.NonlinearFactorGraph()
        for i in range(graph.size()):
            if weights[i] > 0.5:
                kept.add(graph.at(i))
        # the covariance of the inliers, unless dropping the outliers leaves a component unmeasured
        return result, (kept if kept.size() < graph.size() and _determined(kept, result) else graph)

    # --- SequentialStrategy (stateless) ------------------------------------------------------
    def reset(self) -> None:
        """No memory across queries."""

    def update(self, query: Query, reports: Sequence[StepReport]) -> Fused:
        """Fuse the estimates of ``reports`` their estimators judged reliable (all of them with
        ``trust_verdicts=False``); no consistency gate."""
        ests = reliable_estimates(reports) if self.trust_verdicts else [r.estimate for r in reports if r.estimate is not None]
        if not ests:
            seed = query.odometry.T_world_robot if query.odometry is not None else Pose2()
            return Fused(seed, np.diag([np.inf] * 3), (Component.X, Component.Y, Component.THETA))
        return self.fuse(ests)

    def __repr__(self) -> str:
        return f"RobustGraphFusion(kernel={self.kernel!r}, k={self.k:g}, trust_verdicts={self.trust_verdicts})"


def _determined(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> bool:
    try:
        info = np.asarray(graph.linearize(values).hessian()[0])
    except RuntimeError:
        return False
    return bool(np.linalg.matrix_rank(info) == 3)


__all__ = ["DEFAULT_K", "KERNELS", "RobustGraphFusion", "robust_factors_for"]

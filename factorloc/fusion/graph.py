"""The same fusion as a GTSAM factor graph over one ``gtsam.Pose2``.

Each estimate becomes unary factor(s) on the pose:

- heading-only → ``PoseRotationPrior2D`` (error: the angle between the pose's
  rotation and the measurement);
- position-only → ``PoseTranslationPrior2D`` (error: world-frame x, y; a full
  2×2 covariance is kept as a ``Gaussian`` noise model);
- full pose with per-axis (block-diagonal) sigmas → *both* of the above. This
  reproduces the patent's per-axis product exactly.
- full pose whose covariance couples position and heading →
  ``PriorFactorPose2``. Its error is the SE(2) logarithm in the *body* frame,
  so the world-frame covariance is first rotated into the body frame of the
  measurement. It is not the per-axis product (see the tests for a measured
  example), so it is used only for estimates that really carry such a
  joint covariance.

The optimizer starts at the most certain estimate or the closed-form product's solution,
whichever the graph scores better (from zero, headings at 179° and −179° converge to the
wrong side; from the most certain estimate alone, Gauss–Newton can stop short of the
optimum, see :func:`_start`) and runs to tight tolerances.
``gtsam.Marginals`` returns the covariance in the body frame at the solution;
its translation block (and cross terms) are rotated into the world frame.
Components that no estimate constrains would make the graph singular
(``Marginals`` raises on it): they are anchored by a unit placeholder prior
that does not touch the other components, and reported as under-determined
with infinite variance.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import gtsam
import numpy as np

from factorloc.fusion.base import (
    Fused,
    check_conditioning,
    check_estimates,
    fusion_errors,
    mark_undetermined,
    undetermined_components,
)
from factorloc.geometry import Pose2, rotate_covariance
from factorloc.types import Component, Estimate

POSE_KEY = 0


def noise_model(covariance: np.ndarray) -> gtsam.noiseModel.Base:
    """The one place noise models are built: diagonal → ``Diagonal.Sigmas``, else ``Gaussian.Covariance``.

    Built with ``smart=False``: GTSAM's "smart" constructors replace a model whose σ are within 1e-9 of 1 by
    a unit model (and equal σ by an isotropic one), which changes the variance by up to 2e-9 relative —
    whether it does depends on the last bits of σ, so a fused covariance would depend on rounding.
    """
    cov = np.asarray(covariance, dtype=np.float64)
    diag = np.diagonal(cov)
    if not np.any(cov - np.diagflat(diag)):
        return gtsam.noiseModel.Diagonal.Sigmas(np.sqrt(diag), False)
    return gtsam.noiseModel.Gaussian.Covariance(cov, False)


_noise = noise_model


def factors_for(estimate: Estimate, key: int = POSE_KEY) -> list[gtsam.NonlinearFactor]:
    """The unary factor(s) that represent ``estimate`` on pose ``key``."""
    v, cov = estimate.values, estimate.covariance
    k = len(v)  # the components are (θ), (x, y) or (x, y, θ): see Estimate
    if k == 1:
        return [gtsam.PoseRotationPrior2D(key, gtsam.Rot2(float(v[0])), _noise(cov))]
    if k == 2:
        return [gtsam.PoseTranslationPrior2D(key, v[:2].copy(), _noise(cov))]
    if cov[0, 2] != 0.0 or cov[1, 2] != 0.0:  # position and heading coupled: one joint prior, body frame
        body_cov = rotate_covariance(cov, -float(v[2]))
        return [gtsam.PriorFactorPose2(key, gtsam.Pose2(float(v[0]), float(v[1]), float(v[2])), _noise(body_cov))]
    return [
        gtsam.PoseTranslationPrior2D(key, v[:2].copy(), _noise(cov[:2, :2])),
        gtsam.PoseRotationPrior2D(key, gtsam.Rot2(float(v[2])), _noise(cov[2:, 2:])),
    ]


class GraphFusion:
    """Fusion by nonlinear least squares on a one-pose GTSAM factor graph.

    Parameters
    ----------
    optimizer
        ``"gauss_newton"`` (default: the unary priors are linear in the tangent space,
        so each Gauss–Newton step solves them exactly) or ``"levenberg_marquardt"``
        (whose damped steps stop on a relative cost decrease, ~1e-9 short of the optimum).
    max_iterations
        Iteration cap of the optimizer.
    """

    name = "graph"

    def __init__(self, optimizer: str = "gauss_newton", max_iterations: int = 100) -> None:
        if optimizer not in ("levenberg_marquardt", "gauss_newton"):
            from factorloc.errors import ConfigError

            raise ConfigError(f"GraphFusion.optimizer must be 'levenberg_marquardt' or 'gauss_newton', got {optimizer!r}")
        self.optimizer = optimizer
        self.max_iterations = int(max_iterations)

    def build(self, estimates: Sequence[Estimate]) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, tuple[Component, ...]]:
        """The factor graph, its initial values and the under-determined components."""
        ests = check_estimates(estimates)
        check_conditioning(ests)
        graph = gtsam.NonlinearFactorGraph()
        for e in ests:
            for f in factors_for(e):
                graph.add(f)
        undetermined = undetermined_components(ests)
        initial = _initial_pose(ests)
        if Component.X in undetermined:
            graph.add(gtsam.PoseTranslationPrior2D(POSE_KEY, np.array([initial.x, initial.y]), _noise(np.eye(2))))
        if Component.THETA in undetermined:
            graph.add(gtsam.PoseRotationPrior2D(POSE_KEY, gtsam.Rot2(initial.theta), _noise(np.eye(1))))
        return graph, _start(graph, ests, initial), undetermined

    def fuse(self, estimates: Sequence[Estimate]) -> Fused:
        """The fused pose; :class:`~factorloc.errors.FusionError` naming the estimates when their information is
        too ill-conditioned (:func:`~factorloc.fusion.base.check_conditioning`) or GTSAM fails."""
        with fusion_errors(list(estimates), "graph"):
            return self._fuse(estimates)

    def _fuse(self, estimates: Sequence[Estimate]) -> Fused:
        graph, initial, undetermined = self.build(estimates)
        if self.optimizer == "gauss_newton":
            params = gtsam.GaussNewtonParams()
            params.setRelativeErrorTol(1e-16)
            params.setAbsoluteErrorTol(1e-16)
            params.setMaxIterations(self.max_iterations)
            result = gtsam.GaussNewtonOptimizer(graph, initial, params).optimize()
        else:
            params = gtsam.LevenbergMarquardtParams()
            params.setRelativeErrorTol(1e-16)
            params.setAbsoluteErrorTol(1e-16)
            params.setMaxIterations(self.max_iterations)
            result = gtsam.LevenbergMarquardtOptimizer(graph, initial, params).optimize()
        pose = Pose2.from_gtsam(result.atPose2(POSE_KEY))
        body = _body_covariance(graph, result)
        if not np.isfinite(body).all():
            raise FloatingPointError(f"the marginal covariance is not finite: {body.tolist()}")
        cov = mark_undetermined(rotate_covariance(body, pose.theta), undetermined)
        return Fused(pose, cov, undetermined)

    def __repr__(self) -> str:
        return f"GraphFusion(optimizer={self.optimizer!r})"


def _body_covariance(graph: gtsam.NonlinearFactorGraph, result: gtsam.Values) -> np.ndarray:
    """The marginal covariance of the pose at the solution, in the body frame.

    ``gtsam.Marginals`` refuses information matrices it deems nearly
    indeterminate (condition ≳ 1e8 once a strongly anisotropic world-frame
    position is seen from a rotated body frame). Then the same quantity is
    computed from GTSAM's linearization at the solution: the inverse of
    ``graph.linearize(result).hessian()``.
    """
    try:
        return np.asarray(gtsam.Marginals(graph, result).marginalCovariance(POSE_KEY))
    except RuntimeError:
        information = np.asarray(graph.linearize(result).hessian()[0])
        cov = np.linalg.inv(information)
        return 0.5 * cov + 0.5 * cov.T


def _initial_pose(estimates: Sequence[Estimate]) -> Pose2:
    """The most certain position (smallest det of its 2×2 covariance) and the most certain heading."""
    best_pos, best_det = (0.0, 0.0), math.inf
    best_theta, best_var = 0.0, math.inf
    for e in estimates:
        v, c = e.values, e.covariance
        if len(v) >= 2:
            det = float(c[0, 0] * c[1, 1] - c[0, 1] * c[1, 0])
            if det < best_det:
                best_pos, best_det = (float(v[0]), float(v[1])), det
        if len(v) != 2 and c[-1, -1] < best_var:  # same choice as fusion.base.heading_anchor
            best_theta, best_var = float(v[-1]), float(c[-1, -1])
    return Pose2(best_pos[0], best_pos[1], best_theta)


def _start(graph: gtsam.NonlinearFactorGraph, estimates: Sequence[Estimate], initial: Pose2) -> gtsam.Values:
    """The start of the optimizer: :func:`_initial_pose` or the closed-form product's solution, whichever has the
    smaller graph error (the first on a tie).

    The product's solution is the optimum of the problem linearized in the world frame. From the most certain
    estimate alone, Gauss–Newton can stop short: with two headings 0 and 1 rad (σ 1 rad) and two positions, its
    first step went to θ = 0.5 rad and the translation the ``Pose2`` retraction couples to it left it 2.4 mm from
    the optimum, stopped by "error increased" (found by the equivalence property test,
    ``docs/calibration/fusion.md``). The most certain estimate stays the start where it is already the optimum
    (one estimate: error 0), so an ill-conditioned single estimate (one wall, 30 m along it) is not re-solved.
    """
    from factorloc.fusion.product import ProductFusion

    first = gtsam.Values()
    first.insert(POSE_KEY, initial.to_gtsam())
    product = ProductFusion().fuse(estimates).pose
    second = gtsam.Values()
    second.insert(POSE_KEY, Pose2(product.x, product.y, product.theta).to_gtsam())
    return second if graph.error(second) < graph.error(first) else first

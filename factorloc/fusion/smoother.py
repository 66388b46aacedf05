"""Beyond the patent: a trajectory smoother over consecutive queries (iSAM2 and fixed-lag).

One ``gtsam.Pose2`` variable per query. Consecutive poses of one odometry run
are linked by a ``BetweenFactorPose2`` holding the odometry motion
``Δ = T_odom(k-1)⁻¹ T_odom(k)`` with the noise of
:class:`~factorloc.fusion.sequential.MotionModel`; every query's gated
estimates become the same unary factors as in the single-pose graph
(:func:`factorloc.fusion.graph.factors_for`). The graph is solved incrementally
(Kaess et al., *iSAM2*, IJRR 2012): each query adds one variable and a few
factors, and :meth:`update` returns the current estimate of the newest pose
and its marginal covariance (the online, filtered answer that the evaluation
scores); :meth:`TrajectorySmoother.trajectory` gives the smoothed estimates of
all poses after the last update.

Gating: the hierarchy's reliability verdicts, then the consistency gate over
the *prediction* (the previous pose's estimate moved by Δ, as one more
full-pose estimate placed first, so that it loses ties) and the query's
estimates. When the gate rejects the prediction (kidnapped robot), the new
pose is not linked to the previous one: a new chain starts from the
measurements. Where a new odometry run starts (see
:class:`~factorloc.fusion.sequential.OdometryLink`), the odometry step's
absolute estimate is a unary factor like in the per-query fusion.

:class:`FixedLagSmoother` is the same graph in GTSAM's
``IncrementalFixedLagSmoother`` (available in the gtsam 4.3 Python wrapper):
poses older than ``lag`` queries are marginalized out, so the cost per update
stays bounded however long the run.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence

import gtsam
import numpy as np

from factorloc.errors import InputError
from factorloc.fusion.base import Fused, fusion_errors
from factorloc.fusion.graph import factors_for
from factorloc.fusion.product import ProductFusion
from factorloc.fusion.sequential import (
    ODOMETRY_STEP,
    MotionModel,
    OdometryLink,
    compose_with_covariance,
    full_pose_mask,
    gated,
    prior_estimate,
    reliable_estimates,
)
from factorloc.gating import GatingConfig
from factorloc.geometry import Pose2, rotate_covariance
from factorloc.types import Component, Query, StepReport

log = logging.getLogger(__name__)

#: σ of the placeholder prior that anchors a component nothing has measured yet (m and rad): far beyond any
#: indoor uncertainty, yet small enough for GTSAM's Cholesky on a chain linked by cm-level odometry (the
#: measurement that set it: ``docs/calibration/fusion.md``).
PLACEHOLDER_SIGMA = 30.0


def _diag_noise(sigmas: np.ndarray) -> gtsam.noiseModel.Base:
    return gtsam.noiseModel.Diagonal.Sigmas(np.asarray(sigmas, dtype=np.float64), False)  # not "smart": see noise_model


class TrajectorySmoother:
    """Incremental trajectory smoothing with iSAM2 (a :class:`~factorloc.fusion.base.SequentialStrategy`).

    Parameters
    ----------
    motion
        Noise of the odometry motion between queries.
    gating
        The consistency gate (default: the library's); ``None`` accepts every reliable estimate.
    continuous
        Whether consecutive queries share one odometry run (see
        :class:`~factorloc.fusion.sequential.OdometryLink`).
    relinearize_threshold
        iSAM2's relinearization threshold (tangent-space units).

    Attributes
    ----------
    update_seconds
        Wall time of each :meth:`update` (s), including the marginal covariance.
    chains
        Number of chains started (new odometry runs and rejected predictions).
    """

    name = "smoother"

    def __init__(
        self,
        motion: MotionModel = MotionModel(),
        gating: GatingConfig | None = GatingConfig(),
        continuous: bool = True,
        relinearize_threshold: float = 0.01,
    ) -> None:
        if not isinstance(motion, MotionModel):
            raise InputError(f"motion must be a MotionModel, got {type(motion).__name__}")
        self.motion = motion
        self.gating = gating
        self.link = OdometryLink(continuous)
        self.relinearize_threshold = float(relinearize_threshold)
        self.reset()

    # --- backend ------------------------------------------------------------------------
    def _params(self) -> gtsam.ISAM2Params:
        p = gtsam.ISAM2Params()
        p.setRelinearizeThreshold(self.relinearize_threshold)
        p.relinearizeSkip = 1
        return p

    def _new_backend(self) -> None:
        self._isam = gtsam.ISAM2(self._params())

    def _solve(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, key: int) -> tuple[Pose2, np.ndarray]:
        self._isam.update(graph, values)
        pose = Pose2.from_gtsam(self._isam.calculateEstimatePose2(key))
        body = np.asarray(self._isam.marginalCovariance(key))
        return pose, body

    # --- SequentialStrategy -------------------------------------------------------------
    def reset(self) -> None:
        self.link.reset()
        self._new_backend()
        self._k = -1
        self._last: tuple[Pose2, np.ndarray] | None = None  # estimate and world covariance of the newest pose
        self.update_seconds: list[float] = []
        self.chains = 0
        self.keys: list[int] = []

    def update(self, query: Query, reports: Sequence[StepReport]) -> Fused:
        t0 = time.perf_counter()
        delta = self.link.motion(query)
        reliable = reliable_estimates(reports)
        self._k += 1
        key = self._k
        graph = gtsam.NonlinearFactorGraph()
        values = gtsam.Values()
        linked = False
        if delta is not None and self._last is not None:
            measurements = [e for e in reliable if e.step != ODOMETRY_STEP]
            pred_pose, pred_cov = compose_with_covariance(*self._last, delta, self.motion.covariance(delta))
            prior = prior_estimate(pred_pose, pred_cov)
            accepted, rejected = gated([prior, *measurements], self.gating)
            if any(e is prior for e in rejected):
                log.debug("smoother: prediction rejected on query %r: new chain", query.id)
                accepted = [e for e in accepted if e.step != prior.step]
            else:
                accepted = [e for e in accepted if e.step != prior.step]
                graph.add(gtsam.BetweenFactorPose2(key - 1, key, delta.to_gtsam(), _diag_noise(self.motion.sigmas(delta))))
                values.insert(key, pred_pose.to_gtsam())
                linked = True
        else:
            accepted, _ = gated(reliable, self.gating)
        if not linked:
            self.chains += 1
            start = (
                ProductFusion().fuse(accepted).pose
                if accepted
                else (query.odometry.T_world_robot if query.odometry is not None else Pose2())
            )
            values.insert(key, start.to_gtsam())
            has_pos, has_head = full_pose_mask(accepted)
            if not has_pos:
                graph.add(gtsam.PoseTranslationPrior2D(key, start.translation, _diag_noise([PLACEHOLDER_SIGMA] * 2)))
            if not has_head:
                graph.add(gtsam.PoseRotationPrior2D(key, gtsam.Rot2(start.theta), _diag_noise([PLACEHOLDER_SIGMA])))
        for e in accepted:
            for f in factors_for(e, key):
                graph.add(f)
        self._add_timestamp(key)
        with fusion_errors(accepted, self.name):  # a GTSAM failure names the query's estimates; reset() before reuse
            pose, body = self._solve(graph, values, key)
        cov = rotate_covariance(body, pose.theta)
        self._last = (pose, cov)
        self.keys.append(key)
        undetermined: list[Component] = []
        if cov[0, 0] > 0.25 * PLACEHOLDER_SIGMA**2 or cov[1, 1] > 0.25 * PLACEHOLDER_SIGMA**2:
            undetermined += [Component.X, Component.Y]
        if cov[2, 2] > 0.25 * PLACEHOLDER_SIGMA**2:
            undetermined.append(Component.THETA)
        self.update_seconds.append(time.perf_counter() - t0)
        return Fused(pose, cov, tuple(undetermined))

    def _add_timestamp(self, key: int) -> None:
        """Hook for the fixed-lag variant."""

    def trajectory(self) -> list[Pose2]:
        """The smoothed estimate of every pose still in the smoother, oldest first."""
        est = self._isam.calculateEstimate()
        return [Pose2.from_gtsam(est.atPose2(k)) for k in self.keys if est.exists(k)]

    def smoothed(self) -> list[tuple[Pose2, np.ndarray]]:
        """Smoothed pose and world-frame marginal covariance of every pose (after the last update), oldest first.

        Only :class:`TrajectorySmoother` keeps every pose; the fixed-lag variant has marginalized the old ones.
        """
        est = self._isam.calculateEstimate()
        out = []
        for k in self.keys:
            if not est.exists(k):
                raise InputError(f"pose {k} was marginalized out by the fixed-lag smoother; use TrajectorySmoother")
            pose = Pose2.from_gtsam(est.atPose2(k))
            out.append((pose, rotate_covariance(np.asarray(self._isam.marginalCovariance(k)), pose.theta)))
        return out

    def __repr__(self) -> str:
        return f"{type(self).__name__}(motion={self.motion!r})"


class FixedLagSmoother(TrajectorySmoother):
    """The trajectory smoother with bounded cost: GTSAM's ``IncrementalFixedLagSmoother``.

    Poses more than ``lag`` queries older than the newest are marginalized
    out (their information stays as a prior on the rest). Other parameters
    as :class:`TrajectorySmoother`.
    """

    name = "fixed_lag"

    def __init__(
        self,
        lag: int = 5,
        motion: MotionModel = MotionModel(),
        gating: GatingConfig | None = GatingConfig(),
        continuous: bool = True,
        relinearize_threshold: float = 0.01,
    ) -> None:
        if isinstance(lag, bool) or not isinstance(lag, int) or lag < 1:
            raise InputError(f"lag must be an integer >= 1 (queries), got {lag!r}")
        self.lag = lag
        super().__init__(motion, gating, continuous, relinearize_threshold)

    def _new_backend(self) -> None:
        self._isam = gtsam.IncrementalFixedLagSmoother(float(self.lag), self._params())
        self._stamps = gtsam.FixedLagSmootherKeyTimestampMap()

    def _add_timestamp(self, key: int) -> None:
        self._stamps = gtsam.FixedLagSmootherKeyTimestampMap()
        self._stamps.insert((key, float(key)))

    def _solve(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, key: int) -> tuple[Pose2, np.ndarray]:
        self._isam.update(graph, values, self._stamps)
        pose = Pose2.from_gtsam(self._isam.calculateEstimatePose2(key))
        body = np.asarray(self._isam.marginalCovariance(key))
        return pose, body

    def __repr__(self) -> str:
        return f"FixedLagSmoother(lag={self.lag})"


__all__ = ["FixedLagSmoother", "PLACEHOLDER_SIGMA", "TrajectorySmoother"]

"""A textbook extended Kalman filter over the hierarchy's estimates.

State: the pose (x, y, θ) in the world frame with its 3×3 covariance P.

* **Predict** with the odometry motion Δ between consecutive queries
  (Thrun, Burgard & Fox, *Probabilistic Robotics*, Table 3.3 / 7.2):
  x ← x ∘ Δ,  P ← F P Fᵀ + G Q Gᵀ, with F = ∂(x∘Δ)/∂x, G = ∂(x∘Δ)/∂Δ and Q the
  :class:`~factorloc.fusion.sequential.MotionModel` covariance of Δ.
* **Correct** with every reliable estimate of the query, one after the other
  (they are independent): z = H x + v, H selecting the measured components,
  innovation y = z − H x (θ wrapped), S = H P Hᵀ + R, K = P Hᵀ S⁻¹,
  x ← x + K y, P ← (I − K H) P (I − K H)ᵀ + K R Kᵀ (Joseph form).
* **Gating** is the hierarchy's: the estimators' reliability verdicts, then
  the consistency gate (:func:`factorloc.gating.consistency_gate`) over the
  prediction (as one more full-pose estimate, placed first so that it loses
  ties) and the query's estimates. When the gate rejects the prediction's
  position or heading (the robot was kidnapped, or the odometry run was
  wrong), that block of the belief is re-initialized from the measurements.
* A new odometry run (see :class:`~factorloc.fusion.sequential.OdometryLink`)
  starts from the odometry step's absolute estimate, as the per-query fusion does.

The filter is written plainly in numpy (filterpy's ``ExtendedKalmanFilter``
would only wrap these five lines and handles neither angle wrapping nor
partial measurements).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence

import numpy as np

from factorloc.errors import InputError
from factorloc.fusion.base import Fused, indices
from factorloc.fusion.sequential import (
    ODOMETRY_STEP,
    MotionModel,
    OdometryLink,
    compose_with_covariance,
    gated,
    prior_estimate,
    reliable_estimates,
)
from factorloc.gating import GatingConfig
from factorloc.geometry import Pose2, wrap_angle
from factorloc.types import Component, Estimate, Query, StepReport

log = logging.getLogger(__name__)

#: Variance (m², rad²) given to a block of the belief that is re-initialized or unknown.
UNKNOWN_VARIANCE = 1e6


class ExtendedKalmanFilter:
    """EKF localization fed by the hierarchy's step reports (a :class:`~factorloc.fusion.base.SequentialStrategy`).

    Parameters
    ----------
    motion
        Noise of the odometry motion between queries.
    gating
        The consistency gate (default: the library's, χ² 0.999); ``GatingConfig(consistency=False)``
        fuses every reliable estimate.
    continuous
        Whether consecutive queries share one odometry run (see :class:`~factorloc.fusion.sequential.OdometryLink`).
    """

    name = "ekf"

    def __init__(
        self, motion: MotionModel = MotionModel(), gating: GatingConfig | None = GatingConfig(), continuous: bool = True
    ) -> None:
        if not isinstance(motion, MotionModel):
            raise InputError(f"motion must be a MotionModel, got {type(motion).__name__}")
        self.motion = motion
        self.gating = gating
        self.link = OdometryLink(continuous)
        self.reset()

    def reset(self) -> None:
        self.link.reset()
        self.x: np.ndarray | None = None
        self.P: np.ndarray | None = None
        self.reinitialized = 0

    # --- the two textbook steps ---------------------------------------------------------
    def predict(self, delta: Pose2) -> None:
        """x ← x ∘ Δ, P ← F P Fᵀ + G Q Gᵀ."""
        pose, P = compose_with_covariance(Pose2.from_array(self.x), self.P, delta, self.motion.covariance(delta))
        self.x, self.P = pose.as_array(), P

    def correct(self, estimate: Estimate) -> None:
        """One Kalman update with ``estimate`` (Joseph form)."""
        idx = indices(estimate)
        H = np.zeros((len(idx), 3))
        H[np.arange(len(idx)), idx] = 1.0
        y = np.array(estimate.values) - H @ self.x
        if estimate.measures(Component.THETA):
            y[-1] = wrap_angle(y[-1])
        R = np.asarray(estimate.covariance)
        S = H @ self.P @ H.T + R
        K = np.linalg.solve(S, H @ self.P).T
        self.x = self.x + K @ y
        self.x[2] = wrap_angle(self.x[2])
        IKH = np.eye(3) - K @ H
        P = IKH @ self.P @ IKH.T + K @ R @ K.T
        self.P = 0.5 * (P + P.T)

    # --- SequentialStrategy --------------------------------------------------------------
    def update(self, query: Query, reports: Sequence[StepReport]) -> Fused:
        delta = self.link.motion(query)
        reliable = reliable_estimates(reports)
        if delta is None or self.x is None:
            # a new odometry run: the hierarchy's own evidence, odometry included
            accepted, _ = gated(reliable, self.gating)
            self.x = np.zeros(3)
            self.P = np.eye(3) * UNKNOWN_VARIANCE
            for e in sorted(accepted, key=lambda e: -len(e.components)):
                self.correct(e)
        else:
            self.predict(delta)
            measurements = [e for e in reliable if e.step != ODOMETRY_STEP]
            prior = prior_estimate(Pose2.from_array(self.x), self.P)
            accepted, rejected = gated([prior, *measurements], self.gating)
            if any(e is prior for e in rejected):
                kept = next((e for e in accepted if e.step == prior.step), None)
                kept_comps = set() if kept is None else set(kept.components)
                self._forget([c for c in (Component.X, Component.THETA) if c not in kept_comps])
                self.reinitialized += 1
                log.debug("ekf: prediction rejected by the gate on query %r, re-initialized", query.id)
            for e in accepted:
                if e.step != prior.step:
                    self.correct(e)
        return self._belief()

    def _forget(self, components: list[Component]) -> None:
        """Replace the position (X) and/or heading block of the belief by an uninformative one."""
        for c in components:
            idx = [0, 1] if c is Component.X else [2]
            self.P[idx, :] = 0.0
            self.P[:, idx] = 0.0
            self.P[idx, idx] = UNKNOWN_VARIANCE

    def _belief(self) -> Fused:
        cov = np.array(self.P)
        undetermined = []
        if cov[0, 0] >= 0.5 * UNKNOWN_VARIANCE:
            undetermined += [Component.X, Component.Y]
        if cov[2, 2] >= 0.5 * UNKNOWN_VARIANCE:
            undetermined.append(Component.THETA)
        return Fused(Pose2.from_array(self.x), cov, tuple(undetermined))

    def __repr__(self) -> str:
        return f"ExtendedKalmanFilter(motion={self.motion!r})"

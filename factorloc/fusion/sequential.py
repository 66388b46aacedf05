"""What every sequential strategy shares: the odometry motion between queries and the gated evidence.

Used by the trajectory smoothers (:mod:`factorloc.fusion.smoother`), the robust fusion
(:mod:`factorloc.fusion.robust`) and the baselines (:mod:`factorloc.baselines`).

Sequential strategies (:class:`~factorloc.fusion.base.SequentialStrategy`) keep a
belief across queries. Between two queries they move it by the odometry's
relative motion ``Δ = T_odom(k-1)⁻¹ · T_odom(k)`` (robot frame of query k-1),
with the noise of :class:`MotionModel`; at each query they take the reliable
estimates of the hierarchy as measurements. The odometry step's *absolute*
estimate is not a measurement then (its information is the motion already):
it is used only where a new odometry run starts.

**When is the odometry continuous?** A dead-reckoned pose is only related to
the previous query's if both come from the same odometry run. The scenarios
of :func:`factorloc.sim.generate_scenario` (and the shipped sample) are
*independent* queries, each reached from its own exact odometry reset;
:func:`factorloc.baselines.trajectory.generate_trajectory_scenario` makes one
continuous run. :class:`OdometryLink` links every query to the previous one
(``continuous=True``, the default: a trajectory) or none (``False``: independent
queries; the sequential strategies then reduce to per-query fusion). Whether
the odometry was reset cannot be told from the queries themselves: the
simulator's σ is the second moment of systematic drift, which also *shrinks*
when the robot turns or comes back, so a "σ shrank" rule misfires. With
``continuous=True`` on independent queries, the bogus motion is usually
caught by the strategies' prediction gate, but pass ``continuous=False``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from factorloc._validate import nonnegative_float, positive_float
from factorloc.errors import InputError
from factorloc.gating import GatingConfig, consistency_gate
from factorloc.geometry import Pose2, rot2
from factorloc.types import FULL, Component, Estimate, Query, StepReport

#: Name of the odometry step, whose absolute estimate is replaced by the motion.
ODOMETRY_STEP = "odometry"


@dataclass(frozen=True)
class MotionModel:
    """Noise of the odometry's relative motion between two queries (robot frame of the first).

    For a motion of length d (m) and turn Δθ (rad):
    σ_along = σ_lateral = max(min_sigma_m, translation_ratio · d),
    σ_θ = max(min_sigma_rad, rotation_ratio · |Δθ| + heading_rad_per_m · d).
    The defaults are the simulator's drift model (5 %, 5 %, 0.02 rad/m), i.e.
    :meth:`factorloc.Odometry.from_distance`. The simulator's errors are
    systematic per run (correlated between consecutive motions); this model
    treats them as independent, so long chains are somewhat over-confident.
    """

    translation_ratio: float = 0.05
    rotation_ratio: float = 0.05
    heading_rad_per_m: float = 0.02
    min_sigma_m: float = 0.005
    min_sigma_rad: float = 0.002

    def __post_init__(self) -> None:
        for name in ("translation_ratio", "rotation_ratio", "heading_rad_per_m"):
            object.__setattr__(self, name, nonnegative_float(f"MotionModel.{name}", getattr(self, name)))
        for name in ("min_sigma_m", "min_sigma_rad"):
            object.__setattr__(self, name, positive_float(f"MotionModel.{name}", getattr(self, name)))

    def sigmas(self, delta: Pose2) -> np.ndarray:
        """(σ_x, σ_y, σ_θ) of the motion ``delta`` in the robot frame before it (m, m, rad)."""
        d = math.hypot(delta.x, delta.y)
        s = max(self.min_sigma_m, self.translation_ratio * d)
        st = max(self.min_sigma_rad, self.rotation_ratio * abs(delta.theta) + self.heading_rad_per_m * d)
        return np.array([s, s, st])

    def covariance(self, delta: Pose2) -> np.ndarray:
        """3×3 diagonal covariance of ``delta`` (robot frame, m², rad²)."""
        return np.diag(self.sigmas(delta) ** 2)


class OdometryLink:
    """Tracks the odometry from query to query and gives the motion since the previous one.

    Parameters
    ----------
    continuous
        ``True``: every query continues the previous one's odometry run (a new
        run starts only after a query without odometry); ``False``: every query
        starts a new run.
    """

    def __init__(self, continuous: bool = True) -> None:
        if not isinstance(continuous, bool):
            raise InputError(f"continuous must be True or False, got {continuous!r}")
        self.continuous = continuous
        self._last: Query | None = None

    def reset(self) -> None:
        self._last = None

    def motion(self, query: Query) -> Pose2 | None:
        """The odometry motion ``T_odom(prev)⁻¹ T_odom(query)``, or None when ``query`` starts a new run."""
        prev, self._last = self._last, query
        if prev is None or prev.odometry is None or query.odometry is None or self.continuous is False:
            return None
        return prev.odometry.T_world_robot.between(query.odometry.T_world_robot)


def reliable_estimates(reports: Sequence[StepReport]) -> list[Estimate]:
    """The estimates the estimators themselves judged reliable (before any consistency gate)."""
    for i, r in enumerate(reports):
        if not isinstance(r, StepReport):
            raise InputError(f"reports[{i}] must be a StepReport, got {type(r).__name__}")
    return [r.estimate for r in reports if r.estimate is not None and r.estimate.reliable]


def gated(estimates: Sequence[Estimate], gating: GatingConfig | None) -> tuple[list[Estimate], list[Estimate]]:
    """Apply the hierarchy's consistency gate: (accepted parts, estimates losing at least one component).

    ``gating=None`` or ``gating.consistency=False`` accepts everything.
    """
    ests = list(estimates)
    if gating is None or not gating.consistency or len(ests) < 2:
        return ests, []
    verdicts = consistency_gate(ests, gating.consistency_probability, gating.full_pose_whole, gating.heading_takes_position)
    accepted = [p for p in (v.accepted_estimate() for v in verdicts) if p is not None]
    rejected = [v.estimate for v in verdicts if not v.fully_accepted]
    return accepted, rejected


def prior_estimate(pose: Pose2, covariance: np.ndarray, name: str = "prediction") -> Estimate:
    """A belief N(pose, covariance) as a full-pose :class:`Estimate` (world frame), for the gate."""
    cov = 0.5 * (np.asarray(covariance, dtype=np.float64) + np.asarray(covariance, dtype=np.float64).T)
    low = float(np.linalg.eigvalsh(cov)[0])
    if low <= 1e-12 * float(np.max(np.diag(cov))):  # rounding in a belief mixing 1e6 and 1e-6 variances
        cov = cov + np.eye(3) * (1e-12 * float(np.max(np.diag(cov))) - min(low, 0.0))
    return Estimate(name, FULL, pose.as_array(), cov)


def compose_with_covariance(
    pose: Pose2, covariance: np.ndarray, delta: Pose2, delta_covariance: np.ndarray
) -> tuple[Pose2, np.ndarray]:
    """EKF prediction of ``pose ∘ delta`` and its world-frame covariance ``F P Fᵀ + G Q Gᵀ``.

    ``covariance`` is world-frame (x, y, θ); ``delta_covariance`` is in the
    robot frame of ``pose``. F = ∂(pose∘delta)/∂pose, G = ∂/∂delta.
    """
    c, s = math.cos(pose.theta), math.sin(pose.theta)
    F = np.eye(3)
    F[0, 2] = -s * delta.x - c * delta.y
    F[1, 2] = c * delta.x - s * delta.y
    G = np.eye(3)
    G[:2, :2] = rot2(pose.theta)
    P = F @ covariance @ F.T + G @ delta_covariance @ G.T
    return pose.compose(delta), 0.5 * (P + P.T)


def full_pose_mask(estimates: Sequence[Estimate]) -> tuple[bool, bool]:
    """Whether the estimates measure (position, heading)."""
    return any(e.measures(Component.X) for e in estimates), any(e.measures(Component.THETA) for e in estimates)


__all__ = [
    "MotionModel",
    "ODOMETRY_STEP",
    "OdometryLink",
    "compose_with_covariance",
    "full_pose_mask",
    "gated",
    "prior_estimate",
    "reliable_estimates",
]

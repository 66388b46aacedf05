"""Step 1 of the hierarchy: odometry → (x1, y1, θ1) with σ growing with distance travelled."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from factorloc.estimators.base import Hypotheses, sigma_checks
from factorloc.types import Estimate, Odometry, Query, Reference
from factorloc.verdicts import render_checks


@dataclass(frozen=True)
class OdometryConfig:
    """Reliability thresholds of the odometry step.

    The patent's example accepts x1 only when σx1 < 6 cm; the defaults are
    looser because a drifted odometry is still a good *seed* for the later
    steps and its honest σ down-weights it in the fusion.
    """

    enabled: bool = True
    max_sigma_position_m: float = 0.5
    max_sigma_heading_rad: float = 0.35


def estimate(odometry: Odometry, config: OdometryConfig = OdometryConfig()) -> Estimate:
    """The odometry as a full-pose estimate (world frame, per-axis σ), judged by the σ rule.

    Checks ``odometry.sigma_position`` (the larger of σx, σy against ``max_sigma_position_m``) and
    ``odometry.sigma_heading`` (σθ against ``max_sigma_heading_rad``), see
    :func:`~factorloc.estimators.base.sigma_checks`.
    """
    pose = odometry.T_world_robot
    est = Estimate.pose("odometry", pose, odometry.sigma_x_m, odometry.sigma_y_m, odometry.sigma_theta_rad)
    checks = sigma_checks(est, config.max_sigma_position_m, config.max_sigma_heading_rad)
    reliable = all(c.passed for c in checks)
    return est.with_verdict(reliable, render_checks(checks, only_failed=not reliable), checks)


class OdometryStep:
    """The odometry step: always first, needs ``query.odometry``."""

    name = "odometry"

    def __init__(self, config: OdometryConfig = OdometryConfig()) -> None:
        self.config = config

    def prepare(self, reference: Reference) -> Any:
        return None

    def estimate(self, prepared: Any, query: Query, hypotheses: Hypotheses) -> Estimate | None:
        if query.odometry is None:
            return None
        return estimate(query.odometry, self.config)

"""Step 1 of the hierarchy: odometry → (x1, y1, θ1) with σ growing with distance travelled."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from factorloc.estimators.base import Hypotheses
from factorloc.types import Estimate, Odometry, Query, Reference


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
    """Turn the odometry into a full-pose estimate and judge its reliability."""
    pose = odometry.T_world_robot
    sx, sy, st = odometry.sigma_x_m, odometry.sigma_y_m, odometry.sigma_theta_rad
    problems = []
    if max(sx, sy) > config.max_sigma_position_m:
        problems.append(f"σ position {max(sx, sy):.3f} m > {config.max_sigma_position_m:.3f} m")
    if st > config.max_sigma_heading_rad:
        problems.append(f"σθ {st:.3f} rad > {config.max_sigma_heading_rad:.3f} rad")
    reliable = not problems
    reason = "σ under thresholds" if reliable else "; ".join(problems)
    return Estimate.pose("odometry", pose, sx, sy, st, reliable=reliable, reason=reason)


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

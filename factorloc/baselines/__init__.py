"""Other localization strategies to compare the patent's fusion against.

All are :class:`~factorloc.fusion.base.SequentialStrategy` objects: they keep a
belief from one query to the next, move it with the odometry, and take the
hierarchy's estimates as measurements, so :func:`factorloc.evaluation.evaluate`
scores them exactly like the per-query fusion.

- :class:`ExtendedKalmanFilter` — textbook EKF, with the hierarchy's gating;
- :class:`MonteCarloLocalization` — particle filter (Thrun et al. 2001): odometry
  motion model, robust sensor model, low-variance resampling, random particles;
- :class:`MarkovGridLocalization` — histogram filter over a bounded (x, y, θ) grid (Fox et al. 1999).

:func:`generate_trajectory_scenario` renders queries along one continuous
trajectory (the simulator's own scenarios are independent queries).
"""

from typing import TYPE_CHECKING, Any

from factorloc.baselines.ekf import ExtendedKalmanFilter
from factorloc.baselines.markov import MarkovGridLocalization
from factorloc.baselines.mcl import MonteCarloLocalization
from factorloc.fusion.sequential import MotionModel, OdometryLink

if TYPE_CHECKING:  # pragma: no cover
    from factorloc.baselines.trajectory import generate_trajectory_scenario


def __getattr__(name: str) -> Any:
    """``generate_trajectory_scenario`` is imported on first use: it renders with the simulator."""
    if name == "generate_trajectory_scenario":
        from factorloc.baselines.trajectory import generate_trajectory_scenario

        return generate_trajectory_scenario
    raise AttributeError(f"module 'factorloc.baselines' has no attribute {name!r}")


__all__ = [
    "ExtendedKalmanFilter",
    "MarkovGridLocalization",
    "MonteCarloLocalization",
    "MotionModel",
    "OdometryLink",
    "generate_trajectory_scenario",
]

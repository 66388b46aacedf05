"""Every knob of the gate, in one frozen config (the ``gating:`` section of a YAML config)."""

from __future__ import annotations

import math
from dataclasses import dataclass

from factorloc.errors import ConfigError
from factorloc.estimators.icp import UNCONSTRAINED_SIGMA_M


@dataclass(frozen=True)
class GatingConfig:
    """The pipeline's gates, applied after the estimators' own reliability verdicts.

    Parameters
    ----------
    consistency
        Test each reliable estimate against the fusion of the others (:func:`~factorloc.gating.consistency_gate`):
        the parts whose squared Mahalanobis distance exceeds the χ² quantile of ``consistency_probability`` (for
        their number of components) are rejected, worst first, until all agree; between two that disagree
        equally, the earlier (cheaper, less exact) step is rejected.
    consistency_probability
        The χ² probability of that test, in (0, 1).
    full_pose_whole
        A full-pose estimate that loses its position also loses its heading before the headings are tested
        (x, y and θ are one measurement with one cause of failure: the odometry of a robot carried away and
        turned). False tests the position and heading groups independently (the patent's per-axis view).
    heading_takes_position
        The converse, off by default: a full-pose estimate that loses its heading loses its position too, and the
        positions are tested again without it (:func:`~factorloc.gating.consistency_gate`). For factors that are
        all solutions of one matcher against several places (place recognition), where a heading turned by 180°
        is another reading of the building with a position of that reading.
    seed_audit
        Reject a reliable estimate that a later step's data contradict as a seed (:func:`~factorloc.gating.seed_audit`:
        a kidnapped robot's odometry, around which the scan fits nowhere).
    drop_seeded
        With the seed audit, also reject the reliable heading-only estimates between a contradicted seed and the
        step that contradicts it that searched only a window around that seed (they verified nothing outside it).
    undetermined_sigma_m
        A fused position whose largest σ (m) reaches this is reported undetermined
        (:func:`~factorloc.gating.position_determined`): only estimates that state "unknown" along some direction
        measured it. Default: half the σ the ICP step states along a direction its scan does not constrain
        (:data:`~factorloc.estimators.icp.UNCONSTRAINED_SIGMA_M`).
    """

    consistency: bool = True
    consistency_probability: float = 0.999
    full_pose_whole: bool = True
    heading_takes_position: bool = False
    seed_audit: bool = True
    drop_seeded: bool = True
    undetermined_sigma_m: float = 0.5 * UNCONSTRAINED_SIGMA_M

    def __post_init__(self) -> None:
        if not 0.0 < self.consistency_probability < 1.0:
            raise ConfigError(f"gating.consistency_probability must be in (0, 1), got {self.consistency_probability!r}")
        if not (math.isfinite(self.undetermined_sigma_m) and self.undetermined_sigma_m > 0.0):
            raise ConfigError(f"gating.undetermined_sigma_m must be a positive length (m), got {self.undetermined_sigma_m!r}")

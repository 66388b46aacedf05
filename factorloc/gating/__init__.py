"""Gating: which estimates are fused. Small pure rules that return typed checks, and one gate.

Three kinds of rule:

- **reliability** (the patent): an estimate is fused only if its σ is below its step's threshold and the
  estimator's own criteria hold (match count, correlation peak over Ct, ICP fitness…). The estimators judge
  themselves (the σ rule is :func:`factorloc.estimators.base.sigma_checks`) and report
  :class:`~factorloc.verdicts.Check` records in ``Estimate.checks``; an unreliable estimate is neither fused
  nor passed on as a hypothesis.
- **consistency** (beyond the patent, :func:`consistency_gate`): a reliable estimate that disagrees with the
  fusion of the others is rejected, per axis group (``gate.consistency.position`` / ``.heading``).
- **seed audit** (beyond the patent, :func:`seed_audit`): a seed that a later step's data contradict is
  rejected (``gate.seed_audit``), read from the typed ``Estimate.seed`` evidence only.

After fusion, :func:`position_determined` (``gate.undetermined.position``) tells whether the fused position
is determined. :func:`gate` applies them in order; every knob is a field of :class:`GatingConfig`.
"""

from factorloc.estimators.base import sigma_checks
from factorloc.gating.config import GatingConfig
from factorloc.gating.consistency import GROUPS, Verdict, consistency_code, consistency_gate
from factorloc.gating.gate import Gated, StepRun, gate, report_reason
from factorloc.gating.rules import fixes_full_pose, measures_position, position_determined, seed_audit, seed_misfit

__all__ = [
    "GROUPS",
    "Gated",
    "GatingConfig",
    "StepRun",
    "Verdict",
    "consistency_code",
    "consistency_gate",
    "gate",
    "fixes_full_pose",
    "measures_position",
    "position_determined",
    "report_reason",
    "seed_audit",
    "seed_misfit",
    "sigma_checks",
]

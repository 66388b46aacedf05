"""The one gate: from what the steps produced on one query to the step reports and the estimates that may be fused.

:func:`gate` is called by :meth:`factorloc.Localizer.localize`, :func:`factorloc.fuse`, the evaluation runner
(re-gating stored step outputs with another fusion strategy) and the benchmarks. Order of the rules:

1. a step that raised is ``FAILED``, one without its inputs ``SKIPPED``;
2. an estimate its estimator judged unreliable is ``UNRELIABLE`` (its failed checks);
3. the seed audit (:func:`~factorloc.gating.rules.seed_audit`) marks the seeds a later step's data contradict
   ``INCONSISTENT``;
4. the consistency rule (:func:`~factorloc.gating.consistency.consistency_gate`) over the remaining reliable
   estimates: a rejected estimate is ``INCONSISTENT``, a partly accepted one is ``FUSED`` with its accepted part.

Every report carries the checks that decided it; its reason is rendered from them by :func:`report_reason`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

from factorloc.gating.config import GatingConfig
from factorloc.gating.consistency import Verdict, consistency_gate
from factorloc.gating.rules import seed_audit
from factorloc.types import Estimate, StepReport, StepStatus
from factorloc.verdicts import Check, failed, render_checks

__all__ = ["Gated", "StepRun", "gate", "report_reason"]


@dataclass(frozen=True)
class StepRun:
    """What one step produced on one query, before the gate.

    Parameters
    ----------
    name
        The step's name.
    estimate
        Its estimate, or None when its inputs were absent or it raised.
    seconds
        Its run time (s).
    error
        The error it raised (``"InputError: …"``), ``""`` when it did not.
    unusable
        Why its inputs, present, could not be used (:class:`~factorloc.errors.UnusableInputError`), ``""`` when
        they could or were absent: the report is ``SKIPPED`` with ``unusable: <why>`` and a failed
        ``<step>.inputs_usable`` check.
    """

    name: str
    estimate: Estimate | None
    seconds: float = 0.0
    error: str = ""
    unusable: str = ""

    @classmethod
    def of_report(cls, report: StepReport) -> StepRun:
        """The step output behind a report (to gate it again, e.g. with another configuration)."""
        error = report.reason if report.status is StepStatus.FAILED else ""
        return cls(report.name, report.estimate, report.seconds, error)


@dataclass(frozen=True)
class Gated:
    """The gate's result on one query: one report per step (in order) and what may be fused."""

    reports: tuple[StepReport, ...]
    accepted: tuple[Estimate, ...]


def report_reason(
    status: StepStatus, estimate: Estimate | None, checks: Sequence[Check], error: str = "", verdict: Verdict | None = None
) -> str:
    """The sentence a user reads for one step report: the one place it is composed.

    ``FAILED``: the error; ``SKIPPED``: "inputs absent", or "unusable: <why>" when its inputs were present
    but unusable (``error`` is then the why); ``UNRELIABLE``: the estimate's reason (rendered from
    its failed checks when it gave none); ``INCONSISTENT``: the gate's failed checks; ``FUSED``: the estimate's
    own reason, else the consistency ``verdict``'s (``"partly fused: …"`` when a part was rejected).
    """
    if status is StepStatus.FAILED:
        return error
    if status is StepStatus.SKIPPED:
        return f"unusable: {error}" if error else "inputs absent"
    if status is StepStatus.UNRELIABLE:
        return (estimate.reason if estimate is not None else "") or render_checks(checks) or "unreliable"
    if status is StepStatus.INCONSISTENT:
        return render_checks(checks)
    if failed(checks):
        return f"partly fused: {render_checks(checks)}"
    if estimate is not None and estimate.reason:
        return estimate.reason
    return "" if verdict is None else verdict.reason


def _report(run: StepRun, status: StepStatus, checks: Sequence[Check] = (), verdict: Verdict | None = None) -> StepReport:
    checks = tuple(checks)
    reason = report_reason(status, run.estimate, checks, run.unusable if status is StepStatus.SKIPPED else run.error, verdict)
    return StepReport(run.name, status, run.estimate if status is not StepStatus.FAILED else None, reason, run.seconds, checks)


def gate(runs: Sequence[StepRun], config: GatingConfig | None = None) -> Gated:
    """Apply the gate's rules (see the module docstring) to one query's step outputs, in hierarchy order."""
    cfg = config or GatingConfig()
    ran = [r.estimate for r in runs if r.estimate is not None]
    audited = seed_audit(ran, cfg.drop_seeded) if cfg.seed_audit else {}
    contradicted = {id(ran[i]): check for i, check in audited.items()}
    reliable = [e for e in ran if e.reliable and id(e) not in contradicted]
    verdicts = (
        consistency_gate(reliable, cfg.consistency_probability, cfg.full_pose_whole, cfg.heading_takes_position)
        if cfg.consistency
        else []
    )
    verdict_of = {id(v.estimate): v for v in verdicts}
    reports: list[StepReport] = []
    accepted: list[Estimate] = []
    for run in runs:
        est = run.estimate
        if run.error:
            reports.append(_report(run, StepStatus.FAILED))
        elif est is None:
            usable = Check.flag(f"{run.name}.inputs_usable", "inputs usable", False, failure=run.unusable)
            reports.append(_report(run, StepStatus.SKIPPED, (usable,) if run.unusable else ()))
        elif not est.reliable:
            reports.append(_report(run, StepStatus.UNRELIABLE, failed(est.checks)))
        elif id(est) in contradicted:
            reports.append(_report(run, StepStatus.INCONSISTENT, (contradicted[id(est)],)))
        else:
            verdict = verdict_of.get(id(est))
            part = est if verdict is None else verdict.accepted_estimate()
            checks = () if verdict is None else verdict.checks
            if part is None:
                reports.append(_report(run, StepStatus.INCONSISTENT, failed(checks), verdict))
            else:
                accepted.append(part)
                reports.append(_report(run, StepStatus.FUSED, checks, verdict))
    return Gated(tuple(reports), tuple(accepted))

"""Why steps were not fused, counted by rule code: the tallies behind ``gate_reasons``.

Counts come from the typed verdicts (:attr:`factorloc.types.StepReport.rule_codes` and the reports' checks),
never from the reason text; each tally keeps the range of the measured values and limits of its rule, so
that the numbers stay visible (:func:`factorloc.verdicts.render_rule` renders them).
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import dataclass

from factorloc.types import StepReport, StepStatus
from factorloc.verdicts import Check, render_rule

__all__ = ["RuleTally", "tally_reasons"]


@dataclass(frozen=True)
class RuleTally:
    """How often one rule kept one step from being fused, with what values.

    Parameters
    ----------
    status
        The step status it led to (``"unreliable"``, ``"inconsistent"``, ``"skipped"``, ``"failed"``).
    code
        The rule code (``"icp.fitness"``, ``"gate.consistency.position"``; ``"<step>.<status>"`` for a report
        without failed checks: inputs absent, an error, or an estimator that gives a reason without checks).
    count
        Number of step reports.
    text
        The rule in words with the range of its values (:func:`~factorloc.verdicts.render_rule`), or the
        first report's reason for a code without checks.
    value_min, value_max, limit_min, limit_max
        Range of the measured values and limits (NaN for flags and codes without checks), in ``unit``.
    unit
        Unit of the values (see :class:`~factorloc.verdicts.Unit`; "" without checks).
    """

    status: str
    code: str
    count: int
    text: str
    value_min: float = math.nan
    value_max: float = math.nan
    limit_min: float = math.nan
    limit_max: float = math.nan
    unit: str = ""

    @property
    def key(self) -> str:
        """``"<status>: <code>"``, the key of ``gate_reasons``."""
        return f"{self.status}: {self.code}"


def _range(values: list[float]) -> tuple[float, float]:
    finite = [v for v in values if not math.isnan(v)]
    return (min(finite), max(finite)) if finite else (math.nan, math.nan)


def tally_reasons(reports: Iterable[StepReport | None]) -> tuple[RuleTally, ...]:
    """The rules that kept the (not fused) ``reports`` from being fused, most frequent first (ties by key).

    A report with several failed checks counts once under each of their codes.
    """
    checks: dict[tuple[str, str], list[Check]] = {}
    counts: dict[tuple[str, str], int] = {}
    first_reason: dict[tuple[str, str], str] = {}
    for r in reports:
        if r is None or r.status is StepStatus.FUSED:
            continue
        failed = [c for c in r.checks if not c.passed]
        for code in r.rule_codes:
            key = (r.status.value, code)
            counts[key] = counts.get(key, 0) + 1
            first_reason.setdefault(key, r.reason or "(no reason given)")
            checks.setdefault(key, []).extend(c for c in failed if c.code == code)
    out = []
    for key, n in counts.items():
        group = checks[key]
        if group:
            vlo, vhi = _range([c.value for c in group])
            llo, lhi = _range([c.limit for c in group])
            out.append(RuleTally(key[0], key[1], n, render_rule(group), vlo, vhi, llo, lhi, group[0].unit.value))
        else:
            out.append(RuleTally(key[0], key[1], n, first_reason[key]))
    return tuple(sorted(out, key=lambda t: (-t.count, t.key)))

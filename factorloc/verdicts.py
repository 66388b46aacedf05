"""Typed verdicts: the checks a reliability rule returns, the evidence a step reports about its seed, and the
one function that renders them as the sentence a user reads.

A rule of an estimator or of the gate is a small pure function that returns a :class:`Check`: which rule
(``code``), whether it passed, what was measured and against which limit. An :class:`~factorloc.types.Estimate`
carries its step's checks; the reason shown to a user is rendered from them by :func:`render_checks`, and
anything that counts *why* steps were gated counts ``code`` values, never parses text.

Every comparison goes through :meth:`Check.at_least` / :meth:`Check.at_most`, which take a stated
``tolerance``: a quantity that is exactly at its limit in a common geometry (the smallest eigenvalue of a
rank-deficient scatter, a zero difference) is compared with a margin larger than rounding, so that the
verdict does not depend on the CPU's instruction set (see :data:`ROUNDING_TOLERANCE`).
"""

from __future__ import annotations

import math
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from enum import StrEnum

from factorloc.errors import InputError

__all__ = [
    "ROUNDING_TOLERANCE",
    "Check",
    "Comparison",
    "SeedEvidence",
    "Unit",
    "failed",
    "render_check",
    "render_checks",
    "render_rule",
]

#: Absolute tolerance (in the check's own unit) for quantities that are zero in theory in a common geometry:
#: eigenvalues of a normalized normal scatter (in [0, 0.5]) or of a covariance in m², differences of equal
#: scores. Rounding in double precision leaves them at about ±1e-15 after the few dozen operations involved;
#: 1e-9 is far above that and far below any limit a rule uses (the smallest is 0.03 for the normal scatter).
ROUNDING_TOLERANCE = 1e-9


class Comparison(StrEnum):
    """How a check's measured value is compared with its limit."""

    AT_LEAST = ">="
    AT_MOST = "<="
    FLAG = "flag"  # a condition without a number (value 1 = holds, 0 = does not; limit 1)


class Unit(StrEnum):
    """The unit of a check's value and limit (SI inside; :func:`render_check` shows radians in degrees)."""

    NONE = ""
    METRE = "m"
    RADIAN = "rad"
    FRACTION = "fraction"  # rendered in per cent
    COUNT = "count"
    SQUARED = "d²"  # a squared Mahalanobis distance (dimensionless)


@dataclass(frozen=True)
class Check:
    """The outcome of one reliability rule.

    Parameters
    ----------
    code
        Stable identifier of the rule, ``"<step>.<rule>"`` (e.g. ``"icp.fitness"``,
        ``"gate.consistency.position"``). Counts by rule use it; it never changes with the numbers.
    label
        The words a user reads for the measured quantity (``"fitness"``, ``"σ position"``).
    passed
        Whether the rule holds.
    value, limit
        The measured value and the limit it was compared with, in ``unit`` (SI: metres, radians; fractions
        in [0, 1]). NaN when the rule has no number (``Comparison.FLAG``).
    comparison
        ``AT_LEAST`` (holds when ``value ≥ limit``), ``AT_MOST`` (``value ≤ limit``) or ``FLAG``.
    unit
        See :class:`Unit`.
    note
        Optional words rendered after the comparison (why a rule was waived, what the number means).
    failure
        For a flag: the words rendered when it fails (default ``"not <label>"``), e.g. label
        ``"seed confirmed by icp"``, failure ``"seed contradicted by icp"``.
    """

    code: str
    label: str
    passed: bool
    value: float = math.nan
    limit: float = math.nan
    comparison: Comparison = Comparison.FLAG
    unit: Unit = Unit.NONE
    note: str = ""
    failure: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.code, str) or not self.code:
            raise InputError(f"Check.code must be a non-empty string, got {self.code!r}")
        # normalized only when not already of their type (the builders below pass them so: a rule's check costs
        # no conversion calls)
        if type(self.passed) is not bool:
            object.__setattr__(self, "passed", bool(self.passed))
        if type(self.value) is not float:
            object.__setattr__(self, "value", float(self.value))
        if type(self.limit) is not float:
            object.__setattr__(self, "limit", float(self.limit))
        if type(self.comparison) is not Comparison:
            object.__setattr__(self, "comparison", Comparison(self.comparison))
        if type(self.unit) is not Unit:
            object.__setattr__(self, "unit", Unit(self.unit))

    @classmethod
    def at_least(
        cls,
        code: str,
        label: str,
        value: float,
        limit: float,
        unit: Unit = Unit.NONE,
        *,
        tolerance: float = 0.0,
        note: str = "",
    ) -> Check:
        """A rule that holds when ``value ≥ limit − tolerance`` (NaN fails)."""
        value = float(value)
        return cls(code, label, value >= limit - tolerance, value, limit, Comparison.AT_LEAST, unit, note)

    @classmethod
    def at_most(
        cls,
        code: str,
        label: str,
        value: float,
        limit: float,
        unit: Unit = Unit.NONE,
        *,
        tolerance: float = 0.0,
        note: str = "",
    ) -> Check:
        """A rule that holds when ``value ≤ limit + tolerance`` (NaN fails)."""
        value = float(value)
        return cls(code, label, value <= limit + tolerance, value, limit, Comparison.AT_MOST, unit, note)

    @classmethod
    def flag(cls, code: str, label: str, holds: bool, *, note: str = "", failure: str = "") -> Check:
        """A rule without a number: ``label`` states the condition that must hold, ``failure`` what a failure means."""
        return cls(code, label, bool(holds), 1.0 if holds else 0.0, 1.0, Comparison.FLAG, Unit.NONE, note, failure)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Check):
            return NotImplemented

        def same(a: float, b: float) -> bool:
            return a == b or (math.isnan(a) and math.isnan(b))

        return (
            (self.code, self.label, self.passed, self.comparison, self.unit, self.note, self.failure)
            == (other.code, other.label, other.passed, other.comparison, other.unit, other.note, other.failure)
            and same(self.value, other.value)
            and same(self.limit, other.limit)
        )

    def __hash__(self) -> int:
        return hash((self.code, self.passed, self.comparison, self.unit))

    def waived(self, note: str) -> Check:
        """This check marked as passed, with the reason it was waived (the number stays visible)."""
        return Check(self.code, self.label, True, self.value, self.limit, self.comparison, self.unit, note, self.failure)

    def to_dict(self) -> dict[str, object]:
        """A JSON-ready dict (NaN as None)."""
        return {
            "code": self.code,
            "label": self.label,
            "passed": self.passed,
            "value": self.value if math.isfinite(self.value) else None,
            "limit": self.limit if math.isfinite(self.limit) else None,
            "comparison": self.comparison.value,
            "unit": self.unit.value,
            "note": self.note,
            "failure": self.failure,
        }

    @classmethod
    def from_dict(cls, data: dict[str, object]) -> Check:
        """Inverse of :meth:`to_dict`."""

        def num(v: object) -> float:
            return math.nan if v is None else float(v)  # type: ignore[arg-type]

        return cls(
            str(data["code"]),
            str(data.get("label", data["code"])),
            data["passed"] is True,
            num(data.get("value")),
            num(data.get("limit")),
            Comparison(str(data.get("comparison", "flag"))),
            Unit(str(data.get("unit", ""))),
            str(data.get("note", "")),
            str(data.get("failure", "")),
        )


def _number(value: float, unit: Unit) -> str:
    if not math.isfinite(value):
        return "n/a" if math.isnan(value) else ("∞" if value > 0 else "−∞")
    if unit is Unit.RADIAN:
        return f"{math.degrees(value):.3g}°"
    if unit is Unit.FRACTION:
        return f"{100.0 * value:.3g} %"
    if unit is Unit.METRE:
        return f"{value:.3g} m"
    if unit is Unit.COUNT:
        return f"{value:.0f}"
    return f"{value:.3g}"


def _holds(check: Check) -> bool:
    """Whether the value meets the limit in the check's own comparison, to :data:`ROUNDING_TOLERANCE`."""
    slack = ROUNDING_TOLERANCE * max(1.0, abs(check.limit))
    if check.comparison is Comparison.AT_LEAST:
        return check.value >= check.limit - slack
    return check.value <= check.limit + slack


def render_check(check: Check) -> str:
    """The words of one check: ``"fitness 0.21 < 0.25"``, ``"σθ 6.2° > 5°"``, or its label for a flag."""
    if check.comparison is Comparison.FLAG:
        text = check.label if check.passed else (check.failure or f"not {check.label}")
    else:
        # the operator states how the numbers compare, not whether the check passed: a waived check
        # (passed although its value misses the limit) reads "0.385 < 0.4 (waived: ...)"
        ok = check.passed if math.isnan(check.value) or math.isnan(check.limit) else _holds(check)
        if check.comparison is Comparison.AT_LEAST:
            op = "≥" if ok else "<"
        else:
            op = "≤" if ok else ">"
        text = f"{check.label} {_number(check.value, check.unit)} {op} {_number(check.limit, check.unit)}"
    return f"{text} ({check.note})" if check.note else text


def _span(values: Sequence[float], unit: Unit) -> str:
    finite = [v for v in values if not math.isnan(v)]
    if not finite:
        return _number(math.nan, unit)
    lo, hi = _number(min(finite), unit), _number(max(finite), unit)
    if lo == hi:
        return lo
    suffix = next((u for u in (" m", " %", "°") if lo.endswith(u) and hi.endswith(u)), "")
    return f"{lo.removesuffix(suffix)}–{hi}"


def render_rule(checks: Sequence[Check]) -> str:
    """One phrase for several outcomes of one rule (same code; e.g. its failures over many queries).

    ``"σθ 20.6°–29.8° > 20.1°"``: the label, the range of the measured values, the range of the limits.
    A flag gives its label (or failure words); a note is added when every check has the same one.
    """
    if not checks:
        return ""
    first = checks[0]
    notes = {c.note for c in checks}
    note = f" ({first.note})" if len(notes) == 1 and first.note else ""
    if first.comparison is Comparison.FLAG:
        text = first.label if first.passed else (first.failure or f"not {first.label}")
        return text + note
    ok = all(c.passed for c in checks)
    if first.comparison is Comparison.AT_LEAST:
        op = "≥" if ok else "<"
    else:
        op = "≤" if ok else ">"
    values = _span([c.value for c in checks], first.unit)
    limits = _span([c.limit for c in checks], first.unit)
    return f"{first.label} {values} {op} {limits}{note}"


def failed(checks: Iterable[Check]) -> tuple[Check, ...]:
    """The checks that did not pass, in order."""
    return tuple(c for c in checks if not c.passed)


def render_checks(checks: Iterable[Check], *, only_failed: bool = True) -> str:
    """The reason a user reads: the failed checks (or all, ``only_failed=False``), in order, joined by ``"; "``."""
    chosen = [c for c in checks if not (only_failed and c.passed)]
    return "; ".join(render_check(c) for c in chosen)


@dataclass(frozen=True)
class SeedEvidence:
    """What seeded a step, and what the step's own data say about that seed.

    The pipeline hands each step the reliable estimates of the earlier ones
    (:class:`~factorloc.estimators.base.Hypotheses`). A step reports here which of them it used and how,
    and, when it tested the seed against its own data, the checks of that test. The seed audit of the
    gate (:func:`factorloc.gating.seed_audit`) reads only this.

    Parameters
    ----------
    position_step, heading_step
        The step whose reliable position / heading seeded this one (None: not used).
    windowed
        The step searched only a window around the seed (a heading step's search narrowed around θ1, the
        patent's seeding): its result verifies that window and nothing outside it, so it falls with its seed.
    checks
        The step's tests of its seed against its own data (e.g. ICP: the seeded alignment does not put the
        scan into space the reference saw empty). A failed one means the data contradict the seed.
    """

    position_step: str | None = None
    heading_step: str | None = None
    windowed: bool = False
    checks: tuple[Check, ...] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        object.__setattr__(self, "checks", tuple(self.checks))
        for c in self.checks:
            if not isinstance(c, Check):
                raise InputError(f"SeedEvidence.checks must hold Check objects, got {type(c).__name__}")

    @property
    def seeded(self) -> bool:
        """Whether any earlier estimate seeded the step."""
        return self.position_step is not None or self.heading_step is not None

    @property
    def source(self) -> str:
        """What seeded the step, in words: ``"seeded by odometry"``, ``"seeded by odometry (position) and compass
        (heading)"``, ``"seeded by odometry (heading)"``; ``""`` when nothing did."""
        pos, head = self.position_step, self.heading_step
        if pos is None and head is None:
            return ""
        if pos == head or head is None:
            return f"seeded by {pos}" + ("" if pos == head else " (position)")
        if pos is None:
            return f"seeded by {head} (heading)"
        return f"seeded by {pos} (position) and {head} (heading)"

    @property
    def contradicted(self) -> bool:
        """Whether the step's data contradict its seed (a seed check failed)."""
        return any(not c.passed for c in self.checks)

    @property
    def reason(self) -> str:
        """Why the data contradict the seed ("" when they do not)."""
        return render_checks(self.checks)

    def to_dict(self) -> dict[str, object]:
        return {
            "position_step": self.position_step,
            "heading_step": self.heading_step,
            "windowed": self.windowed,
            "checks": [c.to_dict() for c in self.checks],
        }

    @classmethod
    def from_dict(cls, data: dict[str, object]) -> SeedEvidence:
        checks = data.get("checks") or []
        return cls(
            None if data.get("position_step") is None else str(data["position_step"]),
            None if data.get("heading_step") is None else str(data["heading_step"]),
            data.get("windowed") is True,
            tuple(Check.from_dict(c) for c in checks),  # type: ignore[union-attr, arg-type]
        )

"""What the fuzz suite shares: its size (``HYPOTHESIS_PROFILE``), the classification of each case and the tally.

Each generated case is classified (issue #21):

- ``typed``: a :class:`~factorloc.errors.FactorlocError` whose message names the field (or file) at fault;
- ``typed-unnamed``: a ``FactorlocError`` that does not name it (counted as a defect);
- ``escaped``: any other exception (a defect);
- ``crash``: a native crash (signal) of a case run in a subprocess (a defect);
- ``silent``: a result that is not honest — NaN, a zero σ, a σ below what the inputs support (a defect);
- ``sensible``: a result that passes the property's checks.

``make test`` runs a bounded default (``HYPOTHESIS_PROFILE`` unset: a few dozen cases per property);
``make fuzz`` sets ``HYPOTHESIS_PROFILE=fuzz`` (≥ 10,000 cases over the suite) and prints the tally.
"""

from __future__ import annotations

import os
from collections import Counter, defaultdict
from collections.abc import Callable
from typing import Any

from hypothesis import HealthCheck, settings

from factorloc.errors import FactorlocError

PROFILE = os.environ.get("HYPOTHESIS_PROFILE", "default")
OUTCOMES = ("typed", "typed-unnamed", "escaped", "crash", "silent", "sensible")
DEFECTS = ("typed-unnamed", "escaped", "crash", "silent")
TALLY: dict[str, Counter] = defaultdict(Counter)
EXAMPLES: dict[tuple[str, str], str] = {}  # (area, outcome) → the first case's description, for the report


def fuzz_settings(default: int, fuzz: int) -> settings:
    """Hypothesis settings: ``default`` examples in ``make test``, ``fuzz`` under ``HYPOTHESIS_PROFILE=fuzz``."""
    return settings(
        max_examples=fuzz if PROFILE == "fuzz" else default,
        deadline=None,
        database=None,
        derandomize=PROFILE != "fuzz",  # the default run is the same on every machine
        suppress_health_check=list(HealthCheck),
    )


class SilentResultError(AssertionError):
    """A property's check on a returned result failed: the result is silent (not honest)."""


def classify(area: str, names: tuple[str, ...], fn: Callable[[], Any], check: Callable[[Any], None] | None = None) -> str:
    """Run one case, record and return its class. ``names``: strings one of which a typed error must contain;
    ``check``: raises :class:`SilentResultError` when a returned result is not honest."""
    try:
        out = fn()
    except FactorlocError as exc:
        msg = str(exc)
        outcome = "typed" if not names or any(n in msg for n in names) else "typed-unnamed"
        detail = msg
    except Exception as exc:  # noqa: BLE001 - what the suite looks for
        outcome, detail = "escaped", f"{type(exc).__name__}: {exc}"
    else:
        outcome, detail = "sensible", ""
        if check is not None:
            try:
                check(out)
            except SilentResultError as exc:
                outcome, detail = "silent", str(exc)
    record(area, outcome, detail)
    return outcome


def record(area: str, outcome: str, detail: str = "") -> None:
    TALLY[area][outcome] += 1
    EXAMPLES.setdefault((area, outcome), " ".join(detail.split())[:160])


def assert_no_defect(outcome: str, what: str) -> None:
    """Fail the property on a defect (the case is then shrunk and reported by hypothesis)."""
    assert outcome not in DEFECTS, f"{outcome}: {what}"


def summary_lines() -> list[str]:
    """The tally as a table: one row per area, one column per outcome, and the total."""
    if not TALLY:
        return []
    head = f"{'area':28}" + "".join(f"{o:>15}" for o in OUTCOMES) + f"{'total':>9}"
    rows = [head, "-" * len(head)]
    total: Counter = Counter()
    for area in sorted(TALLY):
        c = TALLY[area]
        total.update(c)
        rows.append(f"{area:28}" + "".join(f"{c[o]:>15}" for o in OUTCOMES) + f"{sum(c.values()):>9}")
    rows.append("-" * len(head))
    rows.append(f"{'all':28}" + "".join(f"{total[o]:>15}" for o in OUTCOMES) + f"{sum(total.values()):>9}")
    defects = [(k, v) for k, v in EXAMPLES.items() if k[1] in DEFECTS]
    for (area, outcome), example in defects[:12]:
        rows.append(f"  first {outcome} in {area}: {example}")
    return rows

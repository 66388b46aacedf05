"""How the command line shows the library's results: rich tables and lines built from the typed objects.

:mod:`factorloc.cli` prints what these return; nothing here computes a figure (the evaluation, the gate and
the verdicts do). :func:`progress` is the one progress bar of the CLI.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import TYPE_CHECKING, Any

from rich import box
from rich.console import Console
from rich.markup import escape
from rich.table import Table

from factorloc.types import Component, Estimate, Localization, StepStatus

if TYPE_CHECKING:  # pragma: no cover
    from factorloc.evaluation.report import EvaluationSummary, Summary

__all__ = [
    "evaluation_steps_table",
    "evaluation_summary_table",
    "gate_reasons_text",
    "num",
    "pct",
    "pose_table",
    "progress",
    "status_text",
    "steps_table",
    "table",
]

_STATUS_STYLE = {
    "fused": "green",
    "unreliable": "yellow",
    "inconsistent": "red",
    "skipped": "dim",
    "failed": "bold red",
}


def status_text(status: StepStatus) -> str:
    """A step status as the user reads it: a step without its inputs is "absent"."""
    return "absent" if status is StepStatus.SKIPPED else status.value


# ----------------------------------------------------------------------------
# numbers
# ----------------------------------------------------------------------------
def _missing(v: Any) -> bool:
    return v is None or (isinstance(v, float) and math.isnan(v))


def num(v: Any, fmt: str, scale: float = 1.0, unit: str = "") -> str:
    """A figure formatted for a table (None or NaN: not applicable, "—"); ≥ 100 without decimals."""
    if _missing(v):
        return "[dim]—[/]"
    x = v * scale
    if fmt == "d":
        return f"{int(round(x))}{unit}"
    if fmt.endswith("f") and abs(x) >= 100.0:
        fmt = ".0f" if abs(x) < 1e5 else ".1e"
    return f"{x:{fmt}}{unit}"


def pct(v: Any) -> str:
    """A rate in per cent."""
    return num(v, ".0f", 100.0, "%")


def _graded(v: Any, text: str, good: bool) -> str:
    if _missing(v):
        return text
    return f"[green]{text}[/]" if good else f"[yellow]{text}[/]"


def table(title: str, columns: Sequence[str], caption: str | None = None, *, left: Sequence[str] = ("",)) -> Table:
    """A left-titled rich table; ``columns`` listed in ``left`` are left-justified, the others right-justified.

    With a ``caption`` the compact report style is used (simple header rule, no outer padding).
    """
    style: dict[str, Any] = {}
    if caption is not None:
        style = dict(header_style="bold", box=box.SIMPLE_HEAD, padding=(0, 1), pad_edge=False, caption_justify="left")
    t = Table(title=title, title_justify="left", caption=caption, **style)
    for col in columns:
        t.add_column(col, justify="left" if col in left else "right", no_wrap=caption is not None)
    return t


# ----------------------------------------------------------------------------
# one localization
# ----------------------------------------------------------------------------
def _fmt_estimate(est: Estimate | None) -> tuple[str, str]:
    if est is None:
        return "—", "—"
    parts, sig = [], []
    for c, v, s in zip(est.components, est.values, est.sigmas, strict=True):
        if c is Component.THETA:
            parts.append(f"θ={math.degrees(v):.2f}°")
            sig.append(f"{math.degrees(s):.2f}°")
        else:
            parts.append(f"{c.value}={v:.3f} m")
            sig.append(f"{100 * s:.1f} cm")
    return ", ".join(parts), ", ".join(sig)


def steps_table(loc: Localization, title: str = "Steps") -> Table:
    """One row per step: estimate, σ, status, reason, ms."""
    t = table(title, ("step", "estimate", "σ", "status", "reason", "ms"), left=("step", "estimate", "σ", "status", "reason"))
    for r in loc.steps:
        value, sigma = _fmt_estimate(r.estimate)
        style = _STATUS_STYLE.get(r.status.value, "")
        t.add_row(r.name, value, sigma, f"[{style}]{status_text(r.status)}[/]", escape(r.reason), f"{1000 * r.seconds:.1f}")
    return t


def pose_table(loc: Localization) -> Table:
    """The fused pose with its σ and certainty."""
    t = table(f"Fused pose ({loc.fused_with})", ("x (m)", "y (m)", "θ (°)", "σx (cm)", "σy (cm)", "σθ (°)", "P(±5 cm, ±1°)"))
    sx, sy, st = loc.sigmas
    u = {c.value for c in loc.undetermined}

    def val(name: str, text: str) -> str:
        return "[dim]undetermined[/]" if name in u else text

    t.add_row(
        val("x", f"{loc.pose.x:.4f}"),
        val("y", f"{loc.pose.y:.4f}"),
        val("theta", f"{math.degrees(loc.pose.theta):.3f}"),
        val("x", f"{100 * sx:.2f}"),
        val("y", f"{100 * sy:.2f}"),
        val("theta", f"{math.degrees(st):.3f}"),
        f"{loc.certainty(0.05, math.radians(1.0)):.3f}",
    )
    return t


# ----------------------------------------------------------------------------
# an evaluation
# ----------------------------------------------------------------------------
def evaluation_summary_table(summary: EvaluationSummary, title: str = "Fused pose") -> Table:
    """Accuracy, honesty and speed of the fused poses: all queries, those with an overlapping view, then per fault."""
    t = table(
        title,
        ("queries", "n", "pos\nRMSE", "pos\np95", "θ\nRMSE", "θ\np95", "NEES", "conf.\nwrong", "full\npose", "ms"),
        "position in cm, heading θ in degrees; NEES ≈ 3 and conf. wrong ≤ 1 % when the covariance is honest",
        left=("queries",),
    )

    def row(label: str, s: Summary, style: str = "") -> None:
        nees, wrong = s.nees_mean, s.confidently_wrong_rate
        t.add_row(
            f"[{style}]{label}[/]" if style else label,
            str(s.queries),
            num(s.position_rmse_m, ".1f", 100.0),
            num(s.position_p95_m, ".1f", 100.0),
            num(s.heading_rmse_deg, ".2f"),
            num(s.heading_p95_deg, ".2f"),
            _graded(nees, num(nees, ".2f"), 2.0 <= nees <= 4.5),
            _graded(wrong, pct(wrong), _missing(wrong) or wrong <= 0.01),
            pct(s.determined_rate),
            num(s.latency_median_ms, ".1f"),
        )

    row("all", summary.overall, "bold")
    if summary.overlapping is not None and summary.overlapping.queries:
        row("overlapping view", summary.overlapping, "bold")
    for tag, s in summary.by_fault.items():
        row("no fault" if tag == "none" else tag, s, "dim" if tag == "none" else "")
    return t


def evaluation_steps_table(summary: EvaluationSummary, title: str = "Steps") -> Table:
    """Per step: availability (reliable, fused), its own accuracy, false positives, time ("absent": never ran)."""
    t = table(
        title,
        ("step", "reliable", "fused", "pos\nRMSE", "θ\nRMSE", "false\n+", "ms\nmedian", "ms\np95"),
        "false +: called reliable but off by more than 3σ; absent: its inputs were absent on every query",
        left=("step",),
    )
    for name, s in summary.overall.steps.items():
        if s.absent:
            t.add_row(f"[bold]{name}[/]", "[dim]absent[/]", "[dim]—[/]", *(["[dim]—[/]"] * 5))
            continue
        fp = s.false_positive_count
        t.add_row(
            f"[bold]{name}[/]",
            pct(s.reliable_rate),
            pct(s.fused_rate),
            num(s.position_rmse_m, ".1f", 100.0),
            num(s.heading_rmse_deg, ".2f"),
            f"[red]{fp}[/]" if fp else "0",
            num(s.latency_median_ms, ".1f"),
            num(s.latency_p95_ms, ".1f"),
        )
    return t


def gate_reasons_text(summary: EvaluationSummary, per_step: int = 2) -> str:
    """The most frequent rules that kept each step from being fused, with the range of their values (rich markup).

    One line per rule: ``step ×count status: <rule with its numbers> (rule code)``; a step's absent inputs are
    left out (the steps table says "absent").
    """
    lines = []
    for name, s in summary.overall.steps.items():
        rules = [r for r in s.gate_rules if r.status != StepStatus.SKIPPED.value]
        for r in rules[:per_step]:
            lines.append(f"  [bold]{name}[/] [dim]×{r.count}[/] {r.status}: {escape(r.text)} [dim]({r.code})[/]")
    return "\n".join(["[bold]Why steps were not fused[/] (most frequent rules, with their values)", *lines]) if lines else ""


# ----------------------------------------------------------------------------
# progress
# ----------------------------------------------------------------------------
@contextmanager
def progress(console: Console, *, eta: bool = True, transient: bool = True) -> Iterator[Callable[[str, int, int], None]]:
    """A progress bar on ``console`` for the duration of a ``with`` block: yields ``advance(label, done, total)``.

    Each new ``label`` gets its own bar (a benchmark's stages); ``eta`` adds the time remaining.
    """
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    columns: list[Any] = [TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn()]
    if eta:
        columns.append(TimeRemainingColumn())
    with Progress(*columns, console=console, transient=transient) as bar:
        tasks: dict[str, Any] = {}

        def advance(label: str, done: int, total: int) -> None:
            if label not in tasks:
                tasks[label] = bar.add_task(label, total=total)
            bar.update(tasks[label], completed=done, total=total)

        yield advance

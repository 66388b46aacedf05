"""How ``factorloc bench`` shows a :class:`~factorloc.benchmarking.BenchReport`: one rich table per benchmark."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from rich.table import Table

from factorloc.cli_render import num, pct, table

if TYPE_CHECKING:  # pragma: no cover
    from factorloc.benchmarking.results import (
        BenchReport,
        CostCurve,
        CountComparison,
        FusionBench,
        HierarchyBench,
        IcpVsOpen3d,
        LocalizeBench,
        ModeFigures,
    )

__all__ = ["bench_tables", "hierarchy_table"]


def _ratio_text(ratio: float, prefix: str = "") -> str:
    """``"≥ 4.0×"``-style text of a ratio; "—" when there is nothing to compare (NaN)."""
    return f"{prefix}{ratio:.1f}×" if math.isfinite(ratio) else "—"


def _count_text(m: ModeFigures) -> str:
    """``"2 [0.1–2.4 %]"``: a false-positive count and the exact interval of its rate per query."""
    lo, hi = m.rate_ci
    if not (math.isfinite(lo) and math.isfinite(hi)):
        return str(m.count)
    return f"{m.count} [{100 * lo:.1f}–{100 * hi:.1f} %]"


def _fp_ratio_text(c: CountComparison) -> str:
    """The blind / seeded ratio of a count comparison and its one-sided lower bound."""
    s, b = c.seeded.count, c.blind.count
    if s == b == 0:
        return "— (none)"
    point = "∞" if s == 0 else f"{b / s:.1f}×"
    lb = c.ratio_lower_bound
    return point if not math.isfinite(lb) else f"{point} (≥ {lb:.2f}×)"


def _fused_cells(c: CountComparison) -> tuple[str, str, str]:
    return _count_text(c.seeded), _count_text(c.blind), _fp_ratio_text(c)


def _plain_counts(t: Table, h: HierarchyBench) -> None:
    """No query with truth: the plain counts, without intervals."""
    s, b = h.seeded, h.blind
    lb = "≥ " if h.false_positive_ratio_is_lower_bound else ""
    fp_ratio = _ratio_text(h.false_positive_ratio, lb)
    t.add_row("false positives of seeded steps", str(s.false_positive_count), str(b.false_positive_count), fp_ratio)
    cw_lb = "≥ " if h.confidently_wrong_ratio_is_lower_bound else ""
    t.add_row(
        "confidently-wrong fused",
        f"{s.confidently_wrong_count} ({pct(s.confidently_wrong_rate)})",
        f"{b.confidently_wrong_count} ({pct(b.confidently_wrong_rate)})",
        _ratio_text(h.confidently_wrong_ratio, cw_lb),
    )


def _queries_needed(h: HierarchyBench) -> str:
    fp = h.false_positives
    need = []
    for label, c in (("steps", fp.steps_after_first["sigma3"]), ("fused", fp.fused["sigma3"])):
        if c.shows_target:
            need.append(f"{label} shown")
        elif c.queries_needed is not None:
            q80 = c.queries_needed_power_80
            need.append(f"{label} ≈ {c.queries_needed}" + ("" if q80 is None else f" ({q80} for 80 %)"))
        else:
            need.append(f"{label}: no blind false +" if c.blind.count == 0 else f"{label}: ratio ≤ {fp.target_ratio:g}×")
    return "; ".join(need)


def hierarchy_table(h: HierarchyBench) -> Table:
    """Seeded vs blind: time, false positives with exact intervals and the ratio's lower bound, fused outcome."""
    s, b, fp = h.seeded, h.blind, h.false_positives
    t = table(
        "Hierarchy ablation: every step seeded vs every step blind",
        ("", "seeded", "blind", f"blind/seeded (≥ {100 * fp.confidence:.0f} %)"),
    )
    t.add_row("median ms / query", num(s.median_ms, ".1f"), num(b.median_ms, ".1f"), num(h.time_ratio, ".1f", 1.0, "×"))
    if not fp.queries:
        _plain_counts(t, h)
        t.add_row("fully localized", pct(s.determined_rate), pct(b.determined_rate), "")
        return t
    tol = f"> {100 * fp.tolerance_m:.0f} cm, {fp.tolerance_deg:.0f}°"
    first = next(iter(fp.steps), "the first")
    rows = (
        (f"[bold]steps after {first}: false + (> 3σ)[/]", fp.steps_after_first["sigma3"]),
        (f"steps after {first}: false + ({tol})", fp.steps_after_first["tolerance"]),
    )
    for label, c in rows:
        t.add_row(label, _count_text(c.seeded), _count_text(c.blind), _fp_ratio_text(c))
    for name, per in fp.steps.items():
        c = per["sigma3"]
        t.add_row(
            f"  {name}: > 3σ / reliable",
            f"{c.seeded.count} / {c.seeded.reliable}",
            f"{c.blind.count} / {c.blind.reliable}",
            _fp_ratio_text(c),
        )
    t.add_row("[bold]fused confidently wrong (> 3σ)[/]", *_fused_cells(fp.fused["sigma3"]))
    t.add_row(f"fused wrong ({tol})", *_fused_cells(fp.fused["tolerance"]))
    t.add_row("fully localized", pct(s.determined_rate), pct(b.determined_rate), "")
    t.add_row(f"queries to show {fp.target_ratio:g}× (now {fp.queries})", "", "", _queries_needed(h))
    return t


def _localize_table(loc: LocalizeBench, scenario: str, queries: int) -> Table:
    t = table(f"localize() on {scenario} ({queries} queries × {loc.repeats} repeats)", ("", "median ms", "p95 ms", "mean ms"))
    t.add_row("[bold]localize()[/]", num(loc.median_ms, ".1f"), num(loc.p95_ms, ".1f"), num(loc.mean_ms, ".1f"))
    for name, s in loc.steps.items():
        t.add_row(f"  {name}", num(s.median_ms, ".2f"), num(s.p95_ms, ".2f"), num(s.mean_ms, ".2f"))
    return t


def _icp_table(icp: IcpVsOpen3d) -> Table:
    t = table(f"ICP vs Open3D point-to-plane ({icp.pairs} pairs, same seeds)", ("", "ours", "Open3D", "Open3D / ours"))
    if icp.pairs:
        t.add_row(
            "median ms", num(icp.ours_median_ms, ".2f"), num(icp.open3d_median_ms, ".2f"), num(icp.time_ratio, ".2f", 1.0, "×")
        )
        t.add_row(
            "median error",
            num(icp.ours_median_error_m, ".2f", 100.0, " cm"),
            num(icp.open3d_median_error_m, ".2f", 100.0, " cm"),
            num(icp.error_ratio, ".2f", 1.0, "×"),
        )
        t.add_row(
            "median heading error",
            num(icp.ours_median_error_deg, ".3f", 1.0, "°"),
            num(icp.open3d_median_error_deg, ".3f", 1.0, "°"),
            "",
        )
        t.add_row("success (< 5 cm, < 1°)", pct(icp.ours_success_rate), pct(icp.open3d_success_rate), "")
    return t


def _fusion_table(f: FusionBench) -> Table:
    t = table(f"Fusion: GTSAM graph vs closed-form product ({f.queries} queries)", ("", "value"))
    if f.queries:
        t.add_row("graph median", num(f.graph_median_us, ".0f", 1.0, " µs"))
        t.add_row("product median", num(f.product_median_us, ".0f", 1.0, " µs"))
        t.add_row("graph / product", num(f.time_ratio, ".1f", 1.0, "×"))
        t.add_row("max |Δ position| (per-axis inputs)", num(f.max_position_diff_m, ".2e", 1.0, " m"))
        t.add_row("max |Δ heading| (per-axis inputs)", num(f.max_heading_diff_rad, ".2e", 1.0, " rad"))
        t.add_row(
            f"max |Δ position| (x–θ coupled, {f.queries_with_cross_covariance} q.)",
            num(f.max_position_diff_m_cross_covariance, ".2e", 1.0, " m"),
        )
    return t


def _cost_table(c: CostCurve) -> Table:
    steps = list(c.points[0].steps_median_ms)
    t = table(
        f"Cost curve (exponent of t ∝ scale^k: {num(c.exponent, '.2f')})",
        ("scale", "pano width", "ref cloud", "query cloud", "ms / query", *steps),
        left=(),
    )
    for p in c.points:
        t.add_row(
            f"{p.factor:g}×",
            num(p.panorama_width_px, "d"),
            num(p.reference_cloud_points, "d"),
            num(p.query_cloud_points_median, ".0f"),
            num(p.median_ms, ".1f"),
            *[num(p.steps_median_ms[n], ".2f") for n in steps],
        )
    t.add_row("[bold]exponent[/]", "", "", "", num(c.exponent, ".2f"), *[num(c.steps_exponent[n], ".2f") for n in steps])
    return t


def bench_tables(report: BenchReport) -> list[Table]:
    """The bench figures as rich tables: localize per step, seeded vs blind, ICP vs Open3D, fusion, cost curve."""
    return [
        _localize_table(report.localize, report.scenario, report.queries),
        hierarchy_table(report.hierarchy),
        _icp_table(report.icp_vs_open3d),
        _fusion_table(report.fusion),
        _cost_table(report.cost_curve),
    ]

"""The ``factorloc`` command line: the only place in the package that prints.

Every command is a thin wrapper around the public functions the notebooks
and tests use.
"""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from pathlib import Path
from typing import Annotated, Any

import typer
from rich import box
from rich.console import Console
from rich.table import Table

import factorloc
from factorloc import cli_convert, jit
from factorloc.errors import FactorlocError, InputError

app = typer.Typer(
    name="factorloc",
    help="Localize a robot in the plane by fusing odometry, a visual compass, panorama correlation and ICP in a factor graph.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
console = Console()

PACKAGE_DATA = Path(__file__).resolve().parent.parent / "data"


def _version(value: bool) -> None:
    if value:
        console.print(f"factorloc {factorloc.__version__}")
        raise typer.Exit()


@app.callback()
def main(
    version: Annotated[
        bool | None, typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = None,
) -> None:
    """factorloc command line."""
    # the first run on a machine compiles the ICP kernels: say so (on stderr, so that --json output stays clean)
    jit.on_first_compile(lambda msg: Console(stderr=True).print(f"[dim]{msg}[/]"))


# ----------------------------------------------------------------------------
# shared rendering
# ----------------------------------------------------------------------------
def _fmt_estimate(est: factorloc.Estimate | None) -> tuple[str, str]:
    if est is None:
        return "—", "—"
    parts, sig = [], []
    for c, v, s in zip(est.components, est.values, est.sigmas, strict=True):
        if c is factorloc.Component.THETA:
            parts.append(f"θ={math.degrees(v):.2f}°")
            sig.append(f"{math.degrees(s):.2f}°")
        else:
            parts.append(f"{c.value}={v:.3f} m")
            sig.append(f"{100 * s:.1f} cm")
    return ", ".join(parts), ", ".join(sig)


_STATUS_STYLE = {
    "fused": "green",
    "unreliable": "yellow",
    "inconsistent": "red",
    "skipped": "dim",
    "failed": "bold red",
}


def _table(title: str, columns: Sequence[str], caption: str | None = None, *, left: Sequence[str] = ("",)) -> Table:
    """A left-titled rich table; ``columns`` listed in ``left`` are left-justified, the others right-justified.

    With a ``caption`` the compact report style is used (simple header rule, no outer padding).
    """
    style: dict[str, Any] = {}
    if caption is not None:
        style = dict(header_style="bold", box=box.SIMPLE_HEAD, padding=(0, 1), pad_edge=False, caption_justify="left")
    table = Table(title=title, title_justify="left", caption=caption, **style)
    for col in columns:
        table.add_column(col, justify="left" if col in left else "right", no_wrap=caption is not None)
    return table


def steps_table(loc: factorloc.Localization, title: str = "Steps") -> Table:
    """A rich table: one row per step (estimate, σ, status, reason, ms)."""
    table = _table(title, ("step", "estimate", "σ", "status", "reason", "ms"), left=("step", "estimate", "σ", "status", "reason"))
    for r in loc.steps:
        value, sigma = _fmt_estimate(r.estimate)
        style = _STATUS_STYLE.get(r.status.value, "")
        table.add_row(r.name, value, sigma, f"[{style}]{r.status.value}[/]", r.reason, f"{1000 * r.seconds:.1f}")
    return table


def pose_table(loc: factorloc.Localization) -> Table:
    """The fused pose with its σ and certainty."""
    table = _table(f"Fused pose ({loc.fused_with})", ("x (m)", "y (m)", "θ (°)", "σx (cm)", "σy (cm)", "σθ (°)", "P(±5 cm, ±1°)"))
    sx, sy, st = loc.sigmas
    u = {c.value for c in loc.undetermined}

    def val(name: str, text: str) -> str:
        return "[dim]undetermined[/]" if name in u else text

    table.add_row(
        val("x", f"{loc.pose.x:.4f}"),
        val("y", f"{loc.pose.y:.4f}"),
        val("theta", f"{math.degrees(loc.pose.theta):.3f}"),
        val("x", f"{100 * sx:.2f}"),
        val("y", f"{100 * sy:.2f}"),
        val("theta", f"{math.degrees(st):.3f}"),
        f"{loc.certainty(0.05, math.radians(1.0)):.3f}",
    )
    return table


def _fail(exc: Exception) -> None:
    console.print(f"[bold red]error:[/] {exc}")
    raise typer.Exit(code=2)


def _load_estimates(path: Path) -> list[factorloc.Estimate]:
    if not path.is_file():
        raise InputError(f"estimates file not found: {path}")
    try:
        data = json.loads(path.read_text())
    except json.JSONDecodeError as exc:
        raise InputError(f"{path} is not valid JSON: {exc}") from exc
    items: Any = data.get("estimates") if isinstance(data, dict) else data
    if not isinstance(items, list):
        raise InputError(f"{path} must hold a list of estimates or an object with an 'estimates' list")
    return [factorloc.Estimate.from_dict(item) for item in items]


# ----------------------------------------------------------------------------
# fuse
# ----------------------------------------------------------------------------
@app.command()
def fuse(
    estimates: Annotated[
        Path, typer.Argument(help="JSON file: a list of estimates (step, components, values, sigmas or covariance).")
    ],
    strategy: Annotated[str, typer.Option(help="Fusion strategy: 'graph' (GTSAM) or 'product' (closed form).")] = "graph",
    json_out: Annotated[bool, typer.Option("--json", help="Print JSON instead of tables.")] = False,
) -> None:
    """Gate and fuse ready-made estimates: pose, covariance and per-estimate verdicts."""
    try:
        ests = _load_estimates(estimates)
        if strategy not in ("graph", "product"):
            raise InputError(f"--strategy must be 'graph' or 'product', got {strategy!r}")
        strat = factorloc.GraphFusion() if strategy == "graph" else factorloc.ProductFusion()
        loc = factorloc.fuse(ests, strategy=strat)
    except FactorlocError as exc:
        _fail(exc)
        return
    if json_out:
        typer.echo(json.dumps(loc.to_dict(), indent=2))
    else:
        console.print(steps_table(loc, "Estimates"))
        console.print(pose_table(loc))


# ----------------------------------------------------------------------------
# evaluate
# ----------------------------------------------------------------------------
def _num(v: Any, fmt: str, scale: float = 1.0, unit: str = "") -> str:
    """A figure of the evaluation JSON (``None`` = not applicable) formatted for a table; ≥ 100 without decimals."""
    if v is None:
        return "[dim]—[/]"
    x = v * scale
    if fmt == "d":
        return f"{int(round(x))}{unit}"
    if fmt.endswith("f") and abs(x) >= 100.0:
        fmt = ".0f" if abs(x) < 1e5 else ".1e"
    return f"{x:{fmt}}{unit}"


def _pct(v: Any) -> str:
    return _num(v, ".0f", 100.0, "%")


def _graded(v: Any, text: str, good: bool) -> str:
    if v is None:
        return text
    return f"[green]{text}[/]" if good else f"[yellow]{text}[/]"


def evaluation_summary_table(out: dict[str, Any], title: str = "Fused pose") -> Table:
    """Accuracy, honesty and speed of the fused poses: all queries, those with an overlapping view, then per fault."""
    table = _table(
        title,
        ("queries", "n", "pos\nRMSE", "pos\np95", "θ\nRMSE", "θ\np95", "NEES", "conf.\nwrong", "full\npose", "ms"),
        "position in cm, heading θ in degrees; NEES ≈ 3 and conf. wrong ≤ 1 % when the covariance is honest",
        left=("queries",),
    )

    def row(label: str, s: dict[str, Any], style: str = "") -> None:
        nees, wrong = s["nees_mean"], s["confidently_wrong_rate"]
        table.add_row(
            f"[{style}]{label}[/]" if style else label,
            str(s["queries"]),
            _num(s["position_rmse_m"], ".1f", 100.0),
            _num(s["position_p95_m"], ".1f", 100.0),
            _num(s["heading_rmse_deg"], ".2f"),
            _num(s["heading_p95_deg"], ".2f"),
            _graded(nees, _num(nees, ".2f"), nees is not None and 2.0 <= nees <= 4.5),
            _graded(wrong, _pct(wrong), (wrong or 0.0) <= 0.01),
            _pct(s["determined_rate"]),
            _num(s["latency_median_ms"], ".1f"),
        )

    row("all", out, "bold")
    if out.get("overlapping", {}).get("queries"):
        row("overlapping view", out["overlapping"], "bold")
    for tag, s in out.get("by_fault", {}).items():
        row("no fault" if tag == "none" else tag, s, "dim" if tag == "none" else "")
    return table


def _short(text: str, n: int = 60) -> str:
    return text if len(text) <= n else text[: n - 1] + "…"


def evaluation_steps_table(out: dict[str, Any], title: str = "Steps") -> Table:
    """Per step: availability (reliable, fused), its own accuracy, false positives, time, and why it was not fused."""
    table = _table(
        title,
        ("step", "reliable", "fused", "pos\nRMSE", "θ\nRMSE", "false\n+", "ms\nmedian", "ms\np95"),
        "false +: called reliable but off by more than 3σ",
        left=("step",),
    )
    for name, s in out["steps"].items():
        fp = s.get("false_positive_count", 0)
        table.add_row(
            f"[bold]{name}[/]",
            _pct(s["reliable_rate"]),
            _pct(s["fused_rate"]),
            _num(s["position_rmse_m"], ".1f", 100.0),
            _num(s["heading_rmse_deg"], ".2f"),
            f"[red]{fp}[/]" if fp else "0",
            _num(s["latency_median_ms"], ".1f"),
            _num(s["latency_p95_ms"], ".1f"),
        )
    return table


def gate_reasons_text(out: dict[str, Any], per_step: int = 2) -> str:
    """The most frequent reasons each step was not fused (rich markup, one line per reason)."""
    lines = []
    for name, s in out["steps"].items():
        for reason, count in list((s.get("gate_reasons") or {}).items())[:per_step]:
            lines.append(f"  [bold]{name}[/] [dim]×{count}[/] {_short(reason, 90)}")
    return "\n".join(["[bold]Why steps were not fused[/] (most frequent, numbers masked as #)", *lines]) if lines else ""


def _load_config(path: Path | None) -> factorloc.Config | None:
    return None if path is None else factorloc.Config.from_yaml(path)


def _run_evaluation(scenario: Any, cfg: factorloc.Config | None, label: str) -> Any:
    """Evaluate ``scenario`` with a rich progress bar; returns the EvaluationReport."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn, TimeRemainingColumn

    from factorloc.evaluation import evaluate as evaluate_scenario

    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        TimeRemainingColumn(),
        console=console,
        transient=True,
    ) as bar:
        task = bar.add_task(label, total=len(scenario.queries))
        return evaluate_scenario(scenario, config=cfg, progress=lambda done, total: bar.update(task, completed=done, total=total))


@app.command()
def evaluate(
    scenario: Annotated[Path, typer.Argument(help="Scenario directory (scenario.yaml, see docs/data-format.md).")],
    config: Annotated[Path | None, typer.Option("--config", help="YAML configuration (defaults otherwise).")] = None,
    json_out: Annotated[
        Path | None, typer.Option("--json", help="Write every figure as JSON (keys in docs/evaluation.md).")
    ] = None,
    plot: Annotated[Path | None, typer.Option("--plot", help="Write the figures (PNG) into this directory.")] = None,
) -> None:
    """Localize every query of a scenario; report accuracy, honesty, availability and speed."""
    from factorloc.datasets import load_scenario

    try:
        cfg = _load_config(config)
        scen = load_scenario(scenario)
        report = _run_evaluation(scen, cfg, f"localizing {scen.name}")
    except FactorlocError as exc:
        _fail(exc)
        return
    out = report.to_json_dict()
    console.print(evaluation_summary_table(out, f"{scen.name}: fused pose ({out['strategy']})"))
    console.print(evaluation_steps_table(out))
    reasons = gate_reasons_text(out)
    if reasons:
        console.print(reasons)
    if json_out is not None:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(out, indent=2, allow_nan=False))
        console.print(f"[dim]JSON written to {json_out}[/]")
    if plot is not None:
        from factorloc.plotting import save_report_figures

        paths = save_report_figures(report, plot)
        console.print(f"[dim]figures written to {plot}: {', '.join(p.name for p in paths)}[/]")


# ----------------------------------------------------------------------------
# bench
# ----------------------------------------------------------------------------
def _ratio_text(ratio: float | None, prefix: str = "") -> str:
    """``"≥ 4.0×"``-style text of a ratio; "—" when there is nothing to compare (None or NaN)."""
    return f"{prefix}{ratio:.1f}×" if ratio is not None and math.isfinite(ratio) else "—"


def _count_text(m: dict[str, Any]) -> str:
    """``"2 [0.1–2.4 %]"``: a false-positive count and the exact interval of its rate per query."""
    lo, hi = m["rate_ci"]
    if lo is None or hi is None:
        return str(m["count"])
    return f"{m['count']} [{100 * lo:.1f}–{100 * hi:.1f} %]"


def _fp_ratio_text(c: dict[str, Any]) -> str:
    """The blind / seeded ratio of a :func:`factorloc.benchmarking.compare_counts` block and its one-sided lower bound."""
    s, b = c["seeded"]["count"], c["blind"]["count"]
    if s == b == 0:
        return "— (none)"
    point = "∞" if s == 0 else f"{b / s:.1f}×"
    lb = c.get("ratio_lower_bound")
    return point if lb is None else f"{point} (≥ {lb:.2f}×)"


def hierarchy_table(h: dict[str, Any]) -> Table:
    """Seeded vs blind: time, false positives with exact intervals and the ratio's lower bound, fused outcome."""
    s, b = h["seeded"], h["blind"]
    fp = h.get("false_positives") or {}
    conf = 100 * fp.get("confidence", 0.95)
    t = _table(
        "Hierarchy ablation: every step seeded vs every step blind",
        ("", "seeded", "blind", f"blind/seeded (≥ {conf:.0f} %)"),
    )
    t.add_row(
        "median ms / query", _num(s["median_ms"], ".1f"), _num(b["median_ms"], ".1f"), _num(h["time_ratio"], ".1f", 1.0, "×")
    )
    if not fp.get("queries"):
        # no false-positive comparison (older JSON, or no query with truth): the plain counts
        lb = "≥ " if h["false_positive_ratio_is_lower_bound"] else ""
        t.add_row(
            "false positives of seeded steps",
            str(s["false_positive_count"]),
            str(b["false_positive_count"]),
            _ratio_text(h["false_positive_ratio"], lb),
        )
        cw_lb = "≥ " if h.get("confidently_wrong_ratio_is_lower_bound") else ""
        t.add_row(
            "confidently-wrong fused",
            f"{s['confidently_wrong_count']} ({_pct(s['confidently_wrong_rate'])})",
            f"{b['confidently_wrong_count']} ({_pct(b['confidently_wrong_rate'])})",
            _ratio_text(h.get("confidently_wrong_ratio"), cw_lb),
        )
        t.add_row("fully localized", _pct(s["determined_rate"]), _pct(b["determined_rate"]), "")
        return t
    n = fp["queries"]
    tol = f"> {100 * fp['tolerance_m']:.0f} cm, {fp['tolerance_deg']:.0f}°"
    first = next(iter(fp["steps"]), "the first")
    rows = (
        (f"[bold]steps after {first}: false + (> 3σ)[/]", fp["steps_after_first"]["sigma3"]),
        (f"steps after {first}: false + ({tol})", fp["steps_after_first"]["tolerance"]),
    )
    for label, c in rows:
        t.add_row(label, _count_text(c["seeded"]), _count_text(c["blind"]), _fp_ratio_text(c))
    for name, per in fp["steps"].items():
        c = per["sigma3"]
        t.add_row(
            f"  {name}: > 3σ / reliable",
            f"{c['seeded']['count']} / {c['seeded']['reliable']}",
            f"{c['blind']['count']} / {c['blind']['reliable']}",
            _fp_ratio_text(c),
        )
    t.add_row("[bold]fused confidently wrong (> 3σ)[/]", *_fused_cells(fp["fused"]["sigma3"]))
    t.add_row(f"fused wrong ({tol})", *_fused_cells(fp["fused"]["tolerance"]))
    t.add_row("fully localized", _pct(s["determined_rate"]), _pct(b["determined_rate"]), "")
    target = fp["target_ratio"]
    need = []
    for label, c in (("steps", fp["steps_after_first"]["sigma3"]), ("fused", fp["fused"]["sigma3"])):
        q = c.get("queries_needed")
        if c.get("shows_target"):
            need.append(f"{label} shown")
        elif q is not None:
            q80 = c.get("queries_needed_power_80")
            need.append(f"{label} ≈ {q}" + ("" if q80 is None else f" ({q80} for 80 %)"))
        else:
            need.append(f"{label}: no blind false +" if c["blind"]["count"] == 0 else f"{label}: ratio ≤ {target:g}×")
    t.add_row(f"queries to show {target:g}× (now {n})", "", "", "; ".join(need))
    return t


def _fused_cells(c: dict[str, Any]) -> tuple[str, str, str]:
    return _count_text(c["seeded"]), _count_text(c["blind"]), _fp_ratio_text(c)


def bench_tables(out: dict[str, Any]) -> list[Table]:
    """The bench figures as rich tables: localize per step, seeded vs blind, ICP vs Open3D, fusion, cost curve."""
    loc = out["localize"]
    t1 = _table(
        f"localize() on {out['scenario']} ({out['queries']} queries × {loc['repeats']} repeats)",
        ("", "median ms", "p95 ms", "mean ms"),
    )
    t1.add_row("[bold]localize()[/]", _num(loc["median_ms"], ".1f"), _num(loc["p95_ms"], ".1f"), _num(loc["mean_ms"], ".1f"))
    for name, s in loc["steps"].items():
        t1.add_row(f"  {name}", _num(s["median_ms"], ".2f"), _num(s["p95_ms"], ".2f"), _num(s["mean_ms"], ".2f"))

    t2 = hierarchy_table(out["hierarchy"])

    icp = out["icp_vs_open3d"]
    t3 = _table(
        f"ICP vs Open3D point-to-plane ({icp.get('pairs', 0)} pairs, same seeds)", ("", "ours", "Open3D", "Open3D / ours")
    )
    if icp.get("pairs"):
        t3.add_row(
            "median ms",
            _num(icp["ours_median_ms"], ".2f"),
            _num(icp["open3d_median_ms"], ".2f"),
            _num(icp["time_ratio"], ".2f", 1.0, "×"),
        )
        t3.add_row(
            "median error",
            _num(icp["ours_median_error_m"], ".2f", 100.0, " cm"),
            _num(icp["open3d_median_error_m"], ".2f", 100.0, " cm"),
            _num(icp["error_ratio"], ".2f", 1.0, "×"),
        )
        t3.add_row(
            "median heading error",
            _num(icp["ours_median_error_deg"], ".3f", 1.0, "°"),
            _num(icp["open3d_median_error_deg"], ".3f", 1.0, "°"),
            "",
        )
        t3.add_row("success (< 5 cm, < 1°)", _pct(icp["ours_success_rate"]), _pct(icp["open3d_success_rate"]), "")

    f = out["fusion"]
    t4 = _table(f"Fusion: GTSAM graph vs closed-form product ({f.get('queries', 0)} queries)", ("", "value"))
    if f.get("queries"):
        t4.add_row("graph median", _num(f["graph_median_us"], ".0f", 1.0, " µs"))
        t4.add_row("product median", _num(f["product_median_us"], ".0f", 1.0, " µs"))
        t4.add_row("graph / product", _num(f["time_ratio"], ".1f", 1.0, "×"))
        t4.add_row("max |Δ position| (per-axis inputs)", _num(f["max_position_diff_m"], ".2e", 1.0, " m"))
        t4.add_row("max |Δ heading| (per-axis inputs)", _num(f["max_heading_diff_rad"], ".2e", 1.0, " rad"))
        t4.add_row(
            f"max |Δ position| (x–θ coupled, {f['queries_with_cross_covariance']} q.)",
            _num(f["max_position_diff_m_cross_covariance"], ".2e", 1.0, " m"),
        )

    c = out["cost_curve"]
    steps = list(c["points"][0]["steps_median_ms"])
    t5 = _table(
        f"Cost curve (exponent of t ∝ scale^k: {_num(c['exponent'], '.2f')})",
        ("scale", "pano width", "ref cloud", "query cloud", "ms / query", *steps),
        left=(),
    )
    for p in c["points"]:
        t5.add_row(
            f"{p['factor']:g}×",
            _num(p["panorama_width_px"], "d"),
            _num(p["reference_cloud_points"], "d"),
            _num(p["query_cloud_points_median"], ".0f"),
            _num(p["median_ms"], ".1f"),
            *[_num(p["steps_median_ms"][n], ".2f") for n in steps],
        )
    t5.add_row("[bold]exponent[/]", "", "", "", _num(c["exponent"], ".2f"), *[_num(c["steps_exponent"][n], ".2f") for n in steps])
    return [t1, t2, t3, t4, t5]


@app.command()
def bench(
    json_out: Annotated[
        Path | None, typer.Option("--json", help="Write the figures as JSON (keys in docs/evaluation.md).")
    ] = None,
    queries: Annotated[
        int | None,
        typer.Option("--queries", min=1, help="Queries of the generated scenario (default 200), or the first N of --scenario."),
    ] = None,
    scenario: Annotated[
        Path | None, typer.Option("--scenario", help="Benchmark this scenario directory instead of generating one.")
    ] = None,
    seed: Annotated[int, typer.Option("--seed", help="Seed of the generated scenario.")] = 7,
    repeats: Annotated[int, typer.Option("--repeats", min=1, help="Passes over the queries (figures are medians).")] = 3,
    config: Annotated[Path | None, typer.Option("--config", help="YAML configuration (defaults otherwise).")] = None,
) -> None:
    """Speed as ratios against peers in the same run: localize, seeded vs blind, ICP vs Open3D, GTSAM vs product, cost curve."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from factorloc.benchmarking import BenchSettings, run_bench

    try:
        cfg = _load_config(config)
        if scenario is not None:
            from factorloc.datasets import load_scenario

            scen = load_scenario(scenario)
            if queries is not None:
                scen = _first_queries(scen, queries)
        else:
            scen = _generated_scenario(200 if queries is None else queries, seed)
        settings = BenchSettings(repeats=repeats, cost_queries=min(20, len(scen.queries)))
        with Progress(
            TextColumn("[bold]{task.description}"),
            BarColumn(),
            MofNCompleteColumn(),
            TimeElapsedColumn(),
            console=console,
            transient=True,
        ) as bar:
            tasks: dict[str, Any] = {}

            def progress(stage: str, done: int, total: int) -> None:
                if stage not in tasks:
                    tasks[stage] = bar.add_task(stage, total=total)
                bar.update(tasks[stage], completed=done, total=total)

            out = run_bench(scen, cfg, settings=settings, progress=progress)
    except FactorlocError as exc:
        _fail(exc)
        return
    if json_out is not None:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(out, indent=2, allow_nan=False))
    for t in bench_tables(out):
        console.print(t)
    if json_out is not None:
        console.print(f"[dim]JSON written to {json_out}[/]")


def _first_queries(scen: Any, n: int) -> Any:
    """The scenario restricted to its first ``n`` queries."""
    from factorloc.datasets import Scenario

    return Scenario(scen.name, scen.references, scen.queries[:n], scen.world, scen.seed, scen.description, scen.metadata)


def _generated_scenario(queries: int, seed: int) -> Any:
    """A scenario generated in the built-in apartment with the default fault mix, with a progress bar."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from factorloc.sim import generate_scenario  # the simulator's generator

    with Progress(
        TextColumn("[bold]{task.description}"),
        BarColumn(),
        MofNCompleteColumn(),
        TimeElapsedColumn(),
        console=console,
        transient=True,
    ) as bar:
        task = bar.add_task(f"generating a scenario (seed {seed})", total=queries)
        return generate_scenario("apartment", queries, seed, progress=lambda d, t: bar.update(task, completed=d, total=t))


# ----------------------------------------------------------------------------
# simulate
# ----------------------------------------------------------------------------
@app.command()
def simulate(
    out_dir: Annotated[Path, typer.Argument(help="Directory to write the scenario to.")],
    world: Annotated[str, typer.Option("--world", help="Built-in world name or a world .yaml/.json file.")] = "apartment",
    queries: Annotated[int, typer.Option("--queries", min=0, help="Number of queries.")] = 30,
    seed: Annotated[int, typer.Option("--seed", min=0, help="Seed: the same seed gives the same scenario bit for bit.")] = 103,
    faults: Annotated[
        str,
        typer.Option("--faults", help="Comma-separated faults that may be applied: 'all', 'none', or e.g. 'occlusion,lighting'."),
    ] = "all",
    fault_probability: Annotated[
        float, typer.Option("--fault-probability", min=0.0, max=1.0, help="Share of faulted queries.")
    ] = 0.3,
    image_format: Annotated[str, typer.Option("--image-format", help="png (lossless) or jpg (small) query images.")] = "png",
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace an existing scenario directory.")] = False,
) -> None:
    """Render a simulated scenario (reference + queries with ground truth, drift and faults) into OUT_DIR."""
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from factorloc.datasets import save_scenario
    from factorloc.sim import FAULTS, GeneratorConfig, generate_scenario

    try:
        if faults.strip() == "all":
            fault_list: tuple[str, ...] = FAULTS
        elif faults.strip() in ("", "none"):
            fault_list = ()
        else:
            fault_list = tuple(f.strip() for f in faults.split(",") if f.strip())
        with Progress(
            TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), console=console
        ) as bar:
            task = bar.add_task("rendering queries", total=queries)
            scen = generate_scenario(
                world,
                queries,
                seed,
                fault_list,
                GeneratorConfig(fault_probability=fault_probability),
                progress=lambda done, total: bar.update(task, completed=done, total=total),
            )
        path = save_scenario(scen, out_dir, image_format=image_format, overwrite=overwrite)
    except FactorlocError as exc:
        _fail(exc)
        return
    size = sum(f.stat().st_size for f in path.rglob("*") if f.is_file())
    n_faulted = sum(1 for q in scen.queries if q.faults)
    console.print(
        f"wrote [bold]{path}[/]: {len(scen.queries)} queries ({n_faulted} with faults), world '{scen.world.name}', "
        f"seed {seed}, {size / 1e6:.2f} MB"
    )


# ----------------------------------------------------------------------------
# localize
# ----------------------------------------------------------------------------
@app.command()
def localize(
    scenario: Annotated[Path, typer.Argument(help="A scenario directory (docs/data-format.md), e.g. data/sample.")],
    query_id: Annotated[str, typer.Argument(help="The id of the query to localize (e.g. q0003).")],
    config: Annotated[Path | None, typer.Option("--config", help="A YAML config (keys as in factorloc.Config).")] = None,
    blind: Annotated[bool, typer.Option("--blind", help="Run every step without the hypotheses of the earlier ones.")] = False,
    json_out: Annotated[bool, typer.Option("--json", help="Print JSON instead of tables.")] = False,
) -> None:
    """Localize one query of a scenario: the steps table (estimate, σ, status, reason, ms) and the fused pose."""
    from factorloc.datasets import load_scenario

    try:
        cfg = _load_config(config)
        scen = load_scenario(scenario)
        case = scen.query_by_id(query_id)
        loc = factorloc.Localizer(scen.reference_of(case), cfg).localize(case.query, seeded=not blind)
    except FactorlocError as exc:
        _fail(exc)
        return
    truth = case.truth
    if json_out:
        out = loc.to_dict()
        out["query_id"] = case.id
        out["truth"] = None if truth is None else {"x_m": truth.x, "y_m": truth.y, "theta_rad": truth.theta}
        typer.echo(json.dumps(out, indent=2))
        return
    faults = f", faults: {', '.join(case.faults)}" if case.faults else ""
    console.print(f"Query [bold]{case.id}[/] of {scen.name}{faults}{' — blind' if blind else ''}")
    console.print(steps_table(loc))
    console.print(pose_table(loc))
    if truth is not None:
        err = loc.pose.as_array() - truth.as_array()
        err[2] = factorloc.wrap_angle(err[2])
        und = {c.value for c in loc.undetermined}
        pos = "undetermined" if "x" in und else f"{100 * math.hypot(err[0], err[1]):.2f} cm"
        head = "undetermined" if "theta" in und else f"{math.degrees(abs(err[2])):.3f}°"
        console.print(f"Error against ground truth: position {pos}, heading {head}")


# ----------------------------------------------------------------------------
# demo
# ----------------------------------------------------------------------------
def _sample_scenario_dir() -> Path:
    """The shipped sample scenario: ``data/sample`` or else the first directory of ``data/`` holding a ``scenario.yaml``."""
    preferred = PACKAGE_DATA / "sample"
    if (preferred / "scenario.yaml").is_file():
        return preferred
    found = sorted(p.parent for p in PACKAGE_DATA.glob("*/scenario.yaml"))
    if not found:
        raise InputError(f"no sample scenario (a directory with scenario.yaml) under {PACKAGE_DATA}")
    return found[0]


@app.command()
def demo(
    out: Annotated[Path, typer.Option("--out", help="Where the figures and the JSON report go.")] = Path("factorloc-demo"),
) -> None:
    """The main job on the shipped sample scenario: localize every query, print the figures, draw the plots."""
    import time

    from factorloc.datasets import load_scenario
    from factorloc.plotting import save_report_figures

    t0 = time.perf_counter()
    try:
        path = _sample_scenario_dir()
        scen = load_scenario(path)
        n_faulty = sum(1 for q in scen.queries if q.faults)
        console.rule("[bold]factorloc demo")
        console.print(
            f"Scenario [bold]{scen.name}[/] ({path}): {len(scen.queries)} queries against "
            f"{len(scen.references)} reference(s), {n_faulty} with faults. Each query: "
            "odometry → virtual compass → panorama correlation → ICP, gated, fused in a GTSAM factor graph."
        )
        report = _run_evaluation(scen, None, "localizing")
    except FactorlocError as exc:
        _fail(exc)
        return
    res = report.to_json_dict()
    console.print(evaluation_steps_table(res, "What each step contributed"))
    console.print(evaluation_summary_table(res, f"Fused pose vs ground truth ({res['strategy']})"))
    reasons = gate_reasons_text(res, per_step=1)
    if reasons:
        console.print(reasons)
    out.mkdir(parents=True, exist_ok=True)
    (out / "evaluation.json").write_text(json.dumps(res, indent=2, allow_nan=False))
    paths = save_report_figures(report, out)
    console.print(
        f"\n[bold green]✓[/] {len(scen.queries)} queries in {time.perf_counter() - t0:.1f} s. "
        f"Figures and evaluation.json in [bold]{out}/[/]: {', '.join(p.name for p in paths)}"
    )
    console.print("[dim]Next: factorloc evaluate SCENARIO --plot DIR, factorloc simulate, factorloc bench; docs/evaluation.md[/]")


cli_convert.register(app)

if __name__ == "__main__":  # pragma: no cover
    app()

"""The ``factorloc`` command line: the only place in the package that prints.

Every command is a thin wrapper around the public functions the notebooks and tests use: it parses its
arguments, calls the library, and prints the typed result with :mod:`factorloc.cli_render` (tables) and
:mod:`factorloc.cli_bench`. Every :class:`~factorloc.errors.FactorlocError` becomes one line on stderr
(``error: …``) and exit status 2, never a traceback.
"""

from __future__ import annotations

import functools
import json
import math
import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Annotated, Any, TypeVar

import typer
from rich.console import Console

import factorloc
from factorloc import cli_convert, cli_map, cli_sweep, cli_track, jit
from factorloc.cli_console import console_for
from factorloc.cli_parallel import SchedulerOption, WorkersOption, batch_executor, failure_printer
from factorloc.cli_render import (
    evaluation_steps_table,
    evaluation_summary_table,
    gate_reasons_text,
    pose_table,
    progress,
    steps_table,
)
from factorloc.errors import FactorlocError, InputError


class _OneLineErrors(typer.core.TyperGroup):
    """The command group whose every error is one line on stderr: usage errors and library errors exit 2.

    Click's usage errors (an unknown option, a bad value) would otherwise be drawn in a box wrapped to the
    terminal's width; a library error escaping a command registered elsewhere (``cli_convert``, …) would be a
    traceback. Any other exception is a bug: one line ``error: internal error: …``, exit 1
    (``FACTORLOC_TRACEBACK=1`` shows the traceback).
    """

    def main(self, *args: Any, standalone_mode: bool = True, **kwargs: Any) -> Any:
        if not standalone_mode:
            return super().main(*args, standalone_mode=False, **kwargs)
        try:
            rv = super().main(*args, standalone_mode=False, **kwargs)
        except typer.Abort:
            typer.echo("error: aborted", err=True)
            sys.exit(1)
        except FactorlocError as exc:
            typer.echo(error_line(exc), err=True)
            sys.exit(2)
        except Exception as exc:
            if hasattr(exc, "format_message") and isinstance(getattr(exc, "exit_code", None), int):  # click's usage errors
                if type(exc).__name__ == "NoArgsIsHelpError":
                    exc.show()  # type: ignore[attr-defined]
                else:
                    typer.echo("error: " + " ".join(exc.format_message().split()), err=True)  # type: ignore[attr-defined]
                sys.exit(exc.exit_code)  # type: ignore[attr-defined]
            if os.environ.get("FACTORLOC_TRACEBACK"):
                raise
            typer.echo(f"error: internal error: {type(exc).__name__}: {' '.join(str(exc).split())[:300]}", err=True)
            sys.exit(1)
        sys.exit(rv if isinstance(rv, int) else 0)


app = typer.Typer(
    cls=_OneLineErrors,
    name="factorloc",
    help="Localize a robot in the plane by fusing odometry, a visual compass, panorama correlation and ICP in a factor graph.",
    no_args_is_help=True,
    add_completion=False,
    pretty_exceptions_enable=False,
)
console = console_for()

PACKAGE_DATA = Path(__file__).resolve().parent.parent / "data"

F = TypeVar("F", bound=Callable[..., Any])


def error_line(exc: BaseException) -> str:
    """The one line a user reads for a library error: ``error: <message>`` with its line breaks folded."""
    return "error: " + " ".join(str(exc).split())


def one_line_errors(command: F) -> F:
    """Turn a :class:`~factorloc.errors.FactorlocError` raised by ``command`` into one line on stderr and exit 2."""

    @functools.wraps(command)
    def wrapper(*args: Any, **kwargs: Any) -> Any:
        try:
            return command(*args, **kwargs)
        except FactorlocError as exc:
            typer.echo(error_line(exc), err=True)
            raise typer.Exit(code=2) from None

    return wrapper  # type: ignore[return-value]


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


def _load_config(path: Path | None) -> factorloc.Config | None:
    return None if path is None else factorloc.Config.from_yaml(path)


def _load_estimates(path: Path) -> list[factorloc.Estimate]:
    if not path.is_file():
        raise InputError(f"estimates file not found: {path}")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise InputError(f"{path} is not UTF-8 text: {exc}") from exc
    except RecursionError as exc:
        raise InputError(f"{path} nests JSON too deep to be read") from exc
    except json.JSONDecodeError as exc:
        raise InputError(f"{path} is not valid JSON: {exc}") from exc
    items: Any = data.get("estimates") if isinstance(data, dict) else data
    if not isinstance(items, list):
        raise InputError(f"{path} must hold a list of estimates or an object with an 'estimates' list")
    return [factorloc.Estimate.from_dict(item) for item in items]


def _write_json(path: Path, data: dict[str, Any]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(data, indent=2, allow_nan=False))


# ----------------------------------------------------------------------------
# fuse
# ----------------------------------------------------------------------------
@app.command()
@one_line_errors
def fuse(
    estimates: Annotated[
        Path, typer.Argument(help="JSON file: a list of estimates (step, components, values, sigmas or covariance).")
    ],
    strategy: Annotated[str, typer.Option(help="Fusion strategy: 'graph' (GTSAM) or 'product' (closed form).")] = "graph",
    json_out: Annotated[bool, typer.Option("--json", help="Print JSON instead of tables.")] = False,
) -> None:
    """Gate and fuse ready-made estimates: pose, covariance and per-estimate verdicts."""
    ests = _load_estimates(estimates)
    if strategy not in ("graph", "product"):
        raise InputError(f"--strategy must be 'graph' or 'product', got {strategy!r}")
    strat = factorloc.GraphFusion() if strategy == "graph" else factorloc.ProductFusion()
    loc = factorloc.fuse(ests, strategy=strat)
    if json_out:
        typer.echo(json.dumps(loc.to_dict(), indent=2))
    else:
        console.print(steps_table(loc, "Estimates"))
        console.print(pose_table(loc))


# ----------------------------------------------------------------------------
# evaluate
# ----------------------------------------------------------------------------
def _run_evaluation(
    scenario: Any, cfg: factorloc.Config | None, label: str, workers: int | None = None, scheduler: str | None = None
) -> Any:
    """Evaluate ``scenario`` with a progress bar (on the executor the options ask for); returns the EvaluationReport."""
    from factorloc.evaluation import evaluate as evaluate_scenario

    with batch_executor(console, workers, scheduler) as ex, progress(console) as advance:
        return evaluate_scenario(
            scenario,
            config=cfg,
            progress=lambda done, total: advance(label, done, total),
            executor=ex,
            on_failure=failure_printer(console),
        )


@app.command()
@one_line_errors
def evaluate(
    scenario: Annotated[Path, typer.Argument(help="Scenario directory (scenario.yaml, see docs/data-format.md).")],
    config: Annotated[Path | None, typer.Option("--config", help="YAML configuration (defaults otherwise).")] = None,
    json_out: Annotated[
        Path | None, typer.Option("--json", help="Write every figure as JSON (keys in docs/evaluation.md).")
    ] = None,
    plot: Annotated[Path | None, typer.Option("--plot", help="Write the figures (PNG) into this directory.")] = None,
    workers: WorkersOption = None,
    scheduler: SchedulerOption = None,
) -> None:
    """Localize every query of a scenario; report accuracy, honesty, availability and speed."""
    from factorloc.datasets import load_scenario

    cfg = _load_config(config)
    scen = load_scenario(scenario)
    report = _run_evaluation(scen, cfg, f"localizing {scen.name}", workers, scheduler)
    summary = report.summary()
    if summary.failed_queries:
        console.print(f"[red]{summary.failed_queries} of {len(scen.queries)} queries failed[/] (scored: the others)")
    console.print(evaluation_summary_table(summary, f"{scen.name}: fused pose ({summary.strategy})"))
    console.print(evaluation_steps_table(summary))
    reasons = gate_reasons_text(summary)
    if reasons:
        console.print(reasons)
    if json_out is not None:
        _write_json(json_out, report.to_json())
        console.print(f"[dim]JSON written to {json_out}[/]")
    if plot is not None:
        from factorloc.plotting import save_report_figures

        paths = save_report_figures(report, plot)
        console.print(f"[dim]figures written to {plot}: {', '.join(p.name for p in paths)}[/]")


# ----------------------------------------------------------------------------
# bench
# ----------------------------------------------------------------------------
def _first_queries(scen: Any, n: int) -> Any:
    """The scenario restricted to its first ``n`` queries."""
    from factorloc.datasets import Scenario

    return Scenario(scen.name, scen.references, scen.queries[:n], scen.world, scen.seed, scen.description, scen.metadata)


def _generated_scenario(queries: int, seed: int) -> Any:
    """A scenario generated in the built-in apartment with the default fault mix, with a progress bar."""
    from factorloc.sim import generate_scenario  # the simulator's generator

    label = f"generating a scenario (seed {seed})"
    with progress(console, eta=False) as advance:
        return generate_scenario("apartment", queries, seed, progress=lambda d, t: advance(label, d, t))


@app.command()
@one_line_errors
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
    workers: WorkersOption = None,
    scheduler: SchedulerOption = None,
) -> None:
    """Speed as ratios against peers in the same run: localize, seeded vs blind, ICP vs Open3D, GTSAM vs product, cost curve."""
    from factorloc.benchmarking import BenchSettings, run_bench
    from factorloc.cli_bench import bench_tables

    cfg = _load_config(config)
    if scenario is not None:
        from factorloc.datasets import load_scenario

        scen = load_scenario(scenario)
        if queries is not None:
            scen = _first_queries(scen, queries)
    else:
        scen = _generated_scenario(200 if queries is None else queries, seed)
    settings = BenchSettings(repeats=repeats, cost_queries=min(20, len(scen.queries)))
    with batch_executor(console, workers, scheduler) as ex, progress(console, eta=False) as advance:
        report = run_bench(scen, cfg, settings=settings, progress=advance, executor=ex)
    if json_out is not None:
        _write_json(json_out, report.to_json())
    for t in bench_tables(report):
        console.print(t)
    if json_out is not None:
        console.print(f"[dim]JSON written to {json_out}[/]")


# ----------------------------------------------------------------------------
# simulate
# ----------------------------------------------------------------------------
def _fault_list(faults: str) -> tuple[str, ...]:
    from factorloc.sim import FAULTS

    if faults.strip() == "all":
        return FAULTS
    if faults.strip() in ("", "none"):
        return ()
    return tuple(f.strip() for f in faults.split(",") if f.strip())


@app.command()
@one_line_errors
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
    track: Annotated[
        bool,
        typer.Option(
            "--track",
            help="A trajectory instead: places in every room (the references) and a robot touring the rooms "
            "(queries in time order with one odometry run); faults: occlusion (lighting, blur with --panorama-width).",
        ),
    ] = False,
    kidnaps: Annotated[int, typer.Option("--kidnaps", min=0, help="With --track: times the robot is carried elsewhere.")] = 0,
    place_spacing: Annotated[
        float, typer.Option("--place-spacing", min=0.1, help="With --track: grid spacing of the places in each room (m).")
    ] = 1.5,
    panorama_width: Annotated[
        int,
        typer.Option(
            "--panorama-width", min=0, help="With --track: a 360° panorama of this width per place and query (0: laser only)."
        ),
    ] = 0,
) -> None:
    """Render a simulated scenario (reference + queries with ground truth, drift and faults) into OUT_DIR; with
    --track, a tour of the world's rooms through places in every room, with kidnappings."""
    from factorloc.datasets import check_scenario_target, save_scenario

    check_scenario_target(out_dir, overwrite, how="use --overwrite")  # before the rendering, not after
    if track:
        scen = _simulate_track(world, queries, seed, faults, fault_probability, kidnaps, place_spacing, panorama_width)
    else:
        from factorloc.sim import GeneratorConfig, generate_scenario

        if kidnaps or panorama_width:
            raise InputError(
                "--kidnaps and --panorama-width go with --track (a scenario's kidnappings are the 'kidnapped' fault)"
            )
        with progress(console, eta=False, transient=False) as advance:
            scen = generate_scenario(
                world,
                queries,
                seed,
                _fault_list(faults),
                GeneratorConfig(fault_probability=fault_probability),
                progress=lambda done, total: advance("rendering queries", done, total),
            )
    path = save_scenario(scen, out_dir, image_format=image_format, overwrite=overwrite)
    size = sum(f.stat().st_size for f in path.rglob("*") if f.is_file())
    n_faulted = sum(1 for q in scen.queries if q.faults)
    console.print(
        f"wrote [bold]{path}[/]: {len(scen.queries)} queries ({n_faulted} with faults), world '{scen.world.name}', "
        f"seed {seed}, {size / 1e6:.2f} MB"
    )


def _simulate_track(
    world: str, queries: int, seed: int, faults: str, fault_probability: float, kidnaps: int, spacing_m: float, width_px: int
) -> Any:
    """``simulate --track``: the places of every room and a tour through them (:func:`factorloc.sim.track.generate_track`)."""
    from factorloc.sim import world_by_name
    from factorloc.sim.track import TRACK_FAULTS, TrackConfig, generate_track, room_places

    if faults.strip() == "all":
        fault_list = tuple(f for f in TRACK_FAULTS if width_px > 0 or f == "occlusion")
    else:
        fault_list = _fault_list(faults)
        if "kidnapped" in fault_list:
            raise InputError("--faults: with --track the kidnappings are --kidnaps K, not the 'kidnapped' fault")
    w = world_by_name(world)
    config = TrackConfig(faults=fault_list, fault_probability=fault_probability, panorama_width_px=width_px)
    with progress(console, eta=False, transient=False) as advance:
        place_map = room_places(w, spacing_m, seed=seed, panorama_width_px=width_px)
        advance("rendering places", 1, 1)
        return generate_track(
            w,
            place_map,
            queries,
            seed,
            kidnaps=kidnaps,
            config=config,
            progress=lambda done, total: advance("rendering queries", done, total),
        )


# ----------------------------------------------------------------------------
# localize
# ----------------------------------------------------------------------------
@app.command()
@one_line_errors
def localize(
    scenario: Annotated[Path, typer.Argument(help="A scenario directory (docs/data-format.md), e.g. data/sample.")],
    query_id: Annotated[str, typer.Argument(help="The id of the query to localize (e.g. q0003).")],
    config: Annotated[Path | None, typer.Option("--config", help="A YAML config (keys as in factorloc.Config).")] = None,
    blind: Annotated[bool, typer.Option("--blind", help="Run every step without the hypotheses of the earlier ones.")] = False,
    json_out: Annotated[bool, typer.Option("--json", help="Print JSON instead of tables.")] = False,
) -> None:
    """Localize one query of a scenario: the steps table (estimate, σ, status, reason, ms) and the fused pose."""
    from factorloc.datasets import load_scenario

    cfg = _load_config(config)
    scen = load_scenario(scenario)
    case = scen.query_by_id(query_id)
    loc = factorloc.Localizer(scen.reference_of(case), cfg).localize(case.query, seeded=not blind)
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
@one_line_errors
def demo(
    out: Annotated[Path, typer.Option("--out", help="Where the figures and the JSON report go.")] = Path("factorloc-demo"),
) -> None:
    """The main job on the shipped sample scenario: localize every query, print the figures, draw the plots."""
    import time

    from factorloc.datasets import load_scenario
    from factorloc.plotting import save_report_figures

    t0 = time.perf_counter()
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
    summary = report.summary()
    console.print(evaluation_steps_table(summary, "What each step contributed"))
    console.print(evaluation_summary_table(summary, f"Fused pose vs ground truth ({summary.strategy})"))
    reasons = gate_reasons_text(summary, per_step=1)
    if reasons:
        console.print(reasons)
    out.mkdir(parents=True, exist_ok=True)
    _write_json(out / "evaluation.json", report.to_json())
    paths = save_report_figures(report, out)
    console.print(
        f"\n[bold green]✓[/] {len(scen.queries)} queries in {time.perf_counter() - t0:.1f} s. "
        f"Figures and evaluation.json in [bold]{out}/[/]: {', '.join(p.name for p in paths)}"
    )
    console.print("[dim]Next: factorloc evaluate SCENARIO --plot DIR, factorloc simulate, factorloc bench; docs/evaluation.md[/]")


cli_convert.register(app)
cli_map.register(app)
cli_sweep.register(app)
cli_track.register(app)

if __name__ == "__main__":  # pragma: no cover
    app()

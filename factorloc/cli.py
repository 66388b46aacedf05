"""The ``factorloc`` command line: the only place in the package that prints.

Every command is a thin wrapper around the public functions the notebooks
and tests use.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any, Optional

import typer
from rich.console import Console
from rich.table import Table

import factorloc
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
        Optional[bool], typer.Option("--version", callback=_version, is_eager=True, help="Print the version and exit.")
    ] = None,
) -> None:
    """factorloc command line."""


# ----------------------------------------------------------------------------
# shared rendering
# ----------------------------------------------------------------------------
def _fmt_estimate(est: factorloc.Estimate | None) -> tuple[str, str]:
    if est is None:
        return "—", "—"
    parts, sig = [], []
    for c, v, s in zip(est.components, est.values, est.sigmas):
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


def steps_table(loc: factorloc.Localization, title: str = "Steps") -> Table:
    """A rich table: one row per step (estimate, σ, status, reason, ms)."""
    table = Table(title=title, title_justify="left")
    for col in ("step", "estimate", "σ", "status", "reason", "ms"):
        table.add_column(col, justify="right" if col == "ms" else "left")
    for r in loc.steps:
        value, sigma = _fmt_estimate(r.estimate)
        style = _STATUS_STYLE.get(r.status.value, "")
        table.add_row(r.name, value, sigma, f"[{style}]{r.status.value}[/]", r.reason, f"{1000 * r.seconds:.1f}")
    return table


def pose_table(loc: factorloc.Localization) -> Table:
    """The fused pose with its σ and certainty."""
    table = Table(title=f"Fused pose ({loc.fused_with})", title_justify="left")
    for col in ("x (m)", "y (m)", "θ (°)", "σx (cm)", "σy (cm)", "σθ (°)", "P(±5 cm, ±1°)"):
        table.add_column(col, justify="right")
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
    estimates: Annotated[Path, typer.Argument(help="JSON file: a list of estimates (step, components, values, sigmas or covariance).")],
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
# demo
# ----------------------------------------------------------------------------
@app.command()
def demo() -> None:
    """The main job on the shipped default data: the patent's worked example, fused both ways."""
    path = PACKAGE_DATA / "examples" / "patent_example.json"
    try:
        ests = _load_estimates(path)
    except FactorlocError as exc:
        _fail(exc)
        return
    console.rule("[bold]factorloc demo — the patent's worked example")
    for strat in (factorloc.ProductFusion(), factorloc.GraphFusion()):
        loc = factorloc.fuse(ests, strategy=strat)
        if strat.name == "product":
            console.print(steps_table(loc, f"Estimates ({path.name})"))
        console.print(pose_table(loc))


if __name__ == "__main__":  # pragma: no cover
    app()

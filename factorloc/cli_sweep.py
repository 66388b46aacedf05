"""``factorloc sweep GRID.yaml``: config overrides × scenarios and laser logs (:mod:`factorloc.evaluation.sweep`).

Prints one table of every setting (the evaluation's headline figures per scenario, the leave-one-log-out
fold table on the laser logs) and writes one JSON per setting into ``--out``.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Annotated

import typer

from factorloc.cli_console import console_for
from factorloc.cli_parallel import SchedulerOption, WorkersOption, batch_executor

__all__ = ["register", "sweep"]

console = console_for()


def _slug(name: str) -> str:
    """A file name for a setting's name (``sigma_floor_m=0.0075,bias_rmse_ratio=0.5`` stays readable)."""
    return re.sub(r"[^A-Za-z0-9_.=,+-]+", "_", name).strip("_") or "setting"


def sweep(
    grid: Annotated[
        Path, typer.Argument(help="The sweep file: grid/settings of dotted config overrides, scenarios, laser logs.")
    ],
    out: Annotated[Path, typer.Option("--out", help="Directory for one JSON per setting.")] = Path("factorloc-sweep"),
    every: Annotated[
        int | None, typer.Option("--every", min=1, help="Use every N-th relation of the laser logs (overrides the file).")
    ] = None,
    workers: WorkersOption = None,
    scheduler: SchedulerOption = None,
) -> None:
    """Run every setting of a sweep file on its scenarios and laser logs; one table, one JSON per setting."""
    from factorloc.cli import error_line
    from factorloc.cli_render import progress
    from factorloc.errors import FactorlocError
    from factorloc.evaluation.sweep import SweepSpec, format_sweep, run_sweep

    try:
        spec = SweepSpec.from_yaml(grid)
        console.print(
            f"[dim]{len(spec.settings)} settings × {len(spec.scenarios)} scenarios"
            + (f" + {len(spec.laser.logs)} laser logs" if spec.laser else "")
            + "[/]"
        )
        with batch_executor(console, workers, scheduler) as ex, progress(console) as advance:
            results = run_sweep(spec, executor=ex, progress=advance, every=every)
    except FactorlocError as exc:
        typer.echo(error_line(exc), err=True)
        raise typer.Exit(code=2) from None
    typer.echo(format_sweep(results))  # fixed-width text: not wrapped to the terminal
    out.mkdir(parents=True, exist_ok=True)
    for r in results:
        (out / f"{_slug(r.setting.name)}.json").write_text(json.dumps(r.to_json(), indent=1, allow_nan=False))
    console.print(f"[dim]{len(results)} JSON files written to {out}[/]")


def register(app: typer.Typer) -> None:
    """Add ``sweep`` to the ``factorloc`` app."""
    app.command("sweep")(sweep)

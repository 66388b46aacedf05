"""The command line's ``--workers`` / ``--scheduler`` options and what they start (:mod:`factorloc.parallel`)."""

from __future__ import annotations

from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import TYPE_CHECKING, Annotated, Any

import typer
from rich.console import Console

if TYPE_CHECKING:  # pragma: no cover
    from factorloc.evaluation.runner import QueryFailure

__all__ = ["SchedulerOption", "WorkersOption", "batch_executor", "failure_printer"]

WorkersOption = Annotated[
    int | None,
    typer.Option("--workers", min=1, help="Run the queries on a local Dask cluster of N worker processes (factorloc[dask])."),
]
SchedulerOption = Annotated[
    str | None,
    typer.Option(
        "--scheduler",
        help="Run the queries on the Dask cluster at this address (default: $DASK_SCHEDULER_ADDRESS if set, else in process).",
    ),
]


@contextmanager
def batch_executor(console: Console, workers: int | None, scheduler: str | None) -> Iterator[Any]:
    """The executor the options ask for, started, closed on leaving (also on ``Ctrl-C``)."""
    from factorloc.parallel import DaskExecutor, executor_from_options

    ex = executor_from_options(workers, scheduler)
    try:
        if isinstance(ex, DaskExecutor):
            with console.status("starting the Dask workers"):
                ex.start()
            where = (
                f"{ex.workers} local workers" if ex.scheduler is None else f"the cluster at {ex.scheduler} ({ex.workers} workers)"
            )
            console.print(f"[dim]running on {where}[/]")
        yield ex
    except KeyboardInterrupt:
        console.print("[yellow]interrupted: pending work cancelled[/]")
        raise typer.Exit(code=130) from None
    finally:
        ex.close()


def failure_printer(console: Console) -> Callable[[QueryFailure], None]:
    """``on_failure`` callback of the batch functions: one line per failed query, above the progress bar."""

    def show(failure: QueryFailure) -> None:
        died = " (worker died)" if failure.worker_died else ""
        console.print(f"[red]query {failure.query_id} failed{died}:[/] {failure.error}")

    return show

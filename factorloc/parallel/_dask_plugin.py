"""The worker plugin of :class:`~factorloc.parallel.DaskExecutor` (imports ``distributed``: loaded when a
cluster starts, never at ``import factorloc``)."""

from __future__ import annotations

from typing import Any

from distributed import WorkerPlugin

from factorloc.parallel.dask_executor import _one_thread_per_task


class WorkerSetup(WorkerPlugin):  # type: ignore[misc]
    """Runs :func:`~factorloc.parallel.dask_executor._one_thread_per_task` on every worker, present and future:
    a worker that replaces a dead one is set up the same way."""

    name = "factorloc-worker-setup"

    def __init__(self, warm_up: bool) -> None:
        self.warm_up = bool(warm_up)

    def setup(self, worker: Any) -> None:
        _one_thread_per_task(self.warm_up)

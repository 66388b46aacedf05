"""The executor on ``dask.distributed``: a local cluster of worker processes, or an existing scheduler.

``DaskExecutor(workers=N)`` starts ``LocalCluster(n_workers=N, threads_per_worker=1, processes=True)``;
``DaskExecutor(scheduler=ADDRESS)`` (or the environment variable ``DASK_SCHEDULER_ADDRESS``) connects to a
running cluster. Dask is imported when the executor starts, never at ``import factorloc``; without the extra
(``pip install factorloc[dask]``) starting raises a :class:`~factorloc.errors.ConfigError` saying so.

One chunk is one Dask task (``client.submit(..., pure=False)``: no hashing of the inputs). The ``shared`` object
is scattered to every worker once (``client.scatter(broadcast=True)``); a chunk's items are scattered to the
worker that will run it just before its task is submitted. At most one chunk runs on each worker thread at a
time (the next is sent when one finishes), so a worker that dies loses only the chunks it was running, and
Dask's count of the workers a task was running on when they died is exact. Results are released in input order
as the chunks finish. A chunk whose function raised, or whose worker died more often than the scheduler allows
(``distributed.scheduler.allowed-failures``), yields a :class:`~factorloc.parallel.base.TaskFailure` per item;
the other chunks go on. A chunk whose scattered data died with a worker (its items, or the only copy of
``shared``) cannot be retried by Dask: it is sent again, at most 3 times, then reported failed with
``worker_died``. Each result is gathered as soon as its task finishes. An interrupt (``Ctrl-C``) or any exception in the consumer
cancels the chunks still running; :meth:`DaskExecutor.close` (or leaving the ``with`` block) closes the client
and the local cluster.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Hashable, Iterator, Sequence
from concurrent.futures import CancelledError
from typing import Any

from factorloc.errors import ConfigError, InputError
from factorloc.parallel.base import (
    ChunkFunction,
    InputOrder,
    ItemsProgress,
    SerialExecutor,
    TaskFailure,
    check_results,
    chunk_indices,
    default_chunk_size,
    failure_of,
)

log = logging.getLogger(__name__)

__all__ = ["SCHEDULER_ENV", "DaskExecutor", "executor_from_options"]

#: The environment variable naming a running scheduler (Dask's own convention).
SCHEDULER_ENV = "DASK_SCHEDULER_ADDRESS"

#: Dask's nanny sets ``MALLOC_TRIM_THRESHOLD_=65536`` in every worker it spawns (to hand freed memory back to the
#: OS). Setting that variable at all switches off glibc's dynamic mmap threshold, so every array above 128 KiB is
#: mapped and unmapped afresh, page faults included: a query ran 51 % slower with it (96.5 against 63.8 ms on
#: one thread, ``benchmarks/bench_parallel.py``, docs/scale.md). A local cluster's workers keep glibc's default
#: (the value None unsets it, Dask's documented override); a user's own cluster keeps its own setting.
_TRIM_KEY = "distributed.nanny.pre-spawn-environ.MALLOC_TRIM_THRESHOLD_"

#: Dask's active memory manager (on by default, every 2 s) drops the replicas of a key that no waiting task on
#: that worker needs, the broadcast ``shared`` object's included: a worker then fetches it from another one for
#: its next chunk, and the death of the last holder loses it for every chunk. A local cluster runs without it.
_AMM_KEY = "distributed.scheduler.active-memory-manager.start"

#: How many times a chunk whose scattered data died with a worker is sent again (Dask cannot retry such a task
#: itself: its input is gone and the scheduler cancels it). A chunk finished on a worker that died before its
#: result was gathered is one of them, so this does not follow ``allowed_failures``; on a cluster that retries
#: (``allowed_failures > 0``) a chunk that kills every worker it runs on is reported after 1 + 3 deaths.
_LOST_DATA_RESENDS = 3

#: Dask's work stealing moves a waiting task to an idle worker; with one chunk per worker thread nothing waits,
#: and a task run elsewhere than the worker its chunk was sent to would leave that worker looking busy and the
#: one holding the result looking idle. A local cluster runs without it.
_STEALING_KEY = "distributed.scheduler.work-stealing"


def _run_chunk(fn: ChunkFunction, chunk: Sequence[Any], shared: Any) -> Sequence[Any]:
    """The task a worker runs: ``fn(chunk, shared)``, checked to give one result per item."""
    return list(check_results(fn(chunk, shared), chunk))


def _one_thread_per_task(warm_up: bool) -> None:
    """What every worker process does when it joins: one native thread per task, then (``warm_up``) the
    compiled kernels loaded (:func:`factorloc.jit.warm_up`) so that no query's time includes numba's cache load.

    Dask's nanny sets ``OMP_NUM_THREADS=1`` (and the BLAS variables) before a worker starts, but OpenCV's
    wheels use their own pthreads pool, sized to the machine's cores and blind to those variables: without
    ``cv2.setNumThreads(1)`` two workers on two cores run four OpenCV threads. The worker runs its tasks
    concurrently on its own threads (``threads_per_worker``), which is where the parallelism is.
    """
    try:
        import cv2
    except ImportError:  # pragma: no cover - a dependency of factorloc
        pass
    else:
        cv2.setNumThreads(1)
    if warm_up:
        from factorloc import jit

        jit.warm_up()


def _import_distributed() -> Any:
    try:
        import distributed
    except ImportError as exc:  # pragma: no cover - the dev environment has the extra
        raise ConfigError(
            "DaskExecutor needs dask.distributed: pip install 'factorloc[dask]' (or run without --workers/--scheduler)"
        ) from exc
    return distributed


class DaskExecutor:
    """Runs chunks as tasks on a Dask cluster.

    Parameters
    ----------
    workers
        Start a local cluster of this many single-threaded worker processes.
    scheduler
        Connect to the scheduler at this address (``tcp://host:8786``); default: ``$DASK_SCHEDULER_ADDRESS``
        when ``workers`` is None.
    chunks_per_worker
        With ``chunk_size=None``, items are split into about ``workers × chunks_per_worker`` chunks.
    allowed_failures
        For a local cluster: how many times a task whose worker died is retried before it is reported failed
        (Dask's ``distributed.scheduler.allowed-failures``; its default is 3). A chunk whose scattered input
        died with the worker cannot be retried by Dask; the executor sends it again itself (at most 3 times).
    warm_up
        Load the compiled kernels in every worker when the executor starts (:func:`factorloc.jit.warm_up`,
        about a second each once numba's cache exists), so that no query's time includes it. Every worker,
        warmed up or not, runs OpenCV with one thread (:func:`_one_thread_per_task`).

    Notes
    -----
    Use it as a context manager (``with DaskExecutor(workers=2) as ex: evaluate(..., executor=ex)``) or call
    :meth:`close`; the cluster starts at the first :meth:`map_chunks` (or :meth:`start`).
    """

    def __init__(
        self,
        workers: int | None = None,
        scheduler: str | None = None,
        *,
        chunks_per_worker: int = 16,
        allowed_failures: int | None = None,
        warm_up: bool = True,
    ) -> None:
        if workers is not None and scheduler is not None:
            raise InputError("DaskExecutor takes workers (a local cluster) or scheduler (an existing one), not both")
        if workers is not None and (isinstance(workers, bool) or not isinstance(workers, int) or workers < 1):
            raise InputError(f"workers must be an integer >= 1, got {workers!r}")
        if workers is None and scheduler is None:
            scheduler = os.environ.get(SCHEDULER_ENV) or None
            if scheduler is None:
                raise InputError(f"DaskExecutor needs workers=N or scheduler=ADDRESS (or ${SCHEDULER_ENV})")
        if chunks_per_worker < 1:
            raise InputError(f"chunks_per_worker must be >= 1, got {chunks_per_worker!r}")
        self.n_workers = workers
        self.scheduler = scheduler
        self.chunks_per_worker = int(chunks_per_worker)
        self.allowed_failures = allowed_failures
        self.warm_up = bool(warm_up)
        self._cluster: Any = None
        self._client: Any = None

    # --- life cycle ---------------------------------------------------------
    def start(self) -> DaskExecutor:
        """Start the local cluster (or connect to the scheduler) and the client; idempotent."""
        if self._client is not None:
            return self
        distributed = _import_distributed()
        try:
            if self.scheduler is not None:
                self._client = distributed.Client(self.scheduler)
            else:
                import dask

                overrides: dict[str, Any] = {_TRIM_KEY: None, _AMM_KEY: False, _STEALING_KEY: False}  # see their notes
                if self.allowed_failures is not None:
                    overrides["distributed.scheduler.allowed-failures"] = self.allowed_failures
                with dask.config.set(overrides):
                    self._cluster = distributed.LocalCluster(
                        n_workers=self.n_workers,
                        threads_per_worker=1,
                        processes=True,
                        dashboard_address=":0",  # a free port: the machine may run other clusters
                        silence_logs=logging.ERROR,  # not its shutdown chatter; failures are reported here
                    )
                self._client = distributed.Client(self._cluster)
                # every worker up before anything is broadcast: a worker that joins later would fetch the shared
                # object from another worker instead of holding its own copy
                self._client.wait_for_workers(self.n_workers, timeout=120)
            from factorloc.parallel._dask_plugin import WorkerSetup  # imports distributed

            self._client.register_plugin(WorkerSetup(self.warm_up), name=WorkerSetup.name)
        except BaseException:
            self.close()
            raise
        return self

    def close(self) -> None:
        """Close the client and the local cluster (never the cluster of ``scheduler=``)."""
        client, cluster = self._client, self._cluster
        self._client = self._cluster = None
        try:
            if client is not None:
                client.close()
        finally:
            if cluster is not None:
                cluster.close()

    def __enter__(self) -> DaskExecutor:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    @property
    def client(self) -> Any:
        """The ``distributed.Client`` (started on first use)."""
        return self.start()._client

    @property
    def workers(self) -> int:
        """The workers the scheduler knows now (a local cluster's ``n_workers`` before it starts)."""
        if self._client is None:
            return int(self.n_workers or 1)
        return max(1, len(self._client.scheduler_info().get("workers", {})))

    # --- work ---------------------------------------------------------------
    def _free_slots(self) -> list[str]:
        """One entry per idle worker thread known to the scheduler now (its address, repeated per thread)."""
        workers = self._client.scheduler_info(n_workers=-1).get("workers", {})
        return [addr for addr, info in workers.items() for _ in range(max(1, int(info.get("nthreads", 1))))]

    def map_chunks(
        self,
        fn: ChunkFunction,
        items: Sequence[Any],
        chunk_size: int | None = None,
        *,
        group: Sequence[Hashable] | None = None,
        shared: Any = None,
        progress: ItemsProgress | None = None,
    ) -> Iterator[Any]:
        distributed = _import_distributed()
        client = self.client
        n = len(items)
        size = chunk_size or default_chunk_size(n, self.workers, self.chunks_per_worker)
        chunks = chunk_indices(n, size, group)
        if not chunks:
            return
        # ``shared`` goes to every worker once (wrapped: a list or dict would be scattered element by element)
        shared_futures = [client.scatter([shared], broadcast=True, hash=False)[0]]
        waiting = list(range(len(chunks)))  # chunk numbers not yet sent, in order
        waiting.reverse()
        running: dict[str, tuple[int, Any, str, Any]] = {}  # task key -> (chunk number, data, worker, task)
        resends = [0] * len(chunks)
        finished = distributed.as_completed(with_results=True, raise_errors=False)  # gathered as each finishes

        def send() -> None:
            """Send waiting chunks to the idle worker threads, each chunk's items scattered to its worker."""
            slots = self._free_slots()
            for _, _, addr, _ in running.values():
                if addr in slots:
                    slots.remove(addr)
            if not slots and not running and waiting:  # every worker died: wait for the nanny's new ones
                client.wait_for_workers(1, timeout=120)
                slots = self._free_slots()
            while waiting and slots:
                k, addr = waiting.pop(), slots.pop(0)
                if shared_futures[-1].status != "finished":  # its last copy went with a dead worker
                    shared_futures.append(client.scatter([shared], broadcast=True, hash=False)[0])
                (data,) = client.scatter([[items[i] for i in chunks[k]]], workers=[addr], hash=False)
                fut = client.submit(
                    _run_chunk, fn, data, shared_futures[-1], pure=False, workers=[addr], allow_other_workers=True
                )
                running[fut.key] = (k, data, addr, fut)
                finished.add(fut)

        order = InputOrder(n)
        done = failed = 0
        try:
            send()
            for fut, value in finished:
                k, data, _, _ = running.pop(fut.key)
                idx = chunks[k]
                results = self._results_of(fut, value, idx, distributed, resend=resends[k] < _LOST_DATA_RESENDS)
                data.release()
                fut.release()  # its result is here: the scheduler must not recompute it when its worker dies
                if results is None:  # its data died with a worker: send it again, first
                    resends[k] += 1
                    waiting.append(k)
                send()  # the next chunk runs while the consumer takes these results
                if results is None:
                    continue
                done += len(idx)
                failed += sum(isinstance(r, TaskFailure) for r in results)
                if progress is not None:
                    progress(done, n, failed)
                yield from order.add(idx, results)
        finally:  # Ctrl-C, an error in the consumer, or an abandoned generator: nothing keeps running
            if running:
                client.cancel([task for _, _, _, task in running.values()])
            for _, data, _, _ in running.values():
                data.release()
            for f in shared_futures:
                f.release()

    @staticmethod
    def _results_of(fut: Any, value: Any, idx: Sequence[int], distributed: Any, *, resend: bool) -> Sequence[Any] | None:
        """The chunk's results, a failure per item, or None: its data died with a worker (``resend``).

        ``value`` is what ``as_completed(with_results=True, raise_errors=False)`` gathered: the result list, the
        ``(type, exception, traceback)`` of a task that raised, or the ``CancelledError`` of a cancelled one.
        """
        if isinstance(value, list):
            return value
        exc = value[1] if isinstance(value, tuple) and len(value) == 3 else value
        if not isinstance(exc, BaseException):  # pragma: no cover - as_completed gives one of the three above
            exc = RuntimeError(f"unexpected value from Dask for {fut.key}: {type(value).__name__}")
        if isinstance(exc, distributed.KilledWorker):
            log.warning("the worker running %d items died: %s", len(idx), exc)
            return [failure_of(exc, worker_died=True)] * len(idx)
        if isinstance(exc, CancelledError):  # not by this generator: by the scheduler, its input died with a worker
            if resend:
                log.warning("the worker holding a chunk of %d items died; sending the chunk again", len(idx))
                return None
            log.warning("a chunk of %d items was lost with a dying worker once more than allowed: %s", len(idx), exc)
            return [failure_of(exc, worker_died=True)] * len(idx)
        # the chunk's function raised in the worker
        log.warning("a chunk of %d items failed: %s: %s", len(idx), type(exc).__name__, exc)
        return [failure_of(exc)] * len(idx)


def executor_from_options(workers: int | None = None, scheduler: str | None = None) -> SerialExecutor | DaskExecutor:
    """The executor a command line asks for: ``--workers N`` (a local cluster), ``--scheduler ADDRESS``, else
    ``$DASK_SCHEDULER_ADDRESS`` when set, else in process. Not started yet: use it in a ``with`` block."""
    if workers is not None or scheduler is not None:
        return DaskExecutor(workers=workers, scheduler=scheduler)
    if os.environ.get(SCHEDULER_ENV):
        return DaskExecutor()
    return SerialExecutor()

"""The executor protocol, the in-process executor and the chunking rule they share."""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Hashable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, Protocol, TypeVar, runtime_checkable

from factorloc.errors import InputError

log = logging.getLogger(__name__)

__all__ = ["Executor", "ItemsProgress", "SerialExecutor", "TaskFailure", "chunk_indices"]

T = TypeVar("T")
R = TypeVar("R")

#: ``progress(items_done, items_total, items_failed)``, called as chunks complete (in any order).
ItemsProgress = Callable[[int, int, int], None]

#: ``fn(chunk, shared) -> results``: one result per item of the chunk, in the chunk's order; ``shared`` is the
#: object given to :meth:`Executor.map_chunks` (sent once to each worker: what every chunk needs).
ChunkFunction = Callable[[Sequence[Any], Any], Sequence[Any]]


@dataclass(frozen=True)
class TaskFailure:
    """The result of an item whose whole chunk failed: ``error`` is ``"<ExceptionType>: <message>"``.

    ``worker_died`` is True when the worker running it was lost (Dask's ``KilledWorker``) rather than the
    chunk's function raising.
    """

    error: str
    worker_died: bool = False


def chunk_indices(n: int, chunk_size: int, group: Sequence[Hashable] | None = None) -> list[list[int]]:
    """Split ``range(n)`` into chunks of at most ``chunk_size`` indices, none mixing two values of ``group``.

    Items of one group keep their input order inside their chunks; the chunks are ordered by their first index.
    ``group[i]`` is the key of item ``i`` (e.g. the reference a query is localized against: each chunk then
    prepares one reference once).
    """
    if chunk_size < 1:
        raise InputError(f"chunk_size must be >= 1, got {chunk_size!r}")
    if group is not None and len(group) != n:
        raise InputError(f"group must have one key per item ({n}), got {len(group)}")
    by_key: dict[Hashable, list[int]] = {}
    for i in range(n):
        by_key.setdefault(None if group is None else group[i], []).append(i)
    chunks = [idx[k : k + chunk_size] for idx in by_key.values() for k in range(0, len(idx), chunk_size)]
    return sorted(chunks, key=lambda c: c[0])


def default_chunk_size(n: int, workers: int, chunks_per_worker: int) -> int:
    """``ceil(n / (workers × chunks_per_worker))``, at least 1: a few chunks per worker balance the load."""
    return max(1, math.ceil(n / max(1, workers * chunks_per_worker)))


@runtime_checkable
class Executor(Protocol):
    """Runs ``fn(chunk, shared)`` on chunks of ``items`` and yields one result per item, in input order.

    ``chunk_size=None`` lets the executor choose; ``group`` keeps items of different keys in different chunks
    (:func:`chunk_indices`). ``shared`` reaches every chunk's function: it is sent once to each worker process
    and is the same object for all the chunks a process runs, so a function may memoize per-process work in it
    (a reference prepared once per worker). ``progress(done, total, failed)`` is called with item counts as
    chunks finish. An item whose chunk raised or whose worker died yields a :class:`TaskFailure`.
    """

    @property
    def workers(self) -> int:
        """How many chunks run at once (1 in process)."""
        ...

    def map_chunks(
        self,
        fn: ChunkFunction,
        items: Sequence[Any],
        chunk_size: int | None = None,
        *,
        group: Sequence[Hashable] | None = None,
        shared: Any = None,
        progress: ItemsProgress | None = None,
    ) -> Iterator[Any]: ...


def check_results(results: Sequence[Any], chunk: Sequence[Any]) -> Sequence[Any]:
    """``results`` of one chunk, checked to hold one result per item."""
    if len(results) != len(chunk):
        raise InputError(f"a chunk function returned {len(results)} results for {len(chunk)} items")
    return results


class InputOrder:
    """Buffers per-chunk results and releases them in input order (chunks may finish in any order)."""

    def __init__(self, n: int) -> None:
        self._results: list[Any] = [None] * n
        self._ready = [False] * n
        self._next = 0

    def add(self, idx: Sequence[int], results: Sequence[Any]) -> Iterator[Any]:
        """Store the results of the items ``idx``; yield every result now ready in input order."""
        for i, r in zip(idx, results, strict=True):
            self._results[i], self._ready[i] = r, True
        while self._next < len(self._ready) and self._ready[self._next]:
            yield self._results[self._next]
            self._results[self._next] = None
            self._next += 1


def failure_of(exc: BaseException, *, worker_died: bool = False) -> TaskFailure:
    """The :class:`TaskFailure` of an exception."""
    return TaskFailure(f"{type(exc).__name__}: {exc}", worker_died)


class SerialExecutor:
    """Runs every chunk in this process, one after another: the default (no new import).

    ``chunk_size=None`` makes one chunk per item (progress after each; what a chunk function memoizes in
    ``shared``, e.g. a prepared reference, serves all of them).
    """

    @property
    def workers(self) -> int:
        return 1

    def __enter__(self) -> SerialExecutor:
        return self

    def __exit__(self, *exc: object) -> None:
        return None

    def close(self) -> None:
        """Nothing to release."""

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
        n = len(items)
        done = failed = 0
        order = InputOrder(n)
        for idx in chunk_indices(n, chunk_size or 1, group):
            chunk = [items[i] for i in idx]
            try:
                results: Sequence[Any] = check_results(fn(chunk, shared), chunk)
            except Exception as exc:  # reported per item by the caller; the batch goes on
                log.warning("a chunk of %d items failed: %s: %s", len(chunk), type(exc).__name__, exc)
                results = [failure_of(exc)] * len(chunk)
            done += len(chunk)
            failed += sum(isinstance(r, TaskFailure) for r in results)
            if progress is not None:
                progress(done, n, failed)
            yield from order.add(idx, results)

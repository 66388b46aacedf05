"""The evaluation runner: localize every query of a scenario, score it against ground truth.

Two stages, so that several fusion strategies can be compared on the same
estimator outputs without running the (expensive) estimators again:

1. :func:`run_hierarchy` runs :meth:`factorloc.Localizer.localize` once per
   query and keeps every step's report (estimate, verdict, run time):
   a :class:`HierarchyRun`.
2. :func:`evaluate` fuses those reports with a strategy object and scores
   the results: an :class:`~factorloc.evaluation.report.EvaluationReport` whose
   :meth:`~factorloc.evaluation.report.EvaluationReport.summary` holds the figures documented in
   ``docs/evaluation.md`` (``to_json()``: their stable keys).

A strategy is either a per-query :class:`~factorloc.fusion.base.FusionStrategy`
(the reliable estimates of one query are gated with ``config.gating`` and
fused, exactly as :meth:`~factorloc.Localizer.localize` does) or a
:class:`~factorloc.fusion.base.SequentialStrategy` (reset once, then fed the
step reports query after query in scenario order).

Example
-------
>>> from factorloc.datasets import load_scenario                       # doctest: +SKIP
>>> from factorloc.evaluation import run_hierarchy, evaluate           # doctest: +SKIP
>>> run = run_hierarchy(load_scenario("data/sample"))                  # doctest: +SKIP
>>> graph = evaluate(run)                                              # doctest: +SKIP
>>> product = evaluate(run, factorloc.ProductFusion())                 # doctest: +SKIP
>>> graph.summary().overall.position_rmse_m                            # doctest: +SKIP
"""

from __future__ import annotations

import collections
import logging
import math
import resource
import sys
import threading
import time
import uuid
import weakref
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from factorloc.config import Config
from factorloc.errors import InputError
from factorloc.estimators.base import Step
from factorloc.evaluation import metrics
from factorloc.evaluation.cases import Case, EvaluationSet, evaluation_set
from factorloc.evaluation.report import OVERLAP_RADIUS_M, EvaluationReport
from factorloc.fusion.base import FusionStrategy, SequentialStrategy, mark_undetermined
from factorloc.gating import StepRun, gate
from factorloc.geometry import Pose2
from factorloc.parallel import Executor, SerialExecutor, TaskFailure
from factorloc.parallel.base import failure_of
from factorloc.pipeline import Localizer, default_steps, fuse_gated
from factorloc.types import Localization, Reference, StepReport

log = logging.getLogger(__name__)

__all__ = [
    "HierarchyRun",
    "QueryFailure",
    "QueryResult",
    "QueryRun",
    "evaluate",
    "run_hierarchy",
    "view_overlap",
]

Progress = Callable[[int, int], None]


# --------------------------------------------------------------------------
# Stage 1: the hierarchy, once per query
# --------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class QueryRun:
    """The hierarchy's output on one query: step reports and run times (s)."""

    index: int
    case: Case
    reports: tuple[StepReport, ...]
    localization: Localization
    localize_seconds: float

    @property
    def steps_seconds(self) -> float:
        """Sum of the steps' run times (s), without gating and fusion."""
        return float(sum(r.seconds for r in self.reports))


@dataclass(frozen=True, eq=False)
class HierarchyRun:
    """The estimators' outputs on every query of an evaluation set, reusable by any strategy.

    ``peak_memory_mb`` is the process's peak resident set size after the run
    (``getrusage(RUSAGE_SELF).ru_maxrss``): it includes the loaded scenario.
    ``prepare_seconds`` is each step's reference-only work, summed over the
    references used (and over the worker processes, each of which prepares a
    reference once). With workers, ``peak_memory_mb`` is the largest of this
    process's and the workers'. ``failures`` are the queries that raised (not in ``runs``);
    ``preparations`` counts the references prepared (once per reference and process).
    """

    dataset: EvaluationSet
    config: Config
    seeded: bool
    runs: tuple[QueryRun, ...]
    prepare_seconds: dict[str, float]
    peak_memory_mb: float
    step_names: tuple[str, ...]
    failures: tuple[QueryFailure, ...] = ()
    preparations: int = 0


def peak_memory_mb() -> float:
    """The process's peak resident set size so far (MiB)."""
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return float(rss) / (1024.0 * 1024.0) if sys.platform == "darwin" else float(rss) / 1024.0


@dataclass(frozen=True)
class QueryFailure:
    """A query the hierarchy could not run: its position in the set, its id and the error
    (``"<ExceptionType>: <message>"``); ``worker_died`` when the worker running it was lost."""

    index: int
    query_id: str
    error: str
    worker_died: bool = False


@dataclass(frozen=True, eq=False)
class _Localized:
    """What a worker sends back for one query (the driver adds the case it already holds)."""

    localization: Localization
    seconds: float
    prepare_seconds: dict[str, float] | None = None  # when its Localizer was prepared for it
    peak_memory_mb: float = math.nan  # the worker's peak RSS


@dataclass(frozen=True, eq=False)
class _Batch:
    """What every chunk of a :func:`run_hierarchy` needs; sent once to each worker.

    ``localizers`` is filled by the process that runs the chunks (its own copy on each worker): each process
    prepares each reference once.
    """

    references: Mapping[str, Reference]
    config: Config
    steps: Sequence[Step] | None
    seeded: bool
    token: str = field(default_factory=lambda: uuid.uuid4().hex)
    localizers: dict[str, Localizer] = field(default_factory=dict)

    def __reduce__(self) -> tuple[Any, ...]:
        # sent without the process's own localizers: a prepared reference holds native objects that cannot be
        # pickled (small_gicp's KdTree), and a Dask worker that fetches this batch from another worker after
        # that one used it would otherwise fail the transfer and wait on it for ever. A process that receives
        # the batch again gets the copy it already holds back (:func:`_restore_batch`), localizers included
        return (_restore_batch, (self.references, self.config, self.steps, self.seeded, self.token))

    def localizer(self, reference_id: str) -> tuple[Localizer, bool]:
        """The process's :class:`Localizer` of ``reference_id`` and whether it was prepared just now."""
        loc = self.localizers.get(reference_id)
        if loc is not None:
            return loc, False
        loc = self.localizers[reference_id] = Localizer(self.references[reference_id], self.config, steps=self.steps)
        return loc, True


#: The batches this process holds, by token: a copy received again is the same object (each reference prepared
#: once per process); weak, so a finished batch goes with its localizers.
_BATCHES: weakref.WeakValueDictionary[str, _Batch] = weakref.WeakValueDictionary()
#: The last few batches this process restored, held strongly. Dask may drop a worker's replica of the shared batch
#: while none of that worker's waiting tasks needs it (its active memory manager reduces replicas) and send it
#: again for a later task; without this the first copy, and its prepared references, would be gone by then.
_RECENT_BATCHES: collections.deque[_Batch] = collections.deque(maxlen=4)
_RESTORE_LOCK = threading.Lock()  # a worker may deserialize two copies at once (its comm and task threads)


def _restore_batch(
    references: Mapping[str, Reference], config: Config, steps: Sequence[Step] | None, seeded: bool, token: str
) -> _Batch:
    """Unpickling a :class:`_Batch`: this process's copy of it when it has one, else a new one."""
    with _RESTORE_LOCK:
        batch = _BATCHES.get(token)
        if batch is None:
            batch = _BATCHES[token] = _Batch(references, config, steps, seeded, token)
        if not any(b is batch for b in _RECENT_BATCHES):
            _RECENT_BATCHES.append(batch)
        return batch


def _localize_chunk(chunk: Sequence[Case], batch: _Batch) -> list[_Localized | TaskFailure]:
    """Localize the queries of one chunk (one reference, prepared once per process); each query is timed on its
    own; a query that raises gives a :class:`TaskFailure` and the others go on."""
    localizer, fresh = batch.localizer(chunk[0].reference_id)
    out: list[_Localized | TaskFailure] = []
    for case in chunk:
        t0 = time.perf_counter()
        try:
            loc = localizer.localize(case.query, seeded=batch.seeded)
        except Exception as exc:  # counted and reported by id; the batch goes on
            log.warning("query %r failed: %s: %s", case.query.id, type(exc).__name__, exc)
            out.append(failure_of(exc))
            continue
        dt = time.perf_counter() - t0
        # a fresh preparation and the worker's peak memory ride on the chunk's first successful query
        extra = (dict(localizer.prepare_seconds) if fresh else None, peak_memory_mb())
        fresh = False
        out.append(_Localized(loc, dt, *extra))
    return out


def run_hierarchy(
    scenario: Any,
    config: Config | None = None,
    *,
    seeded: bool = True,
    steps: Sequence[Step] | None = None,
    progress: Progress | None = None,
    executor: Executor | None = None,
    chunk_size: int | None = None,
    on_failure: Callable[[QueryFailure], None] | None = None,
) -> HierarchyRun:
    """Run :meth:`factorloc.Localizer.localize` on every query, keeping the step reports.

    Parameters
    ----------
    scenario
        A :class:`factorloc.datasets.Scenario` or an :class:`EvaluationSet`.
    config
        The configuration (defaults if None).
    seeded
        False runs every step blind (no hypotheses from its predecessors).
    steps
        Override the steps (default: the configured hierarchy; sent to the workers: picklable).
    progress
        Called as ``progress(done, total)`` as queries finish.
    executor
        Where the queries run (:mod:`factorloc.parallel`; default in this process). The queries are split in
        chunks of one reference each; each process prepares a reference once (:class:`~factorloc.Localizer`),
        each query is timed by the worker that ran it. The results do not depend on the executor.
    chunk_size
        Queries per chunk (default: the executor's choice; in process, one).
    on_failure
        Called with each :class:`QueryFailure` as it is known (a query that raised, a worker that died).

    Returns
    -------
    HierarchyRun
        The runs of the queries that ran, in input order; ``failures`` the others.
    """
    data = evaluation_set(scenario)
    cfg = config or Config()
    if not isinstance(cfg, Config):
        raise InputError(f"config must be a factorloc.Config or None, got {type(cfg).__name__}")
    step_names = tuple(s.name for s in (default_steps(cfg) if steps is None else steps))
    ex = executor if executor is not None else SerialExecutor()
    references = {case.reference_id: data.reference_of(case) for case in data.cases}
    batch = _Batch(references, cfg, None if steps is None else tuple(steps), bool(seeded))
    cb = None if progress is None else (lambda done, total, failed: progress(done, total))
    prepare_seconds: dict[str, float] = {}
    preparations = 0
    runs: list[QueryRun] = []
    failures: list[QueryFailure] = []
    peak = peak_memory_mb()
    group = [case.reference_id for case in data.cases]
    results = ex.map_chunks(_localize_chunk, data.cases, chunk_size, group=group, shared=batch, progress=cb)
    for i, result in enumerate(results):
        case = data.cases[i]
        if isinstance(result, TaskFailure):
            failure = QueryFailure(i, case.query.id, result.error, result.worker_died)
            failures.append(failure)
            if on_failure is not None:
                on_failure(failure)
            continue
        if result.prepare_seconds is not None:  # reference-only work, once per reference and process
            preparations += 1
            for name, sec in result.prepare_seconds.items():
                prepare_seconds[name] = prepare_seconds.get(name, 0.0) + sec
        if math.isfinite(result.peak_memory_mb):
            peak = max(peak, result.peak_memory_mb)
        runs.append(QueryRun(i, case, result.localization.steps, result.localization, result.seconds))
    return HierarchyRun(
        data,
        cfg,
        bool(seeded),
        tuple(runs),
        prepare_seconds,
        max(peak, peak_memory_mb()),
        step_names,
        tuple(failures),
        preparations,
    )


# --------------------------------------------------------------------------
# Stage 2: fuse with a strategy, score
# --------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class QueryResult:
    """One query's fused result and everything needed to score it.

    ``pose`` and ``covariance`` (3×3, world frame, m² and rad², ``inf``
    variance where under-determined) are the strategy's answer;
    ``latency_s`` = the steps' time + the strategy's gating/fusion/update time.
    ``view_overlap`` is :func:`view_overlap` of the query (``nan`` when unknown).
    """

    index: int
    query_id: str
    truth: Pose2 | None
    faults: tuple[str, ...]
    pose: Pose2
    covariance: np.ndarray
    reports: tuple[StepReport, ...]
    latency_s: float
    strategy_s: float
    distance_to_reference_m: float
    view_overlap: float = math.nan

    @property
    def determined(self) -> np.ndarray:
        """3 bools: which of (x, y, θ) the result determines."""
        return metrics.determined_mask(self.covariance)[0]

    @property
    def error(self) -> np.ndarray:
        """``estimate − truth`` (m, m, rad; ``nan`` where undetermined or no truth)."""
        if self.truth is None:
            return np.full(3, np.nan)
        err = metrics.pose_errors(self.pose.as_array()[None], self.truth.as_array()[None])[0]
        err[~self.determined] = np.nan
        return err


def _distance(case: Case, reference: Reference) -> float:
    if case.distance_from_reference_m is not None:
        return float(case.distance_from_reference_m)
    if case.truth is None:
        return math.nan
    return float(math.hypot(case.truth.x - reference.T_world_reference.x, case.truth.y - reference.T_world_reference.y))


def _range_points(sensor: Any) -> np.ndarray | None:
    return None if sensor is None or len(sensor) == 0 else np.asarray(sensor.points_m)[:, :2]


def view_overlap(case: Case, reference: Reference, radius_m: float = OVERLAP_RADIUS_M, *, _tree: Any = None) -> float:
    """Fraction of what the query's range sensor saw that the reference saw too (ground truth needed).

    The query's scan (else its depth cloud), placed in the world by its
    **true** pose, against the reference's scan and cloud placed by
    ``T_world_reference``: :func:`metrics.overlap_fraction` in the plane with
    ``radius_m`` (5 cm: the simulated sensors' noise plus the reference
    cloud's point spacing at a few metres). The query *has an overlapping
    view* when this is at least :data:`OVERLAP_MIN_FRACTION`: the two
    observed a common part of the world, so localizing against this
    reference is possible in principle. ``nan`` without truth or without
    range data on either side (camera-only queries or references).
    """
    if case.truth is None:
        return math.nan
    pts = _range_points(case.query.scan)
    if pts is None:
        pts = _range_points(case.query.cloud)
    if pts is None:
        return math.nan
    tree = _tree if _tree is not None else _reference_tree(reference)
    if tree is None:
        return math.nan
    return metrics.overlap_fraction(case.truth.transform_points(pts), tree, radius_m)


def _reference_tree(reference: Reference) -> Any:
    from scipy.spatial import cKDTree

    parts = [p for p in (_range_points(reference.scan), _range_points(reference.cloud)) if p is not None]
    if not parts:
        return None
    return cKDTree(reference.T_world_reference.transform_points(np.vstack(parts)))


def _view_overlaps(run: HierarchyRun) -> list[float]:
    trees: dict[str, Any] = {}
    out = []
    for qr in run.runs:
        rid = qr.case.reference_id
        if rid not in trees:
            trees[rid] = _reference_tree(run.dataset.reference_of(qr.case))
        tree = trees[rid]
        out.append(math.nan if tree is None else view_overlap(qr.case, run.dataset.reference_of(qr.case), _tree=tree))
    return out


def _fuse_per_query(run: HierarchyRun, strategy: FusionStrategy) -> list[QueryResult]:
    out = []
    overlaps = _view_overlaps(run)
    for qr, overlap in zip(run.runs, overlaps, strict=True):
        t0 = time.perf_counter()
        gating = run.config.gating
        loc = fuse_gated(gate([StepRun.of_report(r) for r in qr.reports], gating), strategy, gating=gating)
        dt = time.perf_counter() - t0
        out.append(
            QueryResult(
                qr.index,
                qr.case.query.id,
                qr.case.truth,
                qr.case.faults,
                loc.pose,
                np.array(loc.covariance),
                loc.steps,
                qr.steps_seconds + dt,
                dt,
                _distance(qr.case, run.dataset.reference_of(qr.case)),
                overlap,
            )
        )
    return out


def _fuse_sequential(run: HierarchyRun, strategy: SequentialStrategy) -> list[QueryResult]:
    out = []
    overlaps = _view_overlaps(run)
    strategy.reset()
    for qr, overlap in zip(run.runs, overlaps, strict=True):
        t0 = time.perf_counter()
        fused = strategy.update(qr.case.query, qr.reports)
        dt = time.perf_counter() - t0
        cov = np.array(fused.covariance, dtype=np.float64)
        if cov.shape != (3, 3):
            raise InputError(f"strategy {strategy.name!r} returned a covariance of shape {cov.shape}, expected 3×3")
        cov = mark_undetermined(cov, fused.undetermined)
        out.append(
            QueryResult(
                qr.index,
                qr.case.query.id,
                qr.case.truth,
                qr.case.faults,
                fused.pose,
                cov,
                qr.reports,
                qr.steps_seconds + dt,
                dt,
                _distance(qr.case, run.dataset.reference_of(qr.case)),
                overlap,
            )
        )
    return out


def evaluate(
    scenario: Any,
    strategy: FusionStrategy | SequentialStrategy | None = None,
    config: Config | None = None,
    *,
    seeded: bool = True,
    steps: Sequence[Step] | None = None,
    progress: Progress | None = None,
    executor: Executor | None = None,
    chunk_size: int | None = None,
    on_failure: Callable[[QueryFailure], None] | None = None,
) -> EvaluationReport:
    """Localize every query of ``scenario`` and score accuracy, honesty, availability and speed.

    Parameters
    ----------
    scenario
        A :class:`factorloc.datasets.Scenario`, an :class:`EvaluationSet`, or a
        :class:`HierarchyRun` from :func:`run_hierarchy` (the estimators are
        then not run again; ``config``, ``seeded`` and ``steps`` must be left
        at their defaults or match the run).
    strategy
        A :class:`~factorloc.fusion.base.FusionStrategy` (per query) or a
        :class:`~factorloc.fusion.base.SequentialStrategy` (memory across
        queries, fed in scenario order). Default: the one ``config.fusion`` names.
    config
        As in :func:`run_hierarchy`.
    seeded
        As in :func:`run_hierarchy`.
    steps
        As in :func:`run_hierarchy`.
    progress
        As in :func:`run_hierarchy`.
    executor
        As in :func:`run_hierarchy`: where the hierarchy runs (the fusion and the scoring run here). The
        report's summary counts the failed queries (``failed_queries``) and scores the others.
    chunk_size
        As in :func:`run_hierarchy`.
    on_failure
        As in :func:`run_hierarchy`.

    Returns
    -------
    EvaluationReport
        Per-query results and the metrics of ``docs/evaluation.md``.
    """
    if isinstance(scenario, HierarchyRun):
        run = scenario
        if config is not None and config != run.config:
            raise InputError("evaluate(run, config=...): the config differs from the one the HierarchyRun was made with")
        if not seeded and run.seeded:
            raise InputError("evaluate(run, seeded=False): the HierarchyRun was made seeded; run run_hierarchy(seeded=False)")
        if steps is not None:
            raise InputError("evaluate(run, steps=...): steps cannot change once the HierarchyRun is made")
    else:
        run = run_hierarchy(
            scenario,
            config,
            seeded=seeded,
            steps=steps,
            progress=progress,
            executor=executor,
            chunk_size=chunk_size,
            on_failure=on_failure,
        )
    if strategy is None:
        from factorloc.pipeline import strategy_for

        strategy = strategy_for(run.config)
    if isinstance(strategy, SequentialStrategy):
        results = _fuse_sequential(run, strategy)
    elif isinstance(strategy, FusionStrategy):
        results = _fuse_per_query(run, strategy)
    else:
        raise InputError(
            "strategy must implement FusionStrategy (name, fuse) or SequentialStrategy (name, reset, update), "
            f"got {type(strategy).__name__}"
        )
    return EvaluationReport(run, str(strategy.name), tuple(results))

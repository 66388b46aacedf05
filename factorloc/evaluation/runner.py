"""The evaluation runner: localize every query of a scenario, score it against ground truth.

Two stages, so that several fusion strategies can be compared on the same
estimator outputs without running the (expensive) estimators again:

1. :func:`run_hierarchy` runs :meth:`factorloc.Localizer.localize` once per
   query and keeps every step's report (estimate, verdict, run time):
   a :class:`HierarchyRun`.
2. :func:`evaluate` fuses those reports with a strategy object and scores
   the results: an :class:`EvaluationReport` whose
   :meth:`~EvaluationReport.to_json_dict` holds the stable keys documented in
   ``docs/evaluation.md``.

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
>>> graph.to_json_dict()["position_rmse_m"]                            # doctest: +SKIP
"""

from __future__ import annotations

import logging
import math
import re
import resource
import sys
import time
from collections import Counter
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np

from factorloc.config import Config
from factorloc.errors import InputError
from factorloc.estimators.base import Step
from factorloc.evaluation import metrics
from factorloc.fusion.base import FusionStrategy, SequentialStrategy
from factorloc.geometry import Pose2
from factorloc.pipeline import Localizer, fuse
from factorloc.types import Localization, Query, Reference, StepReport, StepStatus

if TYPE_CHECKING:  # pragma: no cover
    from factorloc.sim.world import World

log = logging.getLogger(__name__)

__all__ = [
    "Case",
    "EvaluationReport",
    "EvaluationSet",
    "HierarchyRun",
    "QueryResult",
    "QueryRun",
    "OVERLAP_MIN_FRACTION",
    "OVERLAP_RADIUS_M",
    "SCHEMA_VERSION",
    "evaluate",
    "evaluation_set",
    "run_hierarchy",
    "view_overlap",
]

#: Version of the JSON written by :meth:`EvaluationReport.to_json_dict`.
SCHEMA_VERSION = 1

#: The id under which a single reference is stored.
DEFAULT_REFERENCE = "ref0"

#: The tag under ``by_fault`` that collects queries without any fault tag.
NO_FAULT = "none"

#: A query point overlaps the reference when a reference surface point lies within this radius (m, in the plane).
OVERLAP_RADIUS_M = 0.05

#: A query *has an overlapping view* when at least this fraction of its range points overlap the reference.
OVERLAP_MIN_FRACTION = 0.3

Progress = Callable[[int, int], None]


# --------------------------------------------------------------------------
# What is evaluated
# --------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class Case:
    """One query with its ground truth.

    Parameters
    ----------
    query
        What the robot sensed.
    truth
        The true ``T_world_robot`` (None: the query is run and timed but not scored).
    faults
        Fault tags of the query (``"kidnapped"``, ``"occlusion"``, …; empty when clean).
    reference_id
        The reference (of the :class:`EvaluationSet`) it is localized against.
    distance_from_reference_m
        Distance of the true pose from that reference's pose (m); computed
        from ``truth`` when None.
    """

    query: Query
    truth: Pose2 | None = None
    faults: tuple[str, ...] = ()
    reference_id: str = DEFAULT_REFERENCE
    distance_from_reference_m: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.query, Query):
            raise InputError(f"Case.query must be a factorloc.Query, got {type(self.query).__name__}")
        if self.truth is not None and not isinstance(self.truth, Pose2):
            raise InputError(f"Case.truth must be a Pose2 or None, got {type(self.truth).__name__}")
        faults = (self.faults,) if isinstance(self.faults, str) else tuple(self.faults)
        for f in faults:
            if not isinstance(f, str) or not f:
                raise InputError(f"Case.faults must be non-empty strings, got {f!r} in query {self.query.id!r}")
        object.__setattr__(self, "faults", faults)
        if not isinstance(self.reference_id, str) or not self.reference_id:
            raise InputError(f"Case.reference_id must be a non-empty string, got {self.reference_id!r}")


@dataclass(frozen=True, eq=False)
class EvaluationSet:
    """References and the cases to localize against them, in scenario (time) order.

    :func:`evaluation_set` builds one from a :class:`factorloc.datasets.Scenario`;
    tests and notebooks may build one directly. ``references`` maps ids to
    references (a single :class:`~factorloc.Reference` is stored under
    ``"ref0"``); ``world`` (optional) is the floor plan the figures draw.
    """

    references: Mapping[str, Reference] | Reference
    cases: tuple[Case, ...]
    name: str = "scenario"
    world: World | None = None

    def __post_init__(self) -> None:
        refs = {DEFAULT_REFERENCE: self.references} if isinstance(self.references, Reference) else dict(self.references)
        if not refs:
            raise InputError(f"EvaluationSet({self.name}).references is empty")
        for k, r in refs.items():
            if not isinstance(r, Reference):
                raise InputError(f"EvaluationSet.references[{k!r}] must be a factorloc.Reference, got {type(r).__name__}")
        object.__setattr__(self, "references", MappingProxyType(refs))
        cases = tuple(self.cases)
        if not cases:
            raise InputError(f"EvaluationSet({self.name}).cases is empty: nothing to evaluate")
        for i, c in enumerate(cases):
            if not isinstance(c, Case):
                raise InputError(f"EvaluationSet.cases[{i}] must be a Case, got {type(c).__name__}")
            if c.reference_id not in refs:
                raise InputError(
                    f"EvaluationSet.cases[{i}] ({c.query.id}) names reference {c.reference_id!r}, not one of {sorted(refs)}"
                )
        object.__setattr__(self, "cases", cases)

    def reference_of(self, case: Case) -> Reference:
        """The reference ``case`` is localized against."""
        return self.references[case.reference_id]


def evaluation_set(scenario: Any) -> EvaluationSet:
    """The :class:`EvaluationSet` of ``scenario`` (an ``EvaluationSet`` is returned as is).

    Accepts a :class:`factorloc.datasets.Scenario`: its references, its
    queries (in scenario order) with their ground truth, fault tags and
    reference, and its world when known.
    """
    if isinstance(scenario, EvaluationSet):
        return scenario
    from factorloc.datasets.scenario import Scenario

    if not isinstance(scenario, Scenario):
        raise InputError(f"scenario must be a factorloc.datasets.Scenario or an EvaluationSet, got {type(scenario).__name__}")
    cases = tuple(Case(q.query, q.truth, tuple(q.faults), q.reference_id, q.distance_from_reference_m) for q in scenario.queries)
    refs = {r.id: r.reference for r in scenario.references}
    return EvaluationSet(refs, cases, name=scenario.name, world=scenario.world)


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
    references used.
    """

    dataset: EvaluationSet
    config: Config
    seeded: bool
    runs: tuple[QueryRun, ...]
    prepare_seconds: dict[str, float]
    peak_memory_mb: float
    step_names: tuple[str, ...]


def peak_memory_mb() -> float:
    """The process's peak resident set size so far (MiB)."""
    rss = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    return float(rss) / (1024.0 * 1024.0) if sys.platform == "darwin" else float(rss) / 1024.0


def run_hierarchy(
    scenario: Any,
    config: Config | None = None,
    *,
    seeded: bool = True,
    steps: Sequence[Step] | None = None,
    progress: Progress | None = None,
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
        Override the steps (default: the configured hierarchy).
    progress
        Called as ``progress(done, total)`` after each query.
    """
    data = evaluation_set(scenario)
    cfg = config or Config()
    if not isinstance(cfg, Config):
        raise InputError(f"config must be a factorloc.Config or None, got {type(cfg).__name__}")
    localizers: dict[str, Localizer] = {}
    prepare_seconds: dict[str, float] = {}
    runs = []
    total = len(data.cases)
    for i, case in enumerate(data.cases):
        localizer = localizers.get(case.reference_id)
        if localizer is None:  # reference-only work, once per reference used
            localizer = localizers[case.reference_id] = Localizer(data.reference_of(case), cfg, steps=steps)
            for name, sec in localizer.prepare_seconds.items():
                prepare_seconds[name] = prepare_seconds.get(name, 0.0) + sec
        t0 = time.perf_counter()
        loc = localizer.localize(case.query, seeded=seeded)
        dt = time.perf_counter() - t0
        runs.append(QueryRun(i, case, loc.steps, loc, dt))
        if progress is not None:
            progress(i + 1, total)
    return HierarchyRun(
        data,
        cfg,
        bool(seeded),
        tuple(runs),
        prepare_seconds,
        peak_memory_mb(),
        tuple(s.name for s in next(iter(localizers.values())).steps),
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


def _normalize_reason(reason: str) -> str:
    """A reason with its numbers replaced by ``#`` so that equal causes count together."""
    text = re.sub(r"(?<![^\W\d_])[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?", "#", reason)  # not "θ2", "χ²"
    return re.sub(r"\s+", " ", text).strip() or "(no reason given)"


def _merge(original: tuple[StepReport, ...], refused: Localization) -> tuple[StepReport, ...]:
    """The re-gated reports of ``refused`` with the steps' original run times and skipped/failed reports."""
    it = iter(refused.steps)
    out = []
    for r in original:
        if r.estimate is None:
            out.append(r)
        else:
            g = next(it)
            out.append(StepReport(r.name, g.status, r.estimate, g.reason, r.seconds))
    return tuple(out)


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
    for qr in run.runs:
        estimates = [r.estimate for r in qr.reports if r.estimate is not None]
        t0 = time.perf_counter()
        loc = fuse(estimates, strategy=strategy, gating=run.config.gating)
        dt = time.perf_counter() - t0
        out.append(
            QueryResult(
                qr.index,
                qr.case.query.id,
                qr.case.truth,
                qr.case.faults,
                loc.pose,
                np.array(loc.covariance),
                _merge(qr.reports, loc),
                qr.steps_seconds + dt,
                dt,
                _distance(qr.case, run.dataset.reference_of(qr.case)),
                overlaps[qr.index],
            )
        )
    return out


def _fuse_sequential(run: HierarchyRun, strategy: SequentialStrategy) -> list[QueryResult]:
    out = []
    overlaps = _view_overlaps(run)
    strategy.reset()
    for qr in run.runs:
        t0 = time.perf_counter()
        fused = strategy.update(qr.case.query, qr.reports)
        dt = time.perf_counter() - t0
        cov = np.array(fused.covariance, dtype=np.float64)
        if cov.shape != (3, 3):
            raise InputError(f"strategy {strategy.name!r} returned a covariance of shape {cov.shape}, expected 3×3")
        for c in fused.undetermined:
            i = {"x": 0, "y": 1, "theta": 2}[c.value]
            cov[i, :] = 0.0
            cov[:, i] = 0.0
            cov[i, i] = math.inf
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
                overlaps[qr.index],
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
        run = run_hierarchy(scenario, config, seeded=seeded, steps=steps, progress=progress)
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


# --------------------------------------------------------------------------
# The report
# --------------------------------------------------------------------------
def _ms(seconds: np.ndarray) -> dict[str, float]:
    s = np.asarray(seconds, dtype=np.float64)
    if s.size == 0:
        return {"median": math.nan, "p95": math.nan, "mean": math.nan}
    return {"median": 1e3 * float(np.median(s)), "p95": 1e3 * float(np.percentile(s, 95.0)), "mean": 1e3 * float(s.mean())}


def _rate(flags: np.ndarray, n: int) -> float:
    return float(np.count_nonzero(flags)) / n if n else math.nan


def _finite(v: Any) -> Any:
    """JSON-safe: non-finite floats become None, recursively."""
    if isinstance(v, dict):
        return {k: _finite(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_finite(x) for x in v]
    if isinstance(v, (float, np.floating)):
        return float(v) if math.isfinite(v) else None
    if isinstance(v, np.integer):
        return int(v)
    return v


@dataclass(frozen=True, eq=False)
class EvaluationReport:
    """What :func:`evaluate` measured: per-query results and their metrics.

    The arrays (``errors``, ``covariances``, ``nees``, ``dof``) are aligned
    with ``results``; :meth:`to_json_dict` gives the documented summary.
    """

    run: HierarchyRun
    strategy: str
    results: tuple[QueryResult, ...]
    _cache: dict[str, Any] = field(default_factory=dict, repr=False)

    # --- arrays -------------------------------------------------------------
    @property
    def errors(self) -> np.ndarray:
        """N×3 errors (m, m, rad), ``nan`` where undetermined or without truth."""
        if "errors" not in self._cache:
            self._cache["errors"] = np.array([r.error for r in self.results]).reshape(-1, 3)
        return self._cache["errors"]

    @property
    def covariances(self) -> np.ndarray:
        """N×3×3 world-frame covariances."""
        if "covariances" not in self._cache:
            self._cache["covariances"] = np.array([r.covariance for r in self.results]).reshape(-1, 3, 3)
        return self._cache["covariances"]

    @property
    def has_truth(self) -> np.ndarray:
        return np.array([r.truth is not None for r in self.results], dtype=bool)

    @property
    def nees(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-query NEES and its degrees of freedom (:func:`metrics.nees`)."""
        return metrics.nees(self.errors, self.covariances)

    @property
    def name(self) -> str:
        return self.run.dataset.name

    # --- summaries ---------------------------------------------------------------
    def to_json_dict(self) -> dict[str, Any]:
        """All the figures under the stable keys of ``docs/evaluation.md`` (JSON-safe: ``null`` for n/a)."""
        if "json" not in self._cache:
            out: dict[str, Any] = {
                "schema_version": SCHEMA_VERSION,
                "scenario": self.name,
                "strategy": self.strategy,
                "seeded": self.run.seeded,
            }
            idx = np.arange(len(self.results))
            out.update(self._summary(idx))
            out["peak_memory_mb"] = self.run.peak_memory_mb
            out["prepare_ms"] = {k: 1e3 * v for k, v in self.run.prepare_seconds.items()}
            tags = sorted({t for r in self.results for t in r.faults})
            by_fault = {}
            clean = np.array([not r.faults for r in self.results], dtype=bool)
            if clean.any():
                by_fault[NO_FAULT] = self._summary(idx[clean])
            for t in tags:
                sel = np.array([t in r.faults for r in self.results], dtype=bool)
                by_fault[t] = self._summary(idx[sel])
            out["by_fault"] = by_fault
            overlap = np.array([r.view_overlap for r in self.results], dtype=np.float64)
            known = np.isfinite(overlap)
            with np.errstate(invalid="ignore"):
                overlapping = known & (overlap >= OVERLAP_MIN_FRACTION)
            out["overlap_radius_m"] = OVERLAP_RADIUS_M
            out["overlap_min_fraction"] = OVERLAP_MIN_FRACTION
            out["overlapping_rate"] = _rate(overlapping, int(known.sum()))
            out["overlapping"] = self._summary(idx[overlapping]) if overlapping.any() else {"queries": 0}
            self._cache["json"] = _finite(out)
        return self._cache["json"]

    def _summary(self, idx: np.ndarray) -> dict[str, Any]:
        res = [self.results[i] for i in idx]
        n = len(res)
        err = self.errors[idx] if n else np.zeros((0, 3))
        cov = self.covariances[idx] if n else np.zeros((0, 3, 3))
        truth = np.array([r.truth is not None for r in res], dtype=bool)
        m = int(truth.sum())
        det = metrics.determined_mask(cov) if n else np.zeros((0, 3), dtype=bool)
        pos = metrics.summarize(metrics.position_error_m(err))
        head = metrics.summarize(metrics.heading_error_rad(err)).scaled(180.0 / math.pi)
        e, k = metrics.nees(err, cov) if n else (np.zeros(0), np.zeros(0, dtype=int))
        scored = truth & det.any(axis=1)
        full = truth & det.all(axis=1)
        outside = metrics.outside_ellipse(e, k, 0.99) if n else np.zeros(0, dtype=bool)
        wrong = metrics.confidently_wrong(err, cov) & truth if n else np.zeros(0, dtype=bool)
        latency = _ms(np.array([r.latency_s for r in res]))
        s: dict[str, Any] = {
            "queries": n,
            "queries_with_truth": m,
            "position_rmse_m": pos.rmse,
            "position_median_m": pos.median,
            "position_p95_m": pos.p95,
            "position_max_m": pos.max,
            "position_count": pos.count,
            "heading_rmse_deg": head.rmse,
            "heading_median_deg": head.median,
            "heading_p95_deg": head.p95,
            "heading_max_deg": head.max,
            "heading_count": head.count,
            "position_determined_rate": _rate(det[:, 0] & det[:, 1], n),
            "heading_determined_rate": _rate(det[:, 2], n),
            "determined_rate": _rate(det.all(axis=1), n),
            "nees_mean": metrics.nees_mean(e[truth], k[truth]) if n else math.nan,
            "nees_median": float(np.median(e[full & np.isfinite(e)])) if np.any(full & np.isfinite(e)) else math.nan,
            "nees_normalized_mean": metrics.normalized_nees_mean(e[truth], k[truth]) if n else math.nan,
            "nees_count": int(np.count_nonzero(full & np.isfinite(e))) if n else 0,
            "outside_99_rate": _rate(outside & scored, int(scored.sum())),
            "confidently_wrong_rate": _rate(wrong, m),
            "confidently_wrong_count": int(np.count_nonzero(wrong)),
            "latency_median_ms": latency["median"],
            "latency_p95_ms": latency["p95"],
            "latency_mean_ms": latency["mean"],
            "fusion_latency_median_ms": _ms(np.array([r.strategy_s for r in res]))["median"],
            "steps": {name: self._step_summary(name, res, wrong) for name in self.run.step_names},
        }
        return s

    @staticmethod
    def _step_summary(name: str, res: list[QueryResult], fused_wrong: np.ndarray) -> dict[str, Any]:
        n = len(res)
        reports = [next((r for r in q.reports if r.name == name), None) for q in res]
        status = Counter(r.status.value if r is not None else "absent" for r in reports)
        reliable = np.array([r is not None and r.estimate is not None and r.estimate.reliable for r in reports], dtype=bool)
        seconds = np.array([r.seconds for r in reports if r is not None and r.status is not StepStatus.SKIPPED])
        reasons = Counter(
            f"{r.status.value}: {_normalize_reason(r.reason)}"
            for r in reports
            if r is not None and r.status is not StepStatus.FUSED
        )
        # the step's own accuracy and honesty, over its reliable estimates of queries with truth
        rows = [
            (metrics.values_of_estimate(r.estimate), metrics.covariance_of_estimate(r.estimate), q.truth.as_array())
            for r, q, ok in zip(reports, res, reliable, strict=True)
            if ok and q.truth is not None
        ]
        row_query = [i for i, (q, ok) in enumerate(zip(res, reliable, strict=True)) if ok and q.truth is not None]
        if rows:
            vals = np.array([a for a, _, _ in rows])
            covs = np.array([c for _, c, _ in rows])
            tru = np.array([t for _, _, t in rows])
            err = metrics.pose_errors(vals, tru)
            e, k = metrics.nees(err, covs)
            wrong = metrics.confidently_wrong(err, covs, reliable=np.ones(len(rows), dtype=bool))
            pos = metrics.summarize(metrics.position_error_m(err))
            head = metrics.summarize(metrics.heading_error_rad(err)).scaled(180.0 / math.pi)
            normalized = metrics.normalized_nees_mean(e, k)
            # each part on its own: position (2 dof, calibrated mean 2) and heading (1 dof, calibrated mean 1)
            has_pos = np.isfinite(covs[:, 0, 0]) & np.isfinite(err[:, 0])
            has_head = np.isfinite(covs[:, 2, 2]) & np.isfinite(err[:, 2])
            if has_pos.any():
                ep = err[has_pos, :2]
                pos_nees = np.einsum("ni,ni->n", ep, np.linalg.solve(covs[has_pos][:, :2, :2], ep[..., None])[..., 0])
                pos_nees_mean, pos_nees_median = float(pos_nees.mean()), float(np.median(pos_nees))
            else:
                pos_nees_mean = pos_nees_median = math.nan
            if has_head.any():
                head_nees = err[has_head, 2] ** 2 / covs[has_head, 2, 2]
                head_nees_mean, head_nees_median = float(head_nees.mean()), float(np.median(head_nees))
            else:
                head_nees_mean = head_nees_median = math.nan
            n_wrong = int(np.count_nonzero(wrong))
            # confidently-wrong fused results to which this step contributed a false positive
            blame = sum(
                1
                for j, w in zip(row_query, wrong, strict=True)
                if w and fused_wrong[j] and reports[j] is not None and reports[j].status is StepStatus.FUSED
            )
        else:
            pos = head = metrics.summarize(np.zeros(0))
            normalized, n_wrong, blame = math.nan, 0, 0
            pos_nees_mean = pos_nees_median = head_nees_mean = head_nees_median = math.nan
        lat = _ms(seconds)
        truth_n = sum(q.truth is not None for q in res)
        return {
            "reliable_rate": _rate(reliable, n),
            "fused_rate": status.get("fused", 0) / n if n else math.nan,
            "status_rates": {s: status.get(s, 0) / n for s in [v.value for v in StepStatus]} if n else {},
            "latency_median_ms": lat["median"],
            "latency_p95_ms": lat["p95"],
            "gate_reasons": dict(reasons.most_common(8)),
            "position_rmse_m": pos.rmse,
            "position_median_m": pos.median,
            "heading_rmse_deg": head.rmse,
            "heading_median_deg": head.median,
            "nees_normalized_mean": normalized,
            "position_nees_mean": pos_nees_mean,
            "position_nees_median": pos_nees_median,
            "heading_nees_mean": head_nees_mean,
            "heading_nees_median": head_nees_median,
            "false_positive_rate": n_wrong / truth_n if truth_n else math.nan,
            "false_positive_count": n_wrong,
            "confidently_wrong_blame": blame,
        }

"""What :func:`~factorloc.evaluation.evaluate` measured, as typed records.

:class:`EvaluationReport` holds the per-query results; :meth:`EvaluationReport.summary` gives an
:class:`EvaluationSummary` (overall, per fault tag, over the queries with an overlapping view), each part a
:class:`Summary` with a :class:`StepSummary` per step. ``to_json()`` of each gives the stable keys of
``docs/evaluation.md`` (``null`` where a figure does not apply).
"""

from __future__ import annotations

import math
from collections import Counter
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np

from factorloc._json import JsonRecord
from factorloc.evaluation import metrics
from factorloc.evaluation.reasons import RuleTally, tally_reasons
from factorloc.types import StepReport, StepStatus

if TYPE_CHECKING:  # pragma: no cover
    from factorloc.evaluation.runner import HierarchyRun, QueryFailure, QueryResult

__all__ = [
    "NO_FAULT",
    "OVERLAP_MIN_FRACTION",
    "OVERLAP_RADIUS_M",
    "SCHEMA_VERSION",
    "EvaluationReport",
    "EvaluationSummary",
    "StepSummary",
    "Summary",
]

#: Version of the JSON written by :meth:`EvaluationSummary.to_json`.
SCHEMA_VERSION = 1

#: The tag under ``by_fault`` that collects queries without any fault tag.
NO_FAULT = "none"

#: A query point overlaps the reference when a reference surface point lies within this radius (m, in the plane).
OVERLAP_RADIUS_M = 0.05

#: A query *has an overlapping view* when at least this fraction of its range points overlap the reference.
OVERLAP_MIN_FRACTION = 0.3


def _ms(seconds: np.ndarray) -> tuple[float, float, float]:
    """Median, 95th percentile and mean of ``seconds``, in ms (NaN when empty)."""
    s = np.asarray(seconds, dtype=np.float64)
    if s.size == 0:
        return math.nan, math.nan, math.nan
    return 1e3 * float(np.median(s)), 1e3 * float(np.percentile(s, 95.0)), 1e3 * float(s.mean())


def _rate(flags: np.ndarray, n: int) -> float:
    return float(np.count_nonzero(flags)) / n if n else math.nan


@dataclass(frozen=True)
class StepSummary(JsonRecord):
    """One step over a set of queries: availability, its own accuracy and honesty, time, why it was not fused.

    Rates are fractions of the queries; errors in m and degrees; the step's own figures are over its reliable
    estimates of queries with truth (see ``docs/evaluation.md``). ``gate_reasons`` counts the rules of
    ``gate_rules`` by ``"<status>: <code>"``.
    """

    reliable_rate: float
    fused_rate: float
    status_rates: Mapping[str, float]
    latency_median_ms: float
    latency_p95_ms: float
    gate_reasons: Mapping[str, int]
    gate_rules: tuple[RuleTally, ...]
    position_rmse_m: float
    position_median_m: float
    heading_rmse_deg: float
    heading_median_deg: float
    nees_normalized_mean: float
    position_nees_mean: float
    position_nees_median: float
    heading_nees_mean: float
    heading_nees_median: float
    false_positive_rate: float
    false_positive_count: int
    confidently_wrong_blame: int

    @property
    def absent(self) -> bool:
        """Whether the step's inputs were absent on every query (it never ran)."""
        return self.status_rates.get(StepStatus.SKIPPED.value, 0.0) == 1.0


@dataclass(frozen=True)
class Summary(JsonRecord):
    """The fused results over a set of queries: accuracy, availability, honesty, speed, and each step."""

    queries: int
    queries_with_truth: int
    position_rmse_m: float
    position_median_m: float
    position_p95_m: float
    position_max_m: float
    position_count: int
    heading_rmse_deg: float
    heading_median_deg: float
    heading_p95_deg: float
    heading_max_deg: float
    heading_count: int
    position_determined_rate: float
    heading_determined_rate: float
    determined_rate: float
    nees_mean: float
    nees_median: float
    nees_normalized_mean: float
    nees_count: int
    outside_99_rate: float
    confidently_wrong_rate: float
    confidently_wrong_count: int
    latency_median_ms: float
    latency_p95_ms: float
    latency_mean_ms: float
    fusion_latency_median_ms: float
    steps: Mapping[str, StepSummary]


@dataclass(frozen=True)
class EvaluationSummary(JsonRecord):
    """Everything :func:`~factorloc.evaluation.evaluate` measured on one scenario with one strategy.

    ``overall`` is over every query (its keys sit at the top level of the JSON); ``by_fault`` per fault tag
    (``"none"``: the queries without one); ``overlapping`` over the queries with an overlapping view
    (None when there is none: ``{"queries": 0}`` in the JSON). ``failed_queries`` counts the queries that
    raised (``failed``: their index, id and error); the figures are over the others.
    """

    scenario: str
    strategy: str
    seeded: bool
    overall: Summary
    peak_memory_mb: float
    prepare_ms: Mapping[str, float]
    by_fault: Mapping[str, Summary]
    overlap_radius_m: float
    overlap_min_fraction: float
    overlapping_rate: float
    overlapping: Summary | None
    schema_version: int = SCHEMA_VERSION
    failed_queries: int = 0
    failed: tuple[QueryFailure, ...] = ()

    def to_json(self) -> dict[str, Any]:
        """The stable keys of ``docs/evaluation.md``: ``overall``'s at the top level."""
        out = {"schema_version": self.schema_version, "scenario": self.scenario, "strategy": self.strategy}
        out["seeded"] = self.seeded
        out.update(self.overall.to_json())
        rest = super().to_json()
        for key in (
            "failed_queries",
            "failed",
            "peak_memory_mb",
            "prepare_ms",
            "by_fault",
            "overlap_radius_m",
            "overlap_min_fraction",
            "overlapping_rate",
        ):
            out[key] = rest[key]
        out["overlapping"] = rest["overlapping"] if self.overlapping is not None else {"queries": 0}
        return out


@dataclass(frozen=True)
class _OwnFigures:
    """A step's own accuracy and honesty over its reliable estimates of queries with truth."""

    position: metrics.ErrorSummary
    heading: metrics.ErrorSummary
    nees_normalized_mean: float = math.nan
    position_nees: tuple[float, float] = (math.nan, math.nan)  # mean, median
    heading_nees: tuple[float, float] = (math.nan, math.nan)
    wrong: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=bool))  # per row: off by > 3σ


def _mean_median(v: np.ndarray) -> tuple[float, float]:
    return (float(v.mean()), float(np.median(v))) if v.size else (math.nan, math.nan)


def _own_figures(values: np.ndarray, covariances: np.ndarray, truths: np.ndarray) -> _OwnFigures:
    """Rows: the step's reliable estimates as (x, y, θ) (``nan`` where unmeasured), 3×3 covariances, truths."""
    if not len(values):
        empty = metrics.summarize(np.zeros(0))
        return _OwnFigures(empty, empty)
    err = metrics.pose_errors(values, truths)
    e, k = metrics.nees(err, covariances)
    wrong = metrics.confidently_wrong(err, covariances, reliable=np.ones(len(values), dtype=bool))
    # each part on its own: position (2 dof, calibrated mean 2) and heading (1 dof, calibrated mean 1)
    has_pos = np.isfinite(covariances[:, 0, 0]) & np.isfinite(err[:, 0])
    has_head = np.isfinite(covariances[:, 2, 2]) & np.isfinite(err[:, 2])
    ep = err[has_pos, :2]
    pos_nees = np.einsum("ni,ni->n", ep, np.linalg.solve(covariances[has_pos][:, :2, :2], ep[..., None])[..., 0])
    head_nees = err[has_head, 2] ** 2 / covariances[has_head, 2, 2]
    return _OwnFigures(
        metrics.summarize(metrics.position_error_m(err)),
        metrics.summarize(metrics.heading_error_rad(err)).scaled(180.0 / math.pi),
        metrics.normalized_nees_mean(e, k),
        _mean_median(pos_nees),
        _mean_median(head_nees),
        wrong,
    )


def step_summary(name: str, results: Sequence[QueryResult], fused_wrong: np.ndarray) -> StepSummary:
    """The :class:`StepSummary` of step ``name`` over ``results`` (``fused_wrong``: their confidently-wrong flags)."""
    n = len(results)
    reports: list[StepReport | None] = [next((r for r in q.reports if r.name == name), None) for q in results]
    status = Counter(r.status.value if r is not None else "absent" for r in reports)
    reliable = [r is not None and r.estimate is not None and r.estimate.reliable for r in reports]
    rows = [i for i, q in enumerate(results) if reliable[i] and q.truth is not None]
    own = _own_figures(
        np.array([metrics.values_of_estimate(reports[i].estimate) for i in rows]).reshape(-1, 3),
        np.array([metrics.covariance_of_estimate(reports[i].estimate) for i in rows]).reshape(-1, 3, 3),
        np.array([results[i].truth.as_array() for i in rows]).reshape(-1, 3),
    )
    # confidently-wrong fused results to which this step contributed a false positive
    blame = sum(1 for j, w in zip(rows, own.wrong, strict=True) if w and fused_wrong[j] and reports[j].status is StepStatus.FUSED)
    median, p95, _ = _ms(np.array([r.seconds for r in reports if r is not None and r.status is not StepStatus.SKIPPED]))
    truth_n = sum(q.truth is not None for q in results)
    n_wrong = int(np.count_nonzero(own.wrong))
    tallies = tally_reasons(reports)[:8]
    return StepSummary(
        reliable_rate=_rate(np.array(reliable, dtype=bool), n),
        fused_rate=status.get("fused", 0) / n if n else math.nan,
        status_rates={s.value: status.get(s.value, 0) / n for s in StepStatus} if n else {},
        latency_median_ms=median,
        latency_p95_ms=p95,
        gate_reasons={t.key: t.count for t in tallies},
        gate_rules=tallies,
        position_rmse_m=own.position.rmse,
        position_median_m=own.position.median,
        heading_rmse_deg=own.heading.rmse,
        heading_median_deg=own.heading.median,
        nees_normalized_mean=own.nees_normalized_mean,
        position_nees_mean=own.position_nees[0],
        position_nees_median=own.position_nees[1],
        heading_nees_mean=own.heading_nees[0],
        heading_nees_median=own.heading_nees[1],
        false_positive_rate=n_wrong / truth_n if truth_n else math.nan,
        false_positive_count=n_wrong,
        confidently_wrong_blame=blame,
    )


@dataclass(frozen=True, eq=False)
class EvaluationReport:
    """What :func:`~factorloc.evaluation.evaluate` measured: per-query results and their metrics.

    The arrays (``errors``, ``covariances``, ``nees``) are aligned with ``results``; :meth:`summary` gives
    the documented figures as an :class:`EvaluationSummary`, :meth:`to_json` their JSON.
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
        """Per-query NEES and its degrees of freedom (:func:`~factorloc.evaluation.metrics.nees`)."""
        return metrics.nees(self.errors, self.covariances)

    @property
    def name(self) -> str:
        return self.run.dataset.name

    # --- summaries ---------------------------------------------------------------
    def summary(self) -> EvaluationSummary:
        """All the figures: over every query, per fault tag and over the queries with an overlapping view."""
        if "summary" not in self._cache:
            idx = np.arange(len(self.results))
            by_fault = {}
            clean = np.array([not r.faults for r in self.results], dtype=bool)
            if clean.any():
                by_fault[NO_FAULT] = self._summary(idx[clean])
            for t in sorted({t for r in self.results for t in r.faults}):
                by_fault[t] = self._summary(idx[np.array([t in r.faults for r in self.results], dtype=bool)])
            overlap = np.array([r.view_overlap for r in self.results], dtype=np.float64)
            known = np.isfinite(overlap)
            with np.errstate(invalid="ignore"):
                overlapping = known & (overlap >= OVERLAP_MIN_FRACTION)
            self._cache["summary"] = EvaluationSummary(
                scenario=self.name,
                strategy=self.strategy,
                seeded=self.run.seeded,
                overall=self._summary(idx),
                peak_memory_mb=self.run.peak_memory_mb,
                prepare_ms={k: 1e3 * v for k, v in self.run.prepare_seconds.items()},
                by_fault=by_fault,
                overlap_radius_m=OVERLAP_RADIUS_M,
                overlap_min_fraction=OVERLAP_MIN_FRACTION,
                overlapping_rate=_rate(overlapping, int(known.sum())),
                overlapping=self._summary(idx[overlapping]) if overlapping.any() else None,
                failed_queries=len(self.run.failures),
                failed=self.run.failures,
            )
        return self._cache["summary"]

    def to_json(self) -> dict[str, Any]:
        """The JSON of :meth:`summary` (the keys of ``docs/evaluation.md``)."""
        if "json" not in self._cache:
            self._cache["json"] = self.summary().to_json()
        return self._cache["json"]

    def _summary(self, idx: np.ndarray) -> Summary:
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
        full = truth & det.all(axis=1) & np.isfinite(e)
        outside = metrics.outside_ellipse(e, k, 0.99) if n else np.zeros(0, dtype=bool)
        wrong = metrics.confidently_wrong(err, cov) & truth if n else np.zeros(0, dtype=bool)
        latency = _ms(np.array([r.latency_s for r in res]))
        return Summary(
            queries=n,
            queries_with_truth=m,
            position_rmse_m=pos.rmse,
            position_median_m=pos.median,
            position_p95_m=pos.p95,
            position_max_m=pos.max,
            position_count=pos.count,
            heading_rmse_deg=head.rmse,
            heading_median_deg=head.median,
            heading_p95_deg=head.p95,
            heading_max_deg=head.max,
            heading_count=head.count,
            position_determined_rate=_rate(det[:, 0] & det[:, 1], n),
            heading_determined_rate=_rate(det[:, 2], n),
            determined_rate=_rate(det.all(axis=1), n),
            nees_mean=metrics.nees_mean(e[truth], k[truth]) if n else math.nan,
            nees_median=float(np.median(e[full])) if np.any(full) else math.nan,
            nees_normalized_mean=metrics.normalized_nees_mean(e[truth], k[truth]) if n else math.nan,
            nees_count=int(np.count_nonzero(full)) if n else 0,
            outside_99_rate=_rate(outside & scored, int(scored.sum())),
            confidently_wrong_rate=_rate(wrong, m),
            confidently_wrong_count=int(np.count_nonzero(wrong)),
            latency_median_ms=latency[0],
            latency_p95_ms=latency[1],
            latency_mean_ms=latency[2],
            fusion_latency_median_ms=_ms(np.array([r.strategy_s for r in res]))[0],
            steps={name: step_summary(name, res, wrong) for name in self.run.step_names},
        )

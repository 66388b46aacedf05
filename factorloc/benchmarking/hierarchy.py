"""The patent's central claim, measured: every step seeded by its predecessors vs every step blind.

False positive
    A step's estimate that the step called *reliable* while its error exceeds 3 marginal σ in a component it
    measures (the confidently-wrong test of :func:`factorloc.evaluation.metrics.confidently_wrong` applied per
    step): the headline. The second definition, a reliable estimate off by more than a fixed tolerance
    (:func:`beyond_tolerance`), does not depend on the σ the step states (a blind step's σ is wider). Counts
    of rare events get exact intervals (:mod:`factorloc.benchmarking.statistics`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from factorloc.benchmarking.base import BenchSettings, per_query_median, ratio, timing
from factorloc.benchmarking.results import CountComparison, FalsePositiveComparison, HierarchyBench, HierarchyMode
from factorloc.benchmarking.statistics import compare_counts
from factorloc.errors import InputError
from factorloc.evaluation import metrics
from factorloc.evaluation.runner import HierarchyRun, evaluate
from factorloc.gating import GatingConfig

__all__ = ["bench_hierarchy", "beyond_tolerance"]


def beyond_tolerance(
    errors: np.ndarray,
    covariance: np.ndarray,
    tolerance_m: float,
    tolerance_rad: float,
    *,
    undetermined_sigma_m: float = GatingConfig().undetermined_sigma_m,
) -> bool:
    """Whether an estimate's error exceeds a fixed tolerance in what it determines.

    Parameters
    ----------
    errors
        (3,) world-frame error ``estimate − truth`` (m, m, rad), ``nan`` where unmeasured.
    covariance
        (3, 3) world-frame covariance, ``inf`` variance where unmeasured.
    tolerance_m, tolerance_rad
        The position error (norm over the determined directions) and heading error allowed.
    undetermined_sigma_m
        σ (m) from which a direction counts as undetermined (``GatingConfig.undetermined_sigma_m``).

    Notes
    -----
    A position is judged along the eigen-directions of its 2×2 covariance whose
    σ is below ``undetermined_sigma_m`` (the pipeline's "undetermined" rule,
    :func:`factorloc.gating.position_determined`): an ICP estimate that only
    fixes the position across a wall claims nothing along it.
    """
    e = np.asarray(errors, dtype=np.float64).reshape(3)
    cov = np.asarray(covariance, dtype=np.float64).reshape(3, 3)
    if math.isfinite(cov[2, 2]) and math.isfinite(e[2]) and abs(e[2]) > tolerance_rad:
        return True
    p = cov[:2, :2]
    if np.all(np.isfinite(p)) and np.all(np.isfinite(e[:2])):
        w, v = np.linalg.eigh(p)
        keep = w < undetermined_sigma_m**2
        if keep.any() and float(np.linalg.norm(v[:, keep].T @ e[:2])) > tolerance_m:
            return True
    return False


@dataclass(frozen=True)
class _Outcomes:
    """Per query with truth (rows) of one hierarchy run: what each step and the fused result did."""

    step_names: tuple[str, ...]
    reliable: np.ndarray  # Q×S bool
    sigma3: np.ndarray  # Q×S bool: reliable and off by > 3σ in a measured component
    tolerance: np.ndarray  # Q×S bool: reliable and beyond the fixed tolerance
    fused_sigma3: np.ndarray  # Q bool: fully determined and off by > 3σ (the confidently-wrong test)
    fused_tolerance: np.ndarray  # Q bool: fully determined and beyond the fixed tolerance


def _outcomes(run: HierarchyRun, tolerance_m: float, tolerance_rad: float) -> _Outcomes:
    limit = run.config.gating.undetermined_sigma_m
    names = tuple(run.step_names)
    col = {n: i for i, n in enumerate(names)}
    rel, s3, tol, f3, ft = [], [], [], [], []
    for q in run.runs:
        if q.case.truth is None:
            continue
        truth = q.case.truth.as_array()[None]
        r_row, s_row, t_row = np.zeros(len(names), bool), np.zeros(len(names), bool), np.zeros(len(names), bool)
        for r in q.reports:
            est = r.estimate
            if est is None or not est.reliable or r.name not in col:
                continue
            err = metrics.pose_errors(metrics.values_of_estimate(est)[None], truth)
            cov = metrics.covariance_of_estimate(est)
            j = col[r.name]
            r_row[j] = True
            s_row[j] = bool(metrics.confidently_wrong(err, cov[None], reliable=np.array([True]))[0])
            t_row[j] = beyond_tolerance(err[0], cov, tolerance_m, tolerance_rad, undetermined_sigma_m=limit)
        loc = q.localization
        err = metrics.pose_errors(loc.pose.as_array()[None], truth)
        cov = np.asarray(loc.covariance, dtype=np.float64)
        full = bool(np.all(np.isfinite(np.diag(cov))))
        f3.append(bool(metrics.confidently_wrong(err, cov[None])[0]))
        ft.append(full and beyond_tolerance(err[0], cov, tolerance_m, tolerance_rad, undetermined_sigma_m=limit))
        rel.append(r_row)
        s3.append(s_row)
        tol.append(t_row)
    shape = (len(rel), len(names))
    arr = (lambda rows: np.array(rows, dtype=bool).reshape(shape)) if rel else (lambda rows: np.zeros(shape, bool))
    return _Outcomes(names, arr(rel), arr(s3), arr(tol), np.array(f3, dtype=bool), np.array(ft, dtype=bool))


def _mode(runs: Sequence[HierarchyRun], outcomes: _Outcomes) -> HierarchyMode:
    """One mode's figures: times from all passes, false positives and the fused outcome from the first."""
    total, steps = per_query_median(runs)
    t = timing(total)
    n_truth = int(outcomes.reliable.shape[0])
    per_step = dict(zip(outcomes.step_names, outcomes.sigma3.sum(axis=0).tolist(), strict=True))
    reliable = dict(zip(outcomes.step_names, outcomes.reliable.sum(axis=0).tolist(), strict=True))
    # the total leaves out the first step of the hierarchy: it has no predecessors, so seeding cannot change it
    fp_total = sum(v for k, v in per_step.items() if k != runs[0].step_names[0])
    overall = evaluate(runs[0]).summary().overall
    return HierarchyMode(
        median_ms=t.median_ms,
        p95_ms=t.p95_ms,
        mean_ms=t.mean_ms,
        steps_median_ms={k: timing(v).median_ms for k, v in steps.items()},
        queries_with_truth=n_truth,
        false_positive_count=fp_total,
        false_positive_rate=fp_total / n_truth if n_truth else math.nan,
        steps_false_positive_count=per_step,
        steps_reliable_count=reliable,
        steps_false_positive_per_reliable={k: (per_step[k] / reliable[k] if reliable[k] else math.nan) for k in per_step},
        steps_reliable_rate={k: v.reliable_rate for k, v in overall.steps.items()},
        confidently_wrong_rate=overall.confidently_wrong_rate,
        confidently_wrong_count=overall.confidently_wrong_count,
        determined_rate=overall.determined_rate,
        position_rmse_m=overall.position_rmse_m,
        heading_rmse_deg=overall.heading_rmse_deg,
    )


def _count_ratio(blind: int, seeded: int) -> tuple[float, bool]:
    """blind / max(seeded, 1), and whether it is a lower bound (none seeded); NaN when neither has any."""
    value = blind / max(seeded, 1) if blind or seeded else math.nan
    return value, seeded == 0 and blind > 0


def bench_hierarchy(
    seeded_runs: Sequence[HierarchyRun], blind_runs: Sequence[HierarchyRun], *, settings: BenchSettings = BenchSettings()
) -> HierarchyBench:
    """Seeded vs blind: time per query, false positives (per step and total), confidently-wrong fused results, ratios.

    ``time_ratio`` = blind / seeded median localize() time; ``false_positive_ratio``
    = blind / seeded false-positive count (with 0 seeded false positives it is
    the blind count, a lower bound: ``false_positive_ratio_is_lower_bound``; with
    none on either side it is ``nan``: there is nothing to compare).

    A step that is never reliable has no false positive: the per-step counts
    are therefore given with the reliable counts they come from
    (``steps_reliable_count``, ``steps_false_positive_per_reliable``), and the
    fused outcome of each mode is compared too: ``confidently_wrong_count``
    (and ``confidently_wrong_ratio`` = blind / seeded, a lower bound when
    seeded has none), ``determined_rate`` (availability) and the RMSEs. Blind
    steps get no hypotheses, so no later step can contradict an earlier one
    (the pipeline's seed audit needs a *seeded* ICP): that is part of what
    the ablation measures.

    ``false_positives`` holds the statistically honest comparison
    (:func:`~factorloc.benchmarking.statistics.compare_counts`: exact intervals at ``settings.confidence``, the
    one-sided lower bound of the ratio, the queries needed to show
    ``settings.fp_target_ratio``) for two definitions of a false positive —
    ``sigma3`` (reliable, off by > 3σ in a measured component: the headline)
    and ``tolerance`` (reliable, off by more than ``settings.fp_tolerance_m`` /
    ``fp_tolerance_rad``, :func:`beyond_tolerance`) — per step, for "any step
    after the first" per query (``steps_after_first``), and for the fused
    result (``fused``: fully determined and wrong).
    """
    modes, outcomes = {}, {}
    for label, runs in (("seeded", seeded_runs), ("blind", blind_runs)):
        if not runs:
            raise InputError(f"bench_hierarchy needs at least one {label} HierarchyRun")
        outcomes[label] = _outcomes(runs[0], settings.fp_tolerance_m, settings.fp_tolerance_rad)
        modes[label] = _mode(runs, outcomes[label])
    s, b = modes["seeded"], modes["blind"]
    fp_ratio, fp_lb = _count_ratio(b.false_positive_count, s.false_positive_count)
    cw_ratio, cw_lb = _count_ratio(b.confidently_wrong_count, s.confidently_wrong_count)
    return HierarchyBench(
        seeded=s,
        blind=b,
        time_ratio=ratio(b.median_ms, s.median_ms),
        false_positive_ratio=fp_ratio,
        false_positive_ratio_is_lower_bound=fp_lb,
        confidently_wrong_ratio=cw_ratio,
        confidently_wrong_ratio_is_lower_bound=cw_lb,
        false_positives=_false_positive_comparison(outcomes["seeded"], outcomes["blind"], settings),
    )


def _false_positive_comparison(seeded: _Outcomes, blind: _Outcomes, settings: BenchSettings) -> FalsePositiveComparison:
    if seeded.step_names != blind.step_names or seeded.reliable.shape != blind.reliable.shape:
        raise InputError("the seeded and blind runs must cover the same steps and queries")
    n = int(seeded.reliable.shape[0])
    after_first: dict[str, CountComparison] = {}
    fused: dict[str, CountComparison] = {}
    steps: dict[str, dict[str, CountComparison]] = {}
    kw = {"confidence": settings.confidence, "target": settings.fp_target_ratio}
    later = slice(1, None)  # the first step has no predecessor: seeding cannot change it
    definitions = (
        ("sigma3", seeded.sigma3, blind.sigma3, seeded.fused_sigma3, blind.fused_sigma3),
        ("tolerance", seeded.tolerance, blind.tolerance, seeded.fused_tolerance, blind.fused_tolerance),
    )
    for label, s_flags, b_flags, s_fused, b_fused in definitions if n else ():
        after_first[label] = compare_counts(
            int(s_flags[:, later].any(axis=1).sum()), int(b_flags[:, later].any(axis=1).sum()), n, **kw
        )
        fused[label] = compare_counts(int(s_fused.sum()), int(b_fused.sum()), n, **kw)
        for j, name in enumerate(seeded.step_names):
            steps.setdefault(name, {})[label] = compare_counts(
                int(s_flags[:, j].sum()),
                int(b_flags[:, j].sum()),
                n,
                seeded_reliable=int(seeded.reliable[:, j].sum()),
                blind_reliable=int(blind.reliable[:, j].sum()),
                **kw,
            )
    return FalsePositiveComparison(
        headline="sigma3",
        confidence=settings.confidence,
        target_ratio=settings.fp_target_ratio,
        tolerance_m=settings.fp_tolerance_m,
        tolerance_deg=math.degrees(settings.fp_tolerance_rad),
        queries=n,
        steps_after_first=after_first,
        fused=fused,
        steps=steps,
    )

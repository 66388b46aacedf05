"""Speed, measured as ratios against peers in the same run on the same inputs.

The library functions behind ``factorloc bench`` (which only prints):

- :func:`bench_localize` — full :meth:`~factorloc.Localizer.localize` per
  query and per step (median and 95th percentile over queries of the
  per-query median over repeats);
- :func:`bench_hierarchy` — the patent's central claim: every step seeded by
  its predecessors vs every step blind (``Localizer.localize(q, seeded=False)``):
  time per query and false positives of each, and their ratios;
- :func:`bench_icp_vs_open3d` — our ICP (:func:`factorloc.registration.icp2d.align`)
  vs Open3D's point-to-plane ICP on the same scan pairs from the same seeds;
- :func:`bench_fusion` — GTSAM graph vs closed-form product on the same gated
  estimates: time ratio and agreement;
- :func:`bench_cost_curve` — time per query as the reference panorama width
  and the cloud sizes double, with the fitted exponent ``t ∝ scale^k``.

:func:`run_bench` runs them all and returns one JSON-ready dict (keys in
``docs/evaluation.md``). Timings use :func:`time.perf_counter`; every figure
is a median, so a stray slow repeat does not move it. Nothing here asserts
a speed: the test suite only checks that the machinery runs.

False positive
    A step's estimate that the step called *reliable* while its error exceeds
    3 marginal σ in a component it measures (the confidently-wrong test of
    :func:`factorloc.evaluation.metrics.confidently_wrong` applied per step):
    the headline. The second definition, a reliable estimate off by more than
    a fixed tolerance (:func:`beyond_tolerance`), does not depend on the σ the
    step states (a blind step's σ is wider). Counts of rare events get exact
    intervals: :func:`clopper_pearson` for a rate, :func:`rate_ratio_interval`
    for the blind / seeded ratio, :func:`queries_to_show_ratio` for the
    sample a claimed ratio needs.
"""

from __future__ import annotations

import logging
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np
from scipy.stats import beta as beta_dist
from scipy.stats import binom as binom_dist

from factorloc.config import Config
from factorloc.errors import InputError
from factorloc.estimators.icp import UNCONSTRAINED_SIGMA_M
from factorloc.evaluation import metrics
from factorloc.evaluation.runner import Case, EvaluationSet, HierarchyRun, evaluate, evaluation_set, run_hierarchy
from factorloc.fusion.graph import GraphFusion
from factorloc.fusion.product import ProductFusion
from factorloc.gating import consistency_gate, seed_audit
from factorloc.geometry import Pose2, wrap_angle
from factorloc.types import Estimate, Panorama, PointCloud, Query, Reference, Scan, StepStatus

log = logging.getLogger(__name__)

__all__ = [
    "BenchSettings",
    "bench_cost_curve",
    "bench_fusion",
    "bench_hierarchy",
    "bench_icp_vs_open3d",
    "bench_localize",
    "beyond_tolerance",
    "clopper_pearson",
    "compare_counts",
    "fit_exponent",
    "power_to_show_ratio",
    "queries_to_show_ratio",
    "rate_ratio_interval",
    "run_bench",
    "scaled_set",
]

#: ``progress(stage, done, total)``: called as each stage advances.
BenchProgress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class BenchSettings:
    """How much to measure.

    Parameters
    ----------
    repeats
        Passes over the queries for the localize and hierarchy figures; each
        query's time is its median over the passes.
    fusion_repeats
        Repeats of each fusion call (µs-scale: many repeats).
    cost_factors
        Scale factors of the cost curve (panorama width and cloud sizes × factor).
    cost_queries
        How many queries (the first ones) each cost-curve point localizes.
    icp_success_m, icp_success_rad
        An ICP alignment is a success when its error is below both.
    confidence
        Confidence of the exact intervals of the false-positive rates and of their ratio.
    fp_target_ratio
        The blind / seeded false-positive ratio to show (the issue's claim: 5).
    fp_tolerance_m, fp_tolerance_rad
        The fixed tolerance of the second false-positive definition (:func:`beyond_tolerance`):
        10 cm, 5° — gross errors (the wrong correlation peak, a look-alike's vote mode, the wrong
        ICP basin), above the honest noise of a reliable visual heading (σ up to 5°).
    """

    repeats: int = 3
    fusion_repeats: int = 20
    cost_factors: tuple[float, ...] = (0.5, 1.0, 2.0)
    cost_queries: int = 20
    icp_success_m: float = 0.05
    icp_success_rad: float = math.radians(1.0)
    confidence: float = 0.95
    fp_target_ratio: float = 5.0
    fp_tolerance_m: float = 0.10
    fp_tolerance_rad: float = math.radians(5.0)

    def __post_init__(self) -> None:
        if self.repeats < 1 or self.fusion_repeats < 1 or self.cost_queries < 1:
            raise InputError(
                "repeats, fusion_repeats and cost_queries must be >= 1, "
                f"got {self.repeats}, {self.fusion_repeats}, {self.cost_queries}"
            )
        factors = tuple(float(f) for f in self.cost_factors)
        if len(factors) < 2 or any(not (f > 0 and math.isfinite(f)) for f in factors):
            raise InputError(f"cost_factors needs at least 2 positive scale factors, got {self.cost_factors!r}")
        object.__setattr__(self, "cost_factors", factors)
        _check_confidence(self.confidence)
        for name in ("fp_target_ratio", "fp_tolerance_m", "fp_tolerance_rad"):
            if not getattr(self, name) > 0.0:
                raise InputError(f"{name} must be > 0, got {getattr(self, name)!r}")


def _ms_stats(seconds: np.ndarray) -> dict[str, float]:
    s = np.asarray(seconds, dtype=np.float64)
    s = s[np.isfinite(s)]
    if s.size == 0:
        return {"median_ms": math.nan, "p95_ms": math.nan, "mean_ms": math.nan}
    return {"median_ms": 1e3 * float(np.median(s)), "p95_ms": 1e3 * float(np.percentile(s, 95)), "mean_ms": 1e3 * float(s.mean())}


def _ratio(num: float, den: float) -> float:
    return num / den if den > 0 and math.isfinite(num) and math.isfinite(den) else math.nan


# --------------------------------------------------------------------------
# localize() per query and per step
# --------------------------------------------------------------------------
def _per_query_median(runs: Sequence[HierarchyRun]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Per query, the median over repeats of localize() time and of each step's time (s)."""
    total = np.median(np.array([[q.localize_seconds for q in r.runs] for r in runs]), axis=0)
    steps = {}
    for name in runs[0].step_names:
        per = np.array([[next((s.seconds for s in q.reports if s.name == name), math.nan) for q in r.runs] for r in runs])
        skipped = np.array(
            [[next((s.status is StepStatus.SKIPPED for s in q.reports if s.name == name), True) for q in r.runs] for r in runs]
        )
        per[skipped] = math.nan
        with np.errstate(all="ignore"):
            steps[name] = np.nanmedian(per, axis=0) if np.isfinite(per).any() else np.full(per.shape[1], math.nan)
    return total, steps


def bench_localize(runs: Sequence[HierarchyRun]) -> dict[str, Any]:
    """Time of ``localize()`` per query and of each step (ms), from repeated :class:`HierarchyRun` passes.

    Each query's time is its median over the passes; the figures are the
    median, 95th percentile and mean over queries. A step's figures exclude
    the queries where it was skipped (its inputs absent).
    """
    if not runs:
        raise InputError("bench_localize needs at least one HierarchyRun")
    total, steps = _per_query_median(runs)
    out: dict[str, Any] = {"queries": int(total.size), "repeats": len(runs), **_ms_stats(total)}
    out["steps"] = {name: _ms_stats(v) for name, v in steps.items()}
    out["prepare_ms"] = {k: 1e3 * v for k, v in runs[0].prepare_seconds.items()}
    return out


# --------------------------------------------------------------------------
# Exact binomial statistics (for counts of rare events)
# --------------------------------------------------------------------------
def _check_count(count: int, trials: int) -> None:
    if not (0 <= count <= trials):
        raise InputError(f"need 0 <= count <= trials, got count={count!r}, trials={trials!r}")


def _check_confidence(confidence: float) -> None:
    if not 0.0 < confidence < 1.0:
        raise InputError(f"confidence must be in (0, 1), got {confidence!r}")


def clopper_pearson(count: int, trials: int, confidence: float = 0.95) -> tuple[float, float]:
    """Exact (Clopper–Pearson) two-sided interval of the binomial rate ``count / trials``.

    ``[B(α/2; k, n − k + 1), B(1 − α/2; k + 1, n − k)]`` with ``B(q; a, b)`` the
    beta distribution's quantile and ``α = 1 − confidence`` (Clopper & Pearson,
    Biometrika 26, 1934); the lower end is 0 when ``k = 0``, the upper 1 when
    ``k = n``. ``(nan, nan)`` with no trial.
    """
    _check_count(count, trials)
    _check_confidence(confidence)
    if trials == 0:
        return math.nan, math.nan
    a = 1.0 - confidence
    lo = 0.0 if count == 0 else float(beta_dist.ppf(a / 2.0, count, trials - count + 1))
    hi = 1.0 if count == trials else float(beta_dist.ppf(1.0 - a / 2.0, count + 1, trials - count))
    return lo, hi


def _ratio_of_share(share: float, trials_num: float, trials_den: float) -> float:
    """ρ from the conditional share π = ρ·n₁ / (ρ·n₁ + n₂): ρ = π·n₂ / ((1 − π)·n₁)."""
    if share >= 1.0:
        return math.inf
    return share * trials_den / ((1.0 - share) * trials_num)


def rate_ratio_interval(
    count_num: float,
    trials_num: float,
    count_den: float,
    trials_den: float,
    confidence: float = 0.95,
    *,
    one_sided: bool = False,
) -> tuple[float, float]:
    """Exact conditional interval of the ratio ρ of two rare-event rates, ``(k₁/n₁) / (k₂/n₂)``.

    Given the total ``m = k₁ + k₂``, ``k₁`` is binomial(m, π) with
    ``π = ρ·n₁ / (ρ·n₁ + n₂)`` (Poisson approximation of rare events: the
    classical exact test of two rates, e.g. Breslow & Day 1987, §2.2); the
    Clopper–Pearson interval of π maps to ρ. With ``one_sided`` the result is
    ``(lower bound at confidence, inf)``. ``(nan, nan)`` when ``m = 0``: no
    event on either side, nothing to compare. Counts may be non-integer
    (expected counts, :func:`queries_to_show_ratio`).
    """
    _check_confidence(confidence)
    if min(count_num, count_den) < 0 or min(trials_num, trials_den) <= 0:
        raise InputError(f"counts must be >= 0 and trials > 0, got {count_num!r}/{trials_num!r} and {count_den!r}/{trials_den!r}")
    if count_num + count_den == 0:
        return math.nan, math.nan
    a = 1.0 - confidence
    q_lo = a if one_sided else a / 2.0
    lo = 0.0 if count_num == 0 else float(beta_dist.ppf(q_lo, count_num, count_den + 1))
    if one_sided:
        return _ratio_of_share(lo, trials_num, trials_den), math.inf
    hi = 1.0 if count_den == 0 else float(beta_dist.ppf(1.0 - a / 2.0, count_num + 1, count_den))
    return _ratio_of_share(lo, trials_num, trials_den), _ratio_of_share(hi, trials_num, trials_den)


def power_to_show_ratio(queries: int, rate_num: float, rate_den: float, target: float = 5.0, confidence: float = 0.95) -> float:
    """Probability that ``queries`` per mode show ``ratio ≥ target`` if the rates are the true ones.

    Exact: the sum, over the binomial counts ``k₁ ~ B(n, rate_num)``,
    ``k₂ ~ B(n, rate_den)`` (independent), of the probability of the pairs whose
    one-sided lower bound (:func:`rate_ratio_interval`) reaches ``target``
    (tails below 1e-12 left out).
    """
    if queries < 1 or not (0.0 <= rate_num <= 1.0 and 0.0 <= rate_den <= 1.0):
        raise InputError(f"need queries >= 1 and rates in [0, 1], got {queries!r}, {rate_num!r}, {rate_den!r}")
    _check_confidence(confidence)

    def support(p: float) -> np.ndarray:
        lo, hi = binom_dist.ppf(1e-12, queries, p), binom_dist.isf(1e-12, queries, p)
        return np.arange(int(lo), int(hi) + 1)

    k1, k2 = support(rate_num), support(rate_den)
    p1, p2 = binom_dist.pmf(k1, queries, rate_num), binom_dist.pmf(k2, queries, rate_den)
    a1, a2 = np.meshgrid(k1.astype(np.float64), k2.astype(np.float64), indexing="ij")
    with np.errstate(all="ignore"):
        share = np.where(a1 > 0, beta_dist.ppf(1.0 - confidence, np.maximum(a1, 1e-300), a2 + 1.0), 0.0)
        # ρ ≥ target ⇔ π ≥ target / (1 + target) for equal sample sizes
        shown = share >= target / (1.0 + target)
    return float(np.sum(np.outer(p1, p2)[shown]))


def queries_to_show_ratio(
    rate_num: float,
    rate_den: float,
    target: float = 5.0,
    confidence: float = 0.95,
    *,
    power: float | None = None,
    max_queries: int = 10**7,
) -> int | None:
    """Fewest queries (per mode) that would show ``rate_num / rate_den ≥ target``.

    Without ``power``: the one-sided lower bound of :func:`rate_ratio_interval`
    computed on the *expected* counts ``n·rate`` must reach ``target`` — about an
    even chance of showing it with that many queries if the rates are the true
    ones. With ``power``: :func:`power_to_show_ratio` must reach it (found by
    bisection; the exact power is slightly saw-toothed in n). ``None`` when
    ``rate_num`` is 0 or the ratio of the rates does not exceed ``target`` (no
    number of queries would show it), or beyond ``max_queries``. With
    ``rate_den = 0`` and no power this is the closed form
    ``n·rate_num ≥ ln α / ln(target / (1 + target))`` (16.4 events for 5× at 95 %).
    """
    if not (rate_num >= 0.0 and rate_den >= 0.0 and target > 0.0):
        raise InputError(f"rates must be >= 0 and target > 0, got {rate_num!r}, {rate_den!r}, {target!r}")
    if power is not None and not 0.0 < power < 1.0:
        raise InputError(f"power must be in (0, 1), got {power!r}")
    if rate_num == 0.0 or rate_num <= target * rate_den:
        return None

    def shown(n: int) -> bool:
        if power is not None:
            return power_to_show_ratio(n, rate_num, rate_den, target, confidence) >= power
        return rate_ratio_interval(n * rate_num, n, n * rate_den, n, confidence, one_sided=True)[0] >= target

    hi = 1
    while not shown(hi):
        hi *= 2
        if hi > max_queries:
            return None
    lo = hi // 2
    while hi - lo > 1:
        mid = (lo + hi) // 2
        lo, hi = (lo, mid) if shown(mid) else (mid, hi)
    return hi


# --------------------------------------------------------------------------
# Seeded vs blind
# --------------------------------------------------------------------------
def beyond_tolerance(errors: np.ndarray, covariance: np.ndarray, tolerance_m: float, tolerance_rad: float) -> bool:
    """Whether an estimate's error exceeds a fixed tolerance in what it determines.

    Parameters
    ----------
    errors
        (3,) world-frame error ``estimate − truth`` (m, m, rad), ``nan`` where unmeasured.
    covariance
        (3, 3) world-frame covariance, ``inf`` variance where unmeasured.
    tolerance_m, tolerance_rad
        The position error (norm over the determined directions) and heading error allowed.

    Notes
    -----
    A position is judged along the eigen-directions of its 2×2 covariance whose
    σ is below half :data:`~factorloc.estimators.icp.UNCONSTRAINED_SIGMA_M`
    (the pipeline's "undetermined" test, :func:`factorloc.gating.unconstrained_position`):
    an ICP estimate that only fixes the position across a wall claims nothing
    along it.
    """
    e = np.asarray(errors, dtype=np.float64).reshape(3)
    cov = np.asarray(covariance, dtype=np.float64).reshape(3, 3)
    if math.isfinite(cov[2, 2]) and math.isfinite(e[2]) and abs(e[2]) > tolerance_rad:
        return True
    p = cov[:2, :2]
    if np.all(np.isfinite(p)) and np.all(np.isfinite(e[:2])):
        w, v = np.linalg.eigh(p)
        keep = w < (0.5 * UNCONSTRAINED_SIGMA_M) ** 2
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
            t_row[j] = beyond_tolerance(err[0], cov, tolerance_m, tolerance_rad)
        loc = q.localization
        err = metrics.pose_errors(loc.pose.as_array()[None], truth)
        cov = np.asarray(loc.covariance, dtype=np.float64)
        full = bool(np.all(np.isfinite(np.diag(cov))))
        f3.append(bool(metrics.confidently_wrong(err, cov[None])[0]))
        ft.append(full and beyond_tolerance(err[0], cov, tolerance_m, tolerance_rad))
        rel.append(r_row)
        s3.append(s_row)
        tol.append(t_row)
    shape = (len(rel), len(names))
    arr = (lambda rows: np.array(rows, dtype=bool).reshape(shape)) if rel else (lambda rows: np.zeros(shape, bool))
    return _Outcomes(names, arr(rel), arr(s3), arr(tol), np.array(f3, dtype=bool), np.array(ft, dtype=bool))


def _false_positives(run: HierarchyRun, outcomes: _Outcomes | None = None) -> dict[str, Any]:
    """Per step and in total: reliable estimates whose error exceeds 3σ (over queries with truth).

    The total leaves out the first step of the hierarchy: it has no
    predecessors, so seeding cannot change it (its false positives are the
    same seeded and blind and would only dilute the ratio). ``outcomes``:
    :func:`_outcomes` of ``run`` when already computed.
    """
    o = outcomes if outcomes is not None else _outcomes(run, math.inf, math.inf)
    n_truth = int(o.reliable.shape[0])
    per_step = dict(zip(o.step_names, o.sigma3.sum(axis=0).tolist(), strict=True))
    reliable = dict(zip(o.step_names, o.reliable.sum(axis=0).tolist(), strict=True))
    total = sum(v for k, v in per_step.items() if k != run.step_names[0])
    return {
        "queries_with_truth": n_truth,
        "false_positive_count": total,
        "false_positive_rate": total / n_truth if n_truth else math.nan,
        "steps": {
            name: {
                "false_positive_count": per_step[name],
                "reliable_count": reliable[name],
                "false_positive_rate": per_step[name] / n_truth if n_truth else math.nan,
            }
            for name in o.step_names
        },
    }


def _mode_figures(count: int, trials: int, confidence: float, reliable: int | None = None) -> dict[str, Any]:
    out: dict[str, Any] = {
        "count": int(count),
        "queries": int(trials),
        "rate": count / trials if trials else math.nan,
        "rate_ci": list(clopper_pearson(int(count), int(trials), confidence)),
    }
    if reliable is not None:
        out["reliable"] = int(reliable)
        out["per_reliable"] = count / reliable if reliable else math.nan
        out["per_reliable_ci"] = list(clopper_pearson(int(count), int(reliable), confidence)) if reliable else [math.nan] * 2
    return out


def compare_counts(
    seeded_count: int,
    blind_count: int,
    queries: int,
    *,
    confidence: float = 0.95,
    target: float = 5.0,
    seeded_reliable: int | None = None,
    blind_reliable: int | None = None,
) -> dict[str, Any]:
    """Blind vs seeded false positives on the same ``queries``: rates, ratio and their exact intervals.

    Returns ``seeded`` / ``blind`` (``count``, ``queries``, ``rate`` and its
    Clopper–Pearson ``rate_ci``; with reliable counts also ``per_reliable`` and
    its interval), ``ratio`` = blind / seeded rate (``inf`` when only blind has
    some, ``nan`` when neither), ``ratio_ci`` (two-sided, :func:`rate_ratio_interval`),
    ``ratio_lower_bound`` (one-sided at ``confidence``), ``shows_target``
    (that bound ≥ ``target``) and ``queries_needed`` (:func:`queries_to_show_ratio`
    at the observed rates, a seeded 0 taken as 0: the best case; ``None`` when
    the observed rates could never show it; ``queries_needed_power_80``: for an
    80 % chance, :func:`power_to_show_ratio`).
    """
    if queries < 1:
        raise InputError(f"queries must be >= 1, got {queries!r}")
    out: dict[str, Any] = {
        "seeded": _mode_figures(seeded_count, queries, confidence, seeded_reliable),
        "blind": _mode_figures(blind_count, queries, confidence, blind_reliable),
    }
    if seeded_count == blind_count == 0:
        out["ratio"] = math.nan
    else:
        out["ratio"] = blind_count / seeded_count if seeded_count else math.inf
    out["ratio_ci"] = list(rate_ratio_interval(blind_count, queries, seeded_count, queries, confidence))
    out["ratio_lower_bound"] = rate_ratio_interval(blind_count, queries, seeded_count, queries, confidence, one_sided=True)[0]
    out["shows_target"] = bool(out["ratio_lower_bound"] >= target)  # nan >= target is False
    rates = (blind_count / queries, seeded_count / queries)
    out["queries_needed"] = queries_to_show_ratio(*rates, target, confidence)
    out["queries_needed_power_80"] = queries_to_show_ratio(*rates, target, confidence, power=0.8)
    return out


def bench_hierarchy(
    seeded_runs: Sequence[HierarchyRun], blind_runs: Sequence[HierarchyRun], *, settings: BenchSettings = BenchSettings()
) -> dict[str, Any]:
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
    (:func:`compare_counts`: exact intervals at ``settings.confidence``, the
    one-sided lower bound of the ratio, the queries needed to show
    ``settings.fp_target_ratio``) for two definitions of a false positive —
    ``sigma3`` (reliable, off by > 3σ in a measured component: the headline)
    and ``tolerance`` (reliable, off by more than ``settings.fp_tolerance_m`` /
    ``fp_tolerance_rad``, :func:`beyond_tolerance`) — per step, for "any step
    after the first" per query (``steps_after_first``), and for the fused
    result (``fused``: fully determined and wrong).
    """
    out: dict[str, Any] = {}
    outcomes: dict[str, _Outcomes] = {}
    for label, runs in (("seeded", seeded_runs), ("blind", blind_runs)):
        if not runs:
            raise InputError(f"bench_hierarchy needs at least one {label} HierarchyRun")
        total, steps = _per_query_median(runs)
        outcomes[label] = _outcomes(runs[0], settings.fp_tolerance_m, settings.fp_tolerance_rad)
        fp = _false_positives(runs[0], outcomes[label])
        report = evaluate(runs[0]).to_json_dict()
        out[label] = {
            **_ms_stats(total),
            "steps_median_ms": {k: _ms_stats(v)["median_ms"] for k, v in steps.items()},
            **{k: v for k, v in fp.items() if k != "steps"},
            "steps_false_positive_count": {k: v["false_positive_count"] for k, v in fp["steps"].items()},
            "steps_reliable_count": {k: v["reliable_count"] for k, v in fp["steps"].items()},
            "steps_false_positive_per_reliable": {
                k: (v["false_positive_count"] / v["reliable_count"] if v["reliable_count"] else math.nan)
                for k, v in fp["steps"].items()
            },
            "steps_reliable_rate": {k: v["reliable_rate"] for k, v in report["steps"].items()},
            "confidently_wrong_rate": report["confidently_wrong_rate"],
            "confidently_wrong_count": report["confidently_wrong_count"],
            "determined_rate": report["determined_rate"],
            "position_rmse_m": report["position_rmse_m"],
            "heading_rmse_deg": report["heading_rmse_deg"],
        }
    s, b = out["seeded"], out["blind"]
    out["time_ratio"] = _ratio(b["median_ms"], s["median_ms"])
    for key, count in (("false_positive_ratio", "false_positive_count"), ("confidently_wrong_ratio", "confidently_wrong_count")):
        # none on either side: no ratio to claim (nan); none seeded only: the blind count is a lower bound
        out[key] = b[count] / max(s[count], 1) if b[count] or s[count] else math.nan
        out[f"{key}_is_lower_bound"] = s[count] == 0 and b[count] > 0
    out["false_positives"] = _false_positive_comparison(outcomes["seeded"], outcomes["blind"], settings)
    return out


def _false_positive_comparison(seeded: _Outcomes, blind: _Outcomes, settings: BenchSettings) -> dict[str, Any]:
    if seeded.step_names != blind.step_names or seeded.reliable.shape != blind.reliable.shape:
        raise InputError("the seeded and blind runs must cover the same steps and queries")
    n = int(seeded.reliable.shape[0])
    out: dict[str, Any] = {
        "headline": "sigma3",
        "confidence": settings.confidence,
        "target_ratio": settings.fp_target_ratio,
        "tolerance_m": settings.fp_tolerance_m,
        "tolerance_deg": math.degrees(settings.fp_tolerance_rad),
        "queries": n,
    }
    if n == 0:
        return out
    kw = {"confidence": settings.confidence, "target": settings.fp_target_ratio}
    later = slice(1, None)  # the first step has no predecessor: seeding cannot change it
    for label, s_flags, b_flags, s_fused, b_fused in (
        ("sigma3", seeded.sigma3, blind.sigma3, seeded.fused_sigma3, blind.fused_sigma3),
        ("tolerance", seeded.tolerance, blind.tolerance, seeded.fused_tolerance, blind.fused_tolerance),
    ):
        out.setdefault("steps_after_first", {})[label] = compare_counts(
            int(s_flags[:, later].any(axis=1).sum()), int(b_flags[:, later].any(axis=1).sum()), n, **kw
        )
        out.setdefault("fused", {})[label] = compare_counts(int(s_fused.sum()), int(b_fused.sum()), n, **kw)
        for j, name in enumerate(seeded.step_names):
            out.setdefault("steps", {}).setdefault(name, {})[label] = compare_counts(
                int(s_flags[:, j].sum()),
                int(b_flags[:, j].sum()),
                n,
                seeded_reliable=int(seeded.reliable[:, j].sum()),
                blind_reliable=int(blind.reliable[:, j].sum()),
                **kw,
            )
    return out


# --------------------------------------------------------------------------
# ICP vs Open3D
# --------------------------------------------------------------------------
def bench_icp_vs_open3d(
    data: EvaluationSet, config: Config | None = None, *, settings: BenchSettings = BenchSettings()
) -> dict[str, Any]:
    """Our point-to-line ICP vs Open3D point-to-plane ICP: same scan pairs, same seeds.

    Pairs: every query with a scan or cloud and ground truth, against its
    reference's scan (or cloud cut), both extracted as the ICP step does.
    Seed: the query's odometry pose (the truth when absent) in the reference
    frame. Both get our target normals (Open3D's own are meaningless in 2D)
    and the same maximum correspondence distance; the target's KD-tree and
    normals are prepared once, outside the timing (Open3D builds its KD-tree
    inside the call — part of its cost). Errors are against the true
    ``T_reference_query``.

    ``time_ratio`` = Open3D / ours (> 1: ours faster); ``error_ratio`` =
    Open3D / ours median translation error (> 1: ours more accurate).
    """
    from factorloc.estimators.icp import prepare_reference, query_points
    from factorloc.registration.icp2d import align
    from factorloc.registration.kernels import kernel_from_name
    from factorloc.registration.open3d_peer import open3d_icp

    cfg = (config or Config()).icp
    kernel = kernel_from_name(cfg.alignment.kernel, cfg.alignment.kernel_scale_m)
    prepared: dict[str, Any] = {}
    rows = []
    for case in data.cases:
        if case.truth is None:
            continue
        pts = query_points(case.query, cfg)
        if pts is None or len(pts) < max(3, cfg.reliability.min_inliers):
            continue
        if case.reference_id not in prepared:
            prepared[case.reference_id] = prepare_reference(data.reference_of(case), cfg)
        target = prepared[case.reference_id]
        if target is None:
            continue
        T_rw = target.T_world_reference.inverse()
        seed_world = case.query.odometry.T_world_robot if case.query.odometry is not None else case.truth
        seed = T_rw * seed_world
        true_rq = T_rw * case.truth
        t0 = time.perf_counter()
        ours = align(target.target, pts, seed, cfg.alignment.icp, kernel).T_target_source
        t1 = time.perf_counter()
        peer = open3d_icp(
            target.points_m,
            pts,
            seed,
            method="point_to_plane",
            target_normals=target.target.normals,
            max_correspondence_m=cfg.alignment.icp.max_correspondence_m,
            max_iterations=cfg.alignment.icp.max_iterations,
        ).T_target_source
        t2 = time.perf_counter()
        rows.append((t1 - t0, t2 - t1, _se2_error(ours, true_rq), _se2_error(peer, true_rq)))
    if not rows:
        return {"pairs": 0}
    a = np.array([(r[0], r[1], r[2][0], r[2][1], r[3][0], r[3][1]) for r in rows])
    ok_ours = (a[:, 2] < settings.icp_success_m) & (a[:, 3] < settings.icp_success_rad)
    ok_peer = (a[:, 4] < settings.icp_success_m) & (a[:, 5] < settings.icp_success_rad)
    out = {
        "pairs": len(rows),
        "ours_median_ms": 1e3 * float(np.median(a[:, 0])),
        "open3d_median_ms": 1e3 * float(np.median(a[:, 1])),
        "ours_median_error_m": float(np.median(a[:, 2])),
        "open3d_median_error_m": float(np.median(a[:, 4])),
        "ours_median_error_deg": math.degrees(float(np.median(a[:, 3]))),
        "open3d_median_error_deg": math.degrees(float(np.median(a[:, 5]))),
        "ours_success_rate": float(ok_ours.mean()),
        "open3d_success_rate": float(ok_peer.mean()),
    }
    out["time_ratio"] = _ratio(out["open3d_median_ms"], out["ours_median_ms"])
    out["error_ratio"] = _ratio(out["open3d_median_error_m"], out["ours_median_error_m"])
    return out


def _se2_error(est: Pose2, true: Pose2) -> tuple[float, float]:
    d = true.between(est)
    return math.hypot(d.x, d.y), abs(float(wrap_angle(d.theta)))


# --------------------------------------------------------------------------
# GTSAM vs product
# --------------------------------------------------------------------------
def _gated_inputs(reports: Sequence[Any], probability: float, consistency: bool, audit: bool = True) -> list[Estimate]:
    ran = [r.estimate for r in reports if r.estimate is not None]
    contradicted = seed_audit(ran) if audit else {}
    reliable = [e for i, e in enumerate(ran) if e.reliable and i not in contradicted]
    if not consistency:
        return reliable
    out = []
    for v in consistency_gate(reliable, probability):
        part = v.accepted_estimate()
        if part is not None:
            out.append(part)
    return out


def bench_fusion(run: HierarchyRun, *, settings: BenchSettings = BenchSettings()) -> dict[str, Any]:
    """GTSAM graph vs closed-form product on each query's gated estimates: time ratio and agreement.

    Agreement is the largest difference of the fused poses (m, rad) and the
    largest relative difference of the determined variances, separately for
    queries where some estimate couples position and heading (the graph then
    uses ``PriorFactorPose2`` and the two legitimately differ).
    """
    gating = run.config.gating
    graph, product = GraphFusion(), ProductFusion()
    tg, tp, dpos, dth, dvar, coupled = [], [], [], [], [], []
    for q in run.runs:
        inputs = _gated_inputs(q.reports, gating.consistency_probability, gating.consistency, gating.seed_audit)
        if not inputs:
            continue
        times = {}
        fused = {}
        for name, strat in (("graph", graph), ("product", product)):
            ts = []
            for _ in range(settings.fusion_repeats):
                t0 = time.perf_counter()
                fused[name] = strat.fuse(inputs)
                ts.append(time.perf_counter() - t0)
            times[name] = float(np.median(ts))
        tg.append(times["graph"])
        tp.append(times["product"])
        g, p = fused["graph"], fused["product"]
        det = np.isfinite(np.diag(p.covariance))
        dpos.append(math.hypot(g.pose.x - p.pose.x, g.pose.y - p.pose.y) if det[0] else 0.0)
        dth.append(abs(float(wrap_angle(g.pose.theta - p.pose.theta))) if det[2] else 0.0)
        vg, vp = np.diag(g.covariance)[det], np.diag(p.covariance)[det]
        dvar.append(float(np.max(np.abs(vg - vp) / vp)) if vp.size else 0.0)
        coupled.append(any(e.has_cross_covariance for e in inputs))
    if not tg:
        return {"queries": 0}
    c = np.array(coupled, dtype=bool)
    dpos_a, dth_a, dvar_a = np.array(dpos), np.array(dth), np.array(dvar)

    def _max(v: np.ndarray, sel: np.ndarray) -> float:
        return float(v[sel].max()) if sel.any() else math.nan

    out = {
        "queries": len(tg),
        "graph_median_us": 1e6 * float(np.median(tg)),
        "product_median_us": 1e6 * float(np.median(tp)),
        "queries_with_cross_covariance": int(c.sum()),
        "max_position_diff_m": _max(dpos_a, ~c),
        "max_heading_diff_rad": _max(dth_a, ~c),
        "max_variance_rel_diff": _max(dvar_a, ~c),
        "max_position_diff_m_cross_covariance": _max(dpos_a, c),
        "max_heading_diff_rad_cross_covariance": _max(dth_a, c),
    }
    out["time_ratio"] = _ratio(out["graph_median_us"], out["product_median_us"])
    return out


# --------------------------------------------------------------------------
# Cost curve
# --------------------------------------------------------------------------
def _resample_points(points: np.ndarray, factor: float, rng: np.random.Generator) -> np.ndarray:
    """``round(N·factor)`` points: a random subset (factor ≤ 1) or the points plus jittered copies (1 mm)."""
    n = len(points)
    m = max(3, int(round(n * factor)))
    if m <= n:
        return points[np.sort(rng.choice(n, size=m, replace=False))]
    extra = points[rng.choice(n, size=m - n, replace=True)] + rng.normal(scale=1e-3, size=(m - n, points.shape[1]))
    return np.vstack([points, extra])


def _scaled_panorama(p: Panorama, factor: float) -> Panorama:
    w, h = max(8, int(round(p.width_px * factor))), max(4, int(round(p.height_px * factor)))
    interp = cv2.INTER_AREA if factor < 1 else cv2.INTER_LINEAR
    return Panorama(cv2.resize(p.image_bgr, (w, h), interpolation=interp), p.fov_v_rad, p.azimuth_col0_rad)


def scaled_set(data: EvaluationSet, factor: float, *, queries: int | None = None, seed: int = 0) -> EvaluationSet:
    """The evaluation set with the reference panoramas scaled by ``factor`` and every cloud and scan × ``factor`` points.

    Panoramas are resized in width and height (same field of view).

    Clouds and scans are resampled (:func:`_resample_points`: subset or jittered copies),
    so their geometry stays; query camera images are unchanged. Only the
    first ``queries`` cases are kept when given.
    """
    rng = np.random.default_rng(seed)
    refs = {}
    for rid, r in data.references.items():
        refs[rid] = Reference(
            panorama=None if r.panorama is None else _scaled_panorama(r.panorama, factor),
            cloud=None if r.cloud is None else PointCloud(_resample_points(r.cloud.points_m, factor, rng)),
            scan=None if r.scan is None else Scan(_resample_points(r.scan.points_m, factor, rng)),
            T_world_reference=r.T_world_reference,
            name=r.name,
        )
    cases = []
    for c in data.cases[: queries or len(data.cases)]:
        q = c.query
        cloud = None if q.cloud is None else PointCloud(_resample_points(q.cloud.points_m, factor, rng))
        scan = None if q.scan is None else Scan(_resample_points(q.scan.points_m, factor, rng))
        q2 = Query(images=q.images, panorama=q.panorama, cloud=cloud, scan=scan, odometry=q.odometry, id=q.id)
        cases.append(Case(q2, c.truth, c.faults, c.reference_id, c.distance_from_reference_m))
    return EvaluationSet(refs, tuple(cases), name=f"{data.name}×{factor:g}", world=data.world)


def _median_len(items: Sequence[Any]) -> float | None:
    sizes = [len(x) for x in items if x is not None]
    return float(np.median(sizes)) if sizes else None


def fit_exponent(scales: Sequence[float], times: Sequence[float]) -> float:
    """The exponent ``k`` of ``t ∝ scale^k``: least-squares slope of log t against log scale (nan with < 2 valid points)."""
    s, t = np.asarray(scales, dtype=np.float64), np.asarray(times, dtype=np.float64)
    ok = np.isfinite(s) & np.isfinite(t) & (s > 0) & (t > 0)
    if ok.sum() < 2:
        return math.nan
    return float(np.polyfit(np.log(s[ok]), np.log(t[ok]), 1)[0])


def bench_cost_curve(
    data: EvaluationSet,
    config: Config | None = None,
    *,
    settings: BenchSettings = BenchSettings(),
    progress: BenchProgress | None = None,
) -> dict[str, Any]:
    """Time per query (median over the first ``cost_queries`` queries) at each scale factor, and the fitted exponents.

    At factor f the reference panorama is f× wider (and higher), every
    reference and query cloud has f× as many points (:func:`scaled_set`).
    ``exponent`` fits the total time, ``steps_exponent`` each step's.
    """
    rows = []
    for i, f in enumerate(settings.cost_factors):
        scaled = scaled_set(data, f, queries=settings.cost_queries)
        run = run_hierarchy(scaled, config)
        total, steps = _per_query_median([run])
        ref = next(iter(scaled.references.values()))
        rows.append(
            {
                "factor": f,
                "panorama_width_px": None if ref.panorama is None else ref.panorama.width_px,
                "reference_cloud_points": None if ref.cloud is None else len(ref.cloud),
                "reference_scan_points": None if ref.scan is None else len(ref.scan),
                "query_cloud_points_median": _median_len([c.query.cloud for c in scaled.cases]),
                "median_ms": 1e3 * float(np.median(total)),
                "steps_median_ms": {k: _ms_stats(v)["median_ms"] for k, v in steps.items()},
            }
        )
        if progress is not None:
            progress("cost curve", i + 1, len(settings.cost_factors))
    factors = [r["factor"] for r in rows]
    step_names = list(rows[0]["steps_median_ms"])
    return {
        "points": rows,
        "exponent": fit_exponent(factors, [r["median_ms"] for r in rows]),
        "steps_exponent": {n: fit_exponent(factors, [r["steps_median_ms"][n] for r in rows]) for n in step_names},
    }


# --------------------------------------------------------------------------
# Everything
# --------------------------------------------------------------------------
def run_bench(
    scenario: Any,
    config: Config | None = None,
    *,
    settings: BenchSettings = BenchSettings(),
    progress: BenchProgress | None = None,
) -> dict[str, Any]:
    """All the benchmarks on one scenario; a JSON-ready dict (keys in ``docs/evaluation.md``).

    Parameters
    ----------
    scenario
        A :class:`factorloc.datasets.Scenario` or :class:`~factorloc.evaluation.EvaluationSet`.
    config
        The configuration (defaults if None).
    settings
        Repeats, cost-curve factors, ….
    progress
        ``progress(stage, done, total)``; stages: ``"seeded"``, ``"blind"``,
        ``"icp vs open3d"``, ``"fusion"``, ``"cost curve"``.
    """
    data = evaluation_set(scenario)
    cfg = config or Config()
    n = len(data.cases)

    def passes(label: str, seeded: bool) -> list[HierarchyRun]:
        runs = []
        for k in range(settings.repeats):
            cb = None if progress is None else (lambda d, t, k=k: progress(label, k * t + d, settings.repeats * t))
            runs.append(run_hierarchy(data, cfg, seeded=seeded, progress=cb))
        return runs

    t_start = time.perf_counter()
    load_before = _load_average()
    seeded = passes("seeded", True)
    blind = passes("blind", False)
    out: dict[str, Any] = {
        "scenario": data.name,
        "queries": n,
        "settings": {
            "repeats": settings.repeats,
            "fusion_repeats": settings.fusion_repeats,
            "cost_factors": list(settings.cost_factors),
            "cost_queries": settings.cost_queries,
        },
        "localize": bench_localize(seeded),
        "hierarchy": bench_hierarchy(seeded, blind, settings=settings),
    }
    out["icp_vs_open3d"] = bench_icp_vs_open3d(data, cfg, settings=settings)
    if progress is not None:
        progress("icp vs open3d", 1, 1)
    out["fusion"] = bench_fusion(seeded[0], settings=settings)
    if progress is not None:
        progress("fusion", 1, 1)
    out["cost_curve"] = bench_cost_curve(data, cfg, settings=replace(settings), progress=progress)
    out["peak_memory_mb"] = seeded[0].peak_memory_mb
    out["wall_seconds"] = time.perf_counter() - t_start
    out["machine"] = {
        "cpu_count": os.cpu_count(),
        "usable_cpus": len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
        "load_average_1min_before": load_before,
        "load_average_1min_after": _load_average(),
        "opencv_threads": cv2.getNumThreads(),
    }
    return _json_safe(out)


def _load_average() -> float:
    """The 1-minute load average (nan where the platform has none): other work competing for the CPU."""
    try:
        return float(os.getloadavg()[0])
    except (AttributeError, OSError):
        return math.nan


def _json_safe(v: Any) -> Any:
    if isinstance(v, dict):
        return {k: _json_safe(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_json_safe(x) for x in v]
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, (float, np.floating)):
        return float(v) if math.isfinite(v) else None
    if isinstance(v, np.integer):
        return int(v)
    return v

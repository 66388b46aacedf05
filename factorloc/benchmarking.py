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
    :func:`factorloc.evaluation.metrics.confidently_wrong` applied per step).
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

from factorloc.config import Config
from factorloc.errors import InputError
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
    "fit_exponent",
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
    """

    repeats: int = 3
    fusion_repeats: int = 20
    cost_factors: tuple[float, ...] = (0.5, 1.0, 2.0)
    cost_queries: int = 20
    icp_success_m: float = 0.05
    icp_success_rad: float = math.radians(1.0)

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
# Seeded vs blind
# --------------------------------------------------------------------------
def _false_positives(run: HierarchyRun) -> dict[str, Any]:
    """Per step and in total: reliable estimates whose error exceeds 3σ (over queries with truth).

    The total leaves out the first step of the hierarchy: it has no
    predecessors, so seeding cannot change it (its false positives are the
    same seeded and blind and would only dilute the ratio).
    """
    per_step: dict[str, int] = {}
    reliable: dict[str, int] = {}
    n_truth = 0
    for q in run.runs:
        if q.case.truth is None:
            continue
        n_truth += 1
        for r in q.reports:
            est = r.estimate
            if est is None or not est.reliable:
                continue
            reliable[r.name] = reliable.get(r.name, 0) + 1
            err = metrics.pose_errors(metrics.values_of_estimate(est)[None], q.case.truth.as_array()[None])
            cov = metrics.covariance_of_estimate(est)[None]
            if metrics.confidently_wrong(err, cov, reliable=np.array([True]))[0]:
                per_step[r.name] = per_step.get(r.name, 0) + 1
    total = sum(v for k, v in per_step.items() if k != run.step_names[0])
    return {
        "queries_with_truth": n_truth,
        "false_positive_count": total,
        "false_positive_rate": total / n_truth if n_truth else math.nan,
        "steps": {
            name: {
                "false_positive_count": per_step.get(name, 0),
                "reliable_count": reliable.get(name, 0),
                "false_positive_rate": per_step.get(name, 0) / n_truth if n_truth else math.nan,
            }
            for name in run.step_names
        },
    }


def bench_hierarchy(seeded_runs: Sequence[HierarchyRun], blind_runs: Sequence[HierarchyRun]) -> dict[str, Any]:
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
    """
    out: dict[str, Any] = {}
    for label, runs in (("seeded", seeded_runs), ("blind", blind_runs)):
        if not runs:
            raise InputError(f"bench_hierarchy needs at least one {label} HierarchyRun")
        total, steps = _per_query_median(runs)
        fp = _false_positives(runs[0])
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
    kernel = kernel_from_name(cfg.kernel, cfg.kernel_scale_m)
    prepared: dict[str, Any] = {}
    rows = []
    for case in data.cases:
        if case.truth is None:
            continue
        pts = query_points(case.query, cfg)
        if pts is None or len(pts) < max(3, cfg.min_inliers):
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
        ours = align(target.target, pts, seed, cfg.icp, kernel).T_target_source
        t1 = time.perf_counter()
        peer = open3d_icp(
            target.points_m,
            pts,
            seed,
            method="point_to_plane",
            target_normals=target.target.normals,
            max_correspondence_m=cfg.icp.max_correspondence_m,
            max_iterations=cfg.icp.max_iterations,
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
        "hierarchy": bench_hierarchy(seeded, blind),
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

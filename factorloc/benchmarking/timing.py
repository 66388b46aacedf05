"""Speed, measured as ratios against peers in the same run on the same inputs.

- :func:`bench_localize` — full :meth:`~factorloc.Localizer.localize` per query and per step;
- :func:`bench_icp_vs_open3d` — our ICP (:func:`factorloc.registration.icp2d.align`) vs Open3D's
  point-to-plane ICP on the same scan pairs from the same seeds;
- :func:`bench_fusion` — GTSAM graph vs closed-form product on the same gated estimates.

Timings use :func:`time.perf_counter`; every figure is a median, so a stray slow repeat does not move it.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from typing import Any

import numpy as np

from factorloc.benchmarking.base import BenchSettings, per_query_median, ratio, timing
from factorloc.benchmarking.results import FusionBench, IcpVsOpen3d, LocalizeBench
from factorloc.config import Config
from factorloc.errors import InputError
from factorloc.evaluation.cases import EvaluationSet
from factorloc.evaluation.runner import HierarchyRun
from factorloc.fusion.graph import GraphFusion
from factorloc.fusion.product import ProductFusion
from factorloc.gating import StepRun, gate
from factorloc.geometry import Pose2, wrap_angle

__all__ = ["bench_fusion", "bench_icp_vs_open3d", "bench_localize"]


def bench_localize(runs: Sequence[HierarchyRun]) -> LocalizeBench:
    """Time of ``localize()`` per query and of each step (ms), from repeated :class:`HierarchyRun` passes.

    Each query's time is its median over the passes; the figures are the
    median, 95th percentile and mean over queries. A step's figures exclude
    the queries where it was skipped (its inputs absent).
    """
    if not runs:
        raise InputError("bench_localize needs at least one HierarchyRun")
    total, steps = per_query_median(runs)
    t = timing(total)
    return LocalizeBench(
        queries=int(total.size),
        repeats=len(runs),
        median_ms=t.median_ms,
        p95_ms=t.p95_ms,
        mean_ms=t.mean_ms,
        steps={name: timing(v) for name, v in steps.items()},
        prepare_ms={k: 1e3 * v for k, v in runs[0].prepare_seconds.items()},
    )


def bench_icp_vs_open3d(
    data: EvaluationSet, config: Config | None = None, *, settings: BenchSettings = BenchSettings()
) -> IcpVsOpen3d:
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
        return IcpVsOpen3d(0)
    a = np.array([(r[0], r[1], r[2][0], r[2][1], r[3][0], r[3][1]) for r in rows])
    ok_ours = (a[:, 2] < settings.icp_success_m) & (a[:, 3] < settings.icp_success_rad)
    ok_peer = (a[:, 4] < settings.icp_success_m) & (a[:, 5] < settings.icp_success_rad)
    ours_ms, peer_ms = 1e3 * float(np.median(a[:, 0])), 1e3 * float(np.median(a[:, 1]))
    ours_m, peer_m = float(np.median(a[:, 2])), float(np.median(a[:, 4]))
    return IcpVsOpen3d(
        pairs=len(rows),
        ours_median_ms=ours_ms,
        open3d_median_ms=peer_ms,
        ours_median_error_m=ours_m,
        open3d_median_error_m=peer_m,
        ours_median_error_deg=math.degrees(float(np.median(a[:, 3]))),
        open3d_median_error_deg=math.degrees(float(np.median(a[:, 5]))),
        ours_success_rate=float(ok_ours.mean()),
        open3d_success_rate=float(ok_peer.mean()),
        time_ratio=ratio(peer_ms, ours_ms),
        error_ratio=ratio(peer_m, ours_m),
    )


def _se2_error(est: Pose2, true: Pose2) -> tuple[float, float]:
    d = true.between(est)
    return math.hypot(d.x, d.y), abs(float(wrap_angle(d.theta)))


def bench_fusion(run: HierarchyRun, *, settings: BenchSettings = BenchSettings()) -> FusionBench:
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
        inputs = gate([StepRun.of_report(r) for r in q.reports], gating).accepted
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
        return FusionBench(0)
    c = np.array(coupled, dtype=bool)
    dpos_a, dth_a, dvar_a = np.array(dpos), np.array(dth), np.array(dvar)

    def _max(v: np.ndarray, sel: np.ndarray) -> float:
        return float(v[sel].max()) if sel.any() else math.nan

    graph_us, product_us = 1e6 * float(np.median(tg)), 1e6 * float(np.median(tp))
    return FusionBench(
        queries=len(tg),
        graph_median_us=graph_us,
        product_median_us=product_us,
        queries_with_cross_covariance=int(c.sum()),
        max_position_diff_m=_max(dpos_a, ~c),
        max_heading_diff_rad=_max(dth_a, ~c),
        max_variance_rel_diff=_max(dvar_a, ~c),
        max_position_diff_m_cross_covariance=_max(dpos_a, c),
        max_heading_diff_rad_cross_covariance=_max(dth_a, c),
        time_ratio=ratio(graph_us, product_us),
    )

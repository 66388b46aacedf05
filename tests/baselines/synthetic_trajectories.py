"""Synthetic trajectories with known truth: the hierarchy's reports without running the estimators.

A robot drives an ellipse (3 ± 2 m, 2.5 ± 1.5 m) queried every ~0.45 m; its
odometry integrates the true motions with independent noise of the default
:class:`~factorloc.baselines.MotionModel`. Each query carries the reports of
an odometry step (absolute dead-reckoned pose, σ grown with the distance), a
compass (heading, σ 0.01 rad) and an ICP step (full pose, σ 1 cm / 0.005 rad)
except in ``no_icp`` stretches. ``kidnap_at``: from that query on the truth
is shifted by (1.0, 0.5) m while the odometry carries on. ``outlier_at``: a
reliable "correlation" heading 0.5 rad off.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from factorloc import Config
from factorloc.baselines import MotionModel
from factorloc.evaluation import Case, EvaluationSet, HierarchyRun, QueryRun
from factorloc.geometry import Pose2
from factorloc.pipeline import fuse
from factorloc.types import Estimate, Odometry, Query, Reference, Scan, StepReport, StepStatus

STEPS = ("odometry", "compass", "correlation", "icp")
BOUNDS = (0.0, 0.0, 6.0, 5.0)


@dataclass
class Synthetic:
    queries: list[Query]
    reports: list[tuple[StepReport, ...]]
    truths: list[Pose2]
    faults: list[tuple[str, ...]]

    def run(self) -> HierarchyRun:
        ref = Reference(scan=Scan(np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])), T_world_reference=Pose2(3.0, 2.5, 0.0))
        cases = tuple(Case(q, t, f) for q, t, f in zip(self.queries, self.truths, self.faults, strict=True))
        data = EvaluationSet(ref, cases, name="synthetic")
        runs = []
        for i, (case, reps) in enumerate(zip(cases, self.reports, strict=True)):
            loc = fuse([r.estimate for r in reps if r.estimate is not None])
            runs.append(QueryRun(i, case, reps, loc, 0.0))
        return HierarchyRun(data, Config(), True, tuple(runs), {}, 0.0, STEPS)


def _report(name: str, est: Estimate | None) -> StepReport:
    if est is None:
        return StepReport(name, StepStatus.SKIPPED, None, "inputs absent", 1e-4)
    status = StepStatus.FUSED if est.reliable else StepStatus.UNRELIABLE
    return StepReport(name, status, est, est.reason, 1e-4)


def make_synthetic(
    n: int = 30,
    seed: int = 0,
    no_icp: tuple[int, int] | None = None,
    kidnap_at: int | None = None,
    outlier_at: int | None = None,
    no_odometry: bool = False,
) -> Synthetic:
    rng = np.random.default_rng(seed)
    motion = MotionModel()
    t = np.linspace(0.0, 2.0 * math.pi * n / 30.0, n)
    base = [Pose2(3.0 + 2.0 * math.cos(a), 2.5 + 1.5 * math.sin(a), a + math.pi / 2) for a in t]
    truths = []
    for k, p in enumerate(base):
        sx, sy = (1.0, 0.5) if kidnap_at is not None and k >= kidnap_at else (0.0, 0.0)
        truths.append(Pose2(p.x + sx, p.y + sy, p.theta))
    odo = [base[0]]
    dist = 0.0
    var = np.zeros(3)
    for k in range(1, n):
        d = base[k - 1].between(base[k])
        sig = motion.sigmas(d)
        noisy = Pose2(d.x + rng.normal(0, sig[0]), d.y + rng.normal(0, sig[1]), d.theta + rng.normal(0, sig[2]))
        odo.append(odo[-1].compose(noisy))
    queries, reports, faults = [], [], []
    for k in range(n):
        if k > 0:
            d = base[k - 1].between(base[k])
            dist += math.hypot(d.x, d.y)
            var = var + motion.sigmas(d) ** 2
        s = np.sqrt(var) + np.array([1e-3, 1e-3, 1e-3])
        sig_xy = float(max(s[0], s[1]) + 0.02 * dist)
        odometry = None if no_odometry else Odometry(odo[k], sig_xy, sig_xy, float(s[2] + 0.01 * dist))
        q = Query(odometry=odometry, id=f"s{k:03d}")
        truth = truths[k]
        o_est = None
        if odometry is not None:
            ok = sig_xy < 0.5 and odometry.sigma_theta_rad < 0.35
            o_est = Estimate.pose(
                "odometry", odo[k], sig_xy, sig_xy, odometry.sigma_theta_rad, reliable=ok, reason="σ" if ok else "σ too large"
            )
        c_est = Estimate.heading("compass", truth.theta + rng.normal(0, 0.01), 0.01)
        cor = None
        tags: list[str] = []
        if outlier_at is not None and k == outlier_at:
            cor = Estimate.heading("correlation", truth.theta + 0.5, 0.01)
            tags.append("outlier")
        i_est = None
        if no_icp is None or not no_icp[0] <= k <= no_icp[1]:
            i_est = Estimate.pose(
                "icp",
                Pose2(truth.x + rng.normal(0, 0.01), truth.y + rng.normal(0, 0.01), truth.theta + rng.normal(0, 0.005)),
                0.01,
                0.01,
                0.005,
            )
        else:
            tags.append("no_depth")
        if kidnap_at is not None and k == kidnap_at:
            tags.append("kidnapped")
        queries.append(q)
        reports.append(tuple(_report(nm, e) for nm, e in zip(STEPS, (o_est, c_est, cor, i_est), strict=True)))
        faults.append(tuple(tags))
    return Synthetic(queries, reports, truths, faults)


def position_errors(poses: list[Pose2], truths: list[Pose2]) -> np.ndarray:
    return np.array([math.hypot(p.x - t.x, p.y - t.y) for p, t in zip(poses, truths, strict=True)])

"""The simulated lidar against the real laser logs: ICP residual statistics and NEES per ``bias_rmse_ratio``.

For seeded scan pairs (seed 5 cm / 2° off the truth), runs the ICP step's :func:`estimate` with
several ``IcpConfig.covariance.bias_rmse_ratio`` values and prints, over the reliable full-pose estimates: the
position error, the fit's RMSE, the autocorrelation of the point-to-line residuals along the scan
(lags 1, 2, 5, 10 correspondences), and the position (2 dof) and heading (1 dof) NEES with the
share outside the 99 % ellipse. Real pairs: every N-th local relation (path < 5 m) of the Intel /
ACES logs; simulated pairs: 360° scans of the apartment within 2 m of each other, rendered by
:func:`factorloc.sim.render_scan` with its real-lidar error model, or with white noise only.
Used to set ``IcpConfig.covariance.bias_rmse_ratio`` and to check the simulator's error model against reality.

Usage::

    .venv/bin/python benchmarks/bench_lidar_model.py intel 10
    .venv/bin/python benchmarks/bench_lidar_model.py aces 10
    .venv/bin/python benchmarks/bench_lidar_model.py sim_new 40
    .venv/bin/python benchmarks/bench_lidar_model.py sim_old 40
"""

from __future__ import annotations

import math
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from factorloc.datasets.rosbag import read_laser_log
from factorloc.errors import InputError
from factorloc.estimators.base import Hypotheses
from factorloc.estimators.icp import estimate, prepare_reference
from factorloc.evaluation.relations import read_relations
from factorloc.geometry import Pose2
from factorloc.types import Estimate, Reference, Scan

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "laser"
RATIOS = (0.0, 0.2, 0.5, 0.75)


def acf(r, k):
    r = r - r.mean()
    return float(np.dot(r[:-k], r[k:]) / np.dot(r, r)) if len(r) > k + 2 else math.nan


def run_pair(ref_pts, qry_pts, true: Pose2, rng, stats):
    seed = Pose2(true.x + rng.normal(0, 0.05), true.y + rng.normal(0, 0.05), true.theta + rng.normal(0, math.radians(2)))
    hyp = Hypotheses((Estimate.pose("odometry", seed, 0.05, 0.05, math.radians(2)),))
    ref0 = prepare_reference(Reference(scan=Scan(ref_pts), T_world_reference=Pose2(0, 0, 0)))
    row = {}
    for b in RATIOS:
        cfg = replace(ref0.config, covariance=replace(ref0.config.covariance, bias_rmse_ratio=b))
        try:
            est = estimate(ref0, qry_pts, hyp, cfg)
        except InputError:
            return
        if est.kind != "full" or not est.reliable:
            return
        e = np.array([est.values[0] - true.x, est.values[1] - true.y])
        eth = math.remainder(est.values[2] - true.theta, 2 * math.pi)
        row[b] = (float(e @ np.linalg.solve(est.covariance[:2, :2], e)), eth**2 / est.covariance[2, 2])
    stats["nees"].append(row)
    stats["err_cm"].append(100 * float(np.hypot(*e)))
    d = est.diagnostics
    stats["rmse_mm"].append(1000 * d["rmse_m"])
    # residual autocorrelation along the scan: re-align to get residuals in source order
    from factorloc.registration.icp2d import align
    from factorloc.registration.kernels import kernel_from_name

    a = cfg.alignment
    res = align(ref0.target, qry_pts, Pose2(*est.values), a.icp, kernel_from_name(a.kernel, a.kernel_scale_m))
    r = np.asarray(res.residuals_m)
    stats["acf"].append([acf(r, k) for k in (1, 2, 5, 10)])


def summary(name, st):
    n = len(st["nees"])
    print(
        f"== {name}: {n} reliable pairs; median err {np.median(st['err_cm']):.2f} cm; mean err {np.mean(st['err_cm']):.2f} cm; "
        f"RMSE median {np.median(st['rmse_mm']):.1f} mm; residual ACF lag1/2/5/10 "
        + " ".join(f"{v:.2f}" for v in np.nanmedian(np.array(st["acf"]), axis=0))
    )
    for b in RATIOS:
        a = np.array([r[b] for r in st["nees"]])
        print(
            f"   ratio {b:4.2f}: pos NEES mean {a[:, 0].mean():6.2f} med {np.median(a[:, 0]):5.2f} "
            f">99% {np.mean(a[:, 0] > 9.21) * 100:4.1f} %  "
            f"head NEES mean {a[:, 1].mean():6.2f} >99% {np.mean(a[:, 1] > 6.63) * 100:4.1f} %"
        )


def real(name, every):
    log = read_laser_log(DATA / f"{name}.sort.bag")
    rel = read_relations(DATA / f"{name}.relations")
    rng = np.random.default_rng(0)
    st = {k: [] for k in ("nees", "err_cm", "rmse_mm", "acf")}
    for i in range(0, len(rel), every):
        t1, t2 = float(rel.t1_s[i]), float(rel.t2_s[i])
        dist, _ = log.odometry.distance_between(t1, t2)
        if dist >= 5.0:
            continue
        run_pair(log.scans.at(t1, 2e-3).points_m, log.scans.at(t2, 2e-3).points_m, Pose2.from_array(rel.poses[i]), rng, st)
    summary(name, st)


def sim(label, n, **kw):
    from factorloc.sim import apartment, render_scan

    world = apartment()
    rng = np.random.default_rng(3)
    x0, y0, x1, y1 = world.bounds_xy
    st = {k: [] for k in ("nees", "err_cm", "rmse_mm", "acf")}

    def free(c):
        while True:
            p = rng.uniform([x0, y0], [x1, y1])
            if world.is_free(p[None, :], c)[0]:
                return p

    tries = 0
    while len(st["nees"]) < n and tries < 5 * n:
        tries += 1
        p0 = free(0.4)
        T0 = Pose2(p0[0], p0[1], rng.uniform(-math.pi, math.pi))
        while True:
            d, a = 2.0 * math.sqrt(rng.uniform()), rng.uniform(-math.pi, math.pi)
            p = np.array([T0.x + d * math.cos(a), T0.y + d * math.sin(a)])
            if world.is_free(p[None, :], 0.3)[0]:
                break
        T1 = Pose2(p[0], p[1], rng.uniform(-math.pi, math.pi))
        try:
            s0 = render_scan(world, T0, rng=rng, **kw).points_m
            s1 = render_scan(world, T1, rng=rng, **kw).points_m
        except InputError:
            continue
        run_pair(s0, s1, T0.inverse() * T1, rng, st)
    summary(label, st)


if __name__ == "__main__":
    what = sys.argv[1]
    if what in ("intel", "aces"):
        real(what, int(sys.argv[2]))
    elif what == "sim_new":
        sim("sim 360 laser, LMS200 model", int(sys.argv[2]))
    elif what == "sim_old":
        sim(
            "sim 360 laser, old white 1 cm",
            int(sys.argv[2]),
            sigma_m=0.01,
            systematic_sigma_m=0.0,
            beam_divergence_rad=0.0,
            spot_exit_m=0.0,
        )

"""The simulated lidar against the real laser logs: the ICP step's errors and residual statistics on seeded pairs.

For seeded scan pairs (seed 5 cm / 2° off the truth), runs the ICP step's :func:`estimate` with the library's
defaults and prints, over its reliable full-pose estimates: the position error, the fit's RMSE, the
autocorrelation of the point-to-line residuals along the scan (lags 1, 2, 5 correspondences), and the position
(2 dof) and heading (1 dof) NEES with the share beyond 3σ (χ² 11.83 / 9). Real pairs: every N-th local relation
(path < 5 m) of a log in ``../shared/data/laser``; simulated pairs: 360° scans of the apartment within 2 m of
each other rendered by :func:`factorloc.sim.render_scan` with its error model (``--pose-sigma-m`` /
``--pose-sigma-deg`` override the sensor-pose error, ``--white`` keeps the white range noise only). A simulator
whose figures match the logs' predicts a robot's (issue 14); see ``docs/calibration/icp.md``.

Usage::

    .venv/bin/python benchmarks/bench_lidar_model.py intel aces mit-csail sim --every 10 --pairs 150
    .venv/bin/python benchmarks/bench_lidar_model.py sim --pose-sigma-m 0 --pose-sigma-deg 0
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from factorloc.datasets.rosbag import read_laser_log
from factorloc.errors import InputError
from factorloc.estimators.base import Hypotheses
from factorloc.estimators.icp import IcpConfig, estimate, prepare_reference
from factorloc.evaluation.relations import read_relations
from factorloc.geometry import Pose2
from factorloc.registration.icp2d import align
from factorloc.registration.kernels import kernel_from_name
from factorloc.types import Estimate, Reference, Scan

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "laser"


def acf(r: np.ndarray, k: int) -> float:
    r = r - r.mean()
    return float(np.dot(r[:-k], r[k:]) / np.dot(r, r)) if len(r) > k + 2 else math.nan


def run_pair(
    ref_pts: np.ndarray, qry_pts: np.ndarray, true: Pose2, rng: np.random.Generator, stats: dict, cfg: IcpConfig
) -> None:
    """One seeded pair: the ICP step's estimate and its figures (kept when reliable and a full pose)."""
    seed = Pose2(true.x + rng.normal(0, 0.05), true.y + rng.normal(0, 0.05), true.theta + rng.normal(0, math.radians(2)))
    hyp = Hypotheses((Estimate.pose("odometry", seed, 0.05, 0.05, math.radians(2)),))
    ref = prepare_reference(Reference(scan=Scan(ref_pts), T_world_reference=Pose2(0, 0, 0)), cfg)
    try:
        est = estimate(ref, qry_pts, hyp, cfg)
    except InputError:
        return
    if not est.reliable or est.kind != "full" or est.sigma("x") > 10.0 or est.sigma("y") > 10.0:
        return
    e = np.array([est.values[0] - true.x, est.values[1] - true.y])
    eth = math.remainder(est.values[2] - true.theta, 2 * math.pi)
    stats["nees"].append(float(e @ np.linalg.solve(est.covariance[:2, :2], e)))
    stats["nees_heading"].append(eth**2 / est.covariance[2, 2])
    stats["err_cm"].append(100 * float(np.hypot(*e)))
    stats["rmse_mm"].append(1000 * est.diagnostics["rmse_m"])
    a = cfg.alignment
    res = align(ref.target, qry_pts, Pose2(*est.values), a.icp, kernel_from_name(a.kernel, a.kernel_scale_m))
    stats["acf"].append([acf(np.asarray(res.residuals_m), k) for k in (1, 2, 5)])


def _empty() -> dict:
    return {k: [] for k in ("nees", "nees_heading", "err_cm", "rmse_mm", "acf")}


def summary(name: str, st: dict) -> str:
    p, h = np.array(st["nees"]), np.array(st["nees_heading"])
    if not len(p):
        return f"{name:34s} no reliable pair"
    lags = np.nanmedian(np.array(st["acf"]), axis=0)
    return (
        f"{name:34s} {len(p):4d}  {np.median(st['err_cm']):6.2f} {np.mean(st['err_cm']):6.2f}  {np.median(st['rmse_mm']):6.1f}  "
        + " ".join(f"{v:5.2f}" for v in lags)
        + f"  {p.mean():6.2f} {np.median(p):5.2f} {100 * np.mean(p > 11.83):5.2f}%"
        + f"  {h.mean():5.2f} {100 * np.mean(h > 9.0):5.2f}%"
    )


def real(name: str, every: int, cfg: IcpConfig, data: Path) -> dict:
    log = read_laser_log(data / f"{name}.sort.bag")
    rel = read_relations(data / f"{name}.relations")
    rng = np.random.default_rng(0)
    st = _empty()
    for i in range(0, len(rel), every):
        t1, t2 = float(rel.t1_s[i]), float(rel.t2_s[i])
        if log.odometry.distance_between(t1, t2)[0] >= 5.0:
            continue
        ref, qry = log.scans.at(t1, 2e-3).points_m, log.scans.at(t2, 2e-3).points_m
        run_pair(ref, qry, Pose2.from_array(rel.poses[i]), rng, st, cfg)
    return st


def sim(n: int, cfg: IcpConfig, **scan_kw: float) -> dict:
    from factorloc.sim import apartment, render_scan

    world = apartment()
    rng = np.random.default_rng(3)
    x0, y0, x1, y1 = world.bounds_xy
    st = _empty()

    def free(c: float) -> np.ndarray:
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
            s0 = render_scan(world, T0, rng=rng, **scan_kw).points_m
            s1 = render_scan(world, T1, rng=rng, **scan_kw).points_m
        except InputError:
            continue
        run_pair(s0, s1, T0.inverse() * T1, rng, st, cfg)
    return st


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("sources", nargs="+", help="log names (intel, aces, mit-csail) and/or 'sim'")
    ap.add_argument("--every", type=int, default=10, help="every k-th relation of a log")
    ap.add_argument("--pairs", type=int, default=150, help="simulated reliable pairs")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--pose-sigma-m", type=float, default=None, help="simulated sensor-pose error σ (m)")
    ap.add_argument("--pose-sigma-deg", type=float, default=None, help="simulated sensor-pose error σ (deg)")
    ap.add_argument("--pose-dof", type=float, default=None, help="its degrees of freedom (Student's t; inf: Gaussian)")
    ap.add_argument("--white", action="store_true", help="simulated scans with white range noise only (1 cm)")
    ap.add_argument("--sigma-mm", type=float, default=None, help="simulated statistical range error σ (mm)")
    ap.add_argument("--systematic-mm", type=float, default=None, help="simulated per-surface range offset σ (mm)")
    args = ap.parse_args()
    cfg = IcpConfig()
    print(
        f"{'source':34s} {'n':>4s}  {'err cm':>6s} {'mean':>6s}  {'rmse mm':>6s}  {'acf 1':>5s} {'2':>5s} {'5':>5s}"
        f"  {'NEES':>6s} {'med':>5s} {'>3σ':>6s}  {'θNEES':>5s} {'>3σ':>6s}"
    )
    for src in args.sources:
        if src != "sim":
            print(summary(f"{src} every {args.every}", real(src, args.every, cfg, args.data)), flush=True)
            continue
        kw: dict[str, float] = {}
        if args.white:
            kw = dict(
                sigma_m=0.01,
                systematic_sigma_m=0.0,
                beam_divergence_rad=0.0,
                spot_exit_m=0.0,
                pose_sigma_m=0.0,
                pose_sigma_rad=0.0,
            )
        if args.sigma_mm is not None:
            kw["sigma_m"] = args.sigma_mm / 1000
        if args.systematic_mm is not None:
            kw["systematic_sigma_m"] = args.systematic_mm / 1000
        if args.pose_sigma_m is not None:
            kw["pose_sigma_m"] = args.pose_sigma_m
        if args.pose_dof is not None:
            kw["pose_dof"] = args.pose_dof
        if args.pose_sigma_deg is not None:
            kw["pose_sigma_rad"] = math.radians(args.pose_sigma_deg)
        label = "sim 360° " + ("white 1 cm" if args.white else "lidar model") + "".join(f" {k}={v:g}" for k, v in kw.items())
        print(summary(label, sim(args.pairs, cfg, **kw)), flush=True)


if __name__ == "__main__":
    main()

"""Benchmark of the ICP step: the relations benchmark on the Intel and ACES laser logs (ours, ours_icp,
odometry, Open3D point-to-point and point-to-plane, same pairs and seeds, one run), the time and error
ratios against Open3D, and the NEES calibration on simulated queries.

Usage::

    .venv/bin/python benchmarks/bench_icp.py                 # every relation of both logs (~15 min on one core)
    .venv/bin/python benchmarks/bench_icp.py --every 10      # a fixed 10 % subset
    .venv/bin/python benchmarks/bench_icp.py --sim 100       # + 100 simulated queries for the NEES figures
"""

from __future__ import annotations

import argparse
import json
import math
import time
from pathlib import Path

import numpy as np

from factorloc.datasets.rosbag import read_laser_log
from factorloc.evaluation.relations import format_table, read_relations, relations_benchmark, summarize

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "laser"


def _row(rows: list[dict], method: str, subset: str) -> dict:
    return next(r for r in rows if r["method"] == method and r["subset"] == subset)


def sim_calibration(n: int, seed: int = 2) -> dict:
    """Mean NEES of (x4, y4) and the fraction outside the 99 % ellipse on simulated seeded queries."""
    from scipy.spatial import cKDTree  # noqa: F401 - keeps the import cost out of the timed part

    from factorloc.errors import InputError
    from factorloc.estimators.base import Hypotheses
    from factorloc.estimators.icp import estimate, prepare_reference, query_points
    from factorloc.geometry import Pose2
    from factorloc.sim import DepthCamera, apartment, render_cloud, render_cloud_360
    from factorloc.types import Estimate, Query, Reference

    world = apartment()
    rng = np.random.default_rng(seed)
    x0, y0, x1, y1 = world.bounds_xy

    def free(clear: float) -> np.ndarray:
        while True:
            p = rng.uniform([x0, y0], [x1, y1])
            if world.is_free(p[None, :], clear)[0]:
                return p

    nees, errs, reliable = [], [], []
    while len(reliable) < n:
        r0 = free(0.4)
        T_ref = Pose2(r0[0], r0[1], rng.uniform(-math.pi, math.pi))
        while True:
            d, a = 2.0 * math.sqrt(rng.uniform()), rng.uniform(-math.pi, math.pi)
            p = np.array([T_ref.x + d * math.cos(a), T_ref.y + d * math.sin(a)])
            if world.is_free(p[None, :], 0.3)[0]:
                break
        truth = Pose2(p[0], p[1], rng.uniform(-math.pi, math.pi))
        try:
            ref = prepare_reference(
                Reference(cloud=render_cloud_360(world, T_ref, DepthCamera(stride_px=4), rng), T_world_reference=T_ref)
            )
            pts = query_points(Query(cloud=render_cloud(world, truth, DepthCamera(stride_px=2), rng)), ref.config)
            seed = Pose2(
                truth.x + rng.normal(0, 0.05), truth.y + rng.normal(0, 0.05), truth.theta + rng.normal(0, math.radians(2))
            )
            est = estimate(ref, pts, Hypotheses((Estimate.pose("odometry", seed, 0.05, 0.05, math.radians(2)),)))
        except InputError:
            continue
        reliable.append(est.reliable)
        if est.reliable:
            e = np.array([est.values[0] - truth.x, est.values[1] - truth.y])
            nees.append(float(e @ np.linalg.solve(est.covariance[:2, :2], e)))
            errs.append(float(np.hypot(*e)))
    nees_a = np.array(nees)
    return {
        "queries": n,
        "reliable_rate": float(np.mean(reliable)),
        "median_error_cm": 100 * float(np.median(errs)),
        "nees_mean": float(nees_a.mean()),
        "nees_median": float(np.median(nees_a)),
        "outside_99_rate": float(np.mean(nees_a > 9.2103)),
    }


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--every", type=int, default=1, help="use every k-th relation (fixed subset)")
    ap.add_argument("--datasets", default="intel,aces")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--sim", type=int, default=0, help="number of simulated queries for the NEES figures (0 = skip)")
    ap.add_argument("--json", type=Path, default=None, help="write the table rows here")
    args = ap.parse_args()
    all_rows: list[dict] = []
    for name in args.datasets.split(","):
        log = read_laser_log(args.data / f"{name}.sort.bag")
        rel = read_relations(args.data / f"{name}.relations").subset(args.every)
        t0 = time.perf_counter()
        rows = summarize(relations_benchmark(log, rel), name)
        all_rows += rows
        print(format_table(rows))
        ours, peer = _row(rows, "ours", "local"), _row(rows, "open3d_p2plane", "local")
        icp = _row(rows, "ours_icp", "local")
        print(
            f"{name}: local translation error ours/open3d_p2plane = {ours['trans_mean_cm'] / peer['trans_mean_cm']:.2f} "
            f"(ICP alone {icp['trans_mean_cm'] / peer['trans_mean_cm']:.2f}); "
            f"time per pair open3d_p2plane/ours = {peer['ms_per_pair'] / ours['ms_per_pair']:.2f}; "
            f"loop recovered {100 * _row(rows, 'ours', 'loop')['recovered_rate']:.1f} %, "
            f"unrecovered flagged {100 * _row(rows, 'ours', 'loop')['unrecovered_flagged_rate']:.1f} %; "
            f"{time.perf_counter() - t0:.0f} s\n"
        )
    if args.sim:
        cal = sim_calibration(args.sim)
        print("simulated seeded queries (apartment, single 58° depth view within 2 m of a 360° reference):")
        print("  " + ", ".join(f"{k} {v:.3g}" for k, v in cal.items()))
    if args.json:
        args.json.write_text(json.dumps(all_rows, indent=1))


if __name__ == "__main__":
    main()

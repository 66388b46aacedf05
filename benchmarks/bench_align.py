"""Benchmark of the ICP core alone: :func:`factorloc.registration.icp2d.align` against Open3D's
``registration_icp`` (point-to-plane and point-to-point) on the local relations of the Intel and ACES laser
logs, same pairs, same odometry seeds, same 0.5 m correspondence distance, one run.

What the step adds around the core (covariance, free-space test, reliability verdict, ``Estimate``) is not
timed here; ``benchmarks/bench_icp.py`` times the whole step against the same peer.

Each pair is timed ``--repeats`` times in turn for every method and its fastest time is kept (the machine is
shared: the minimum is the figure least disturbed by other processes); the table gives the median and the
mean over pairs, and the errors against the published relations.

Usage::

    .venv/bin/python benchmarks/bench_align.py                  # every 10th relation of both logs
    .venv/bin/python benchmarks/bench_align.py --every 3 --repeats 5
"""

from __future__ import annotations

import argparse
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from factorloc.datasets.rosbag import read_laser_log
from factorloc.estimators.icp import IcpConfig
from factorloc.evaluation.relations import read_relations
from factorloc.geometry import Pose2
from factorloc.registration.icp2d import align, prepare_target
from factorloc.registration.kernels import kernel_from_name
from factorloc.registration.open3d_peer import open3d_icp

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "laser"
GATE_M = 0.5  # the correspondence distance of every method (Open3D's in the relations benchmark)


def _pairs(name: str, data: Path, every: int) -> list[tuple[np.ndarray, np.ndarray, Pose2, Pose2]]:
    log = read_laser_log(data / f"{name}.sort.bag")
    rel = read_relations(data / f"{name}.relations").subset(every)
    out = []
    for i in range(len(rel)):
        t1, t2 = float(rel.t1_s[i]), float(rel.t2_s[i])
        if log.odometry.distance_between(t1, t2)[0] < 5.0:
            ref, qry = log.scans.at(t1, 2e-3).points_m, log.scans.at(t2, 2e-3).points_m
            out.append((ref, qry, log.odometry.between(t1, t2), Pose2.from_array(rel.poses[i])))
    return out


def run(name: str, data: Path, every: int, repeats: int) -> None:
    cfg = IcpConfig()
    params = replace(cfg.icp, max_correspondence_m=GATE_M)
    kernel = kernel_from_name(cfg.kernel, cfg.kernel_scale_m)
    pairs = _pairs(name, data, every)

    def ours(ref, qry, seed):
        return align(prepare_target(ref, params), qry, seed, params, kernel).T_target_source

    def ours_align(ref, qry, seed, target):
        return align(target, qry, seed, params, kernel).T_target_source

    def o3d_plane_icp(ref, qry, seed, normals):
        res = open3d_icp(ref, qry, seed, method="point_to_plane", target_normals=normals, max_correspondence_m=GATE_M)
        return res.T_target_source

    def o3d_plane(ref, qry, seed):
        return o3d_plane_icp(ref, qry, seed, prepare_target(ref, params).normals)

    def o3d_point(ref, qry, seed):
        return open3d_icp(ref, qry, seed, method="point_to_point", max_correspondence_m=GATE_M).T_target_source

    methods = {
        "ours (prepare_target + align)": lambda p: ours(*p[:3]),
        "ours align only": lambda p: ours_align(*p[:3], p[4]),
        "open3d p2plane (normals + icp)": lambda p: o3d_plane(*p[:3]),
        "open3d p2plane icp only": lambda p: o3d_plane_icp(*p[:3], p[4].normals),
        "open3d p2p": lambda p: o3d_point(*p[:3]),
    }
    seconds = {m: np.full(len(pairs), np.inf) for m in methods}
    errors = {m: np.zeros((len(pairs), 2)) for m in methods}
    for k, (ref, qry, seed, truth) in enumerate(pairs):
        p = (ref, qry, seed, truth, prepare_target(ref, params))
        for _ in range(repeats):
            for m, f in methods.items():
                t0 = time.perf_counter()
                est = f(p)
                seconds[m][k] = min(seconds[m][k], time.perf_counter() - t0)
                e = truth.between(est)
                errors[m][k] = (math.hypot(e.x, e.y), abs(math.degrees(e.theta)))
    print(f"{name}: {len(pairs)} local relations (every {every}th relation), fastest of {repeats} runs per pair")
    print(f"  {'method':32s} {'ms median':>9s} {'ms mean':>8s} {'trans cm':>9s} {'rot deg':>8s}")
    for m in methods:
        s, e = seconds[m] * 1e3, errors[m]
        print(f"  {m:32s} {np.median(s):9.3f} {s.mean():8.3f} {100 * e[:, 0].mean():9.2f} {e[:, 1].mean():8.3f}")
    ratio = seconds["open3d p2plane (normals + icp)"] / seconds["ours (prepare_target + align)"]
    core = seconds["open3d p2plane icp only"] / seconds["ours align only"]
    print(
        f"  time open3d_p2plane/ours per pair: with the target preparation {np.median(ratio):.2f} (median of the "
        f"per-pair ratios), ICP calls alone {np.median(core):.2f}; translation error ours/open3d_p2plane "
        f"{errors['ours align only'][:, 0].mean() / errors['open3d p2plane icp only'][:, 0].mean():.2f}\n"
    )


def _first_call_seconds() -> float:
    """Seconds of the process's first prepare_target + align: numba's cache load (or its compilation, ~6 s, on a
    fresh checkout); every timed call below runs the compiled core."""
    pts = np.column_stack([np.linspace(0.0, 3.0, 30), np.r_[np.zeros(15), np.ones(15)]])
    t0 = time.perf_counter()
    align(prepare_target(pts), pts, Pose2())
    return time.perf_counter() - t0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--every", type=int, default=10, help="use every k-th relation (fixed subset)")
    ap.add_argument("--repeats", type=int, default=3, help="timed runs per pair and method (the fastest is kept)")
    ap.add_argument("--datasets", default="intel,aces")
    ap.add_argument("--data", type=Path, default=DATA)
    args = ap.parse_args()
    print(f"first prepare_target + align of the process (compiled core loaded or compiled): {_first_call_seconds():.3f} s")
    for name in [d for d in args.datasets.split(",") if d]:
        run(name, args.data, args.every, args.repeats)


if __name__ == "__main__":
    main()

"""What limits the loop closures: the global search or its verdict. Replays the ICP step's seedless global
initialization on every loop relation of the real laser logs and prints, per log: the share the step recovers
(within 10 cm and 1°, reliable), the share a perfect verdict would (the best refined candidate right), the share
any refined candidate is right, and the held-out figures of a verdict read from the likelihood's shape alone,
fitted leave-one-log-out (see ``docs/calibration/icp.md``).

Usage::

    .venv/bin/python benchmarks/bench_icp_loops.py            # Intel, ACES, MIT CSAIL loops (~3 min)
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from factorloc.datasets.rosbag import read_laser_log
from factorloc.estimators.icp import IcpReference, estimate
from factorloc.estimators.icp.candidates import QueryScan, _distinct, _search_window
from factorloc.estimators.icp.covariance import constraint_strength, covariance, largest_sigma_position
from factorloc.evaluation.folds import LOGS
from factorloc.evaluation.relations import read_relations, relations_config
from factorloc.geometry import Pose2

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "laser"


def loops(name: str, data: Path) -> list[dict]:
    """Per loop relation: the step's own verdict and the refined candidates of its (seedless) global search."""
    cfg = relations_config().icp
    log = read_laser_log(data / f"{name}.sort.bag")
    rel = read_relations(data / f"{name}.relations")
    out = []
    for i in range(len(rel)):
        t1, t2 = float(rel.t1_s[i]), float(rel.t2_s[i])
        if log.odometry.distance_between(t1, t2)[0] < 5.0:
            continue
        truth = Pose2.from_array(rel.poses[i])
        prep = IcpReference(log.scans.at(t1, 2e-3).points_m, Pose2(), cfg)
        pts = np.asarray(log.scans.at(t2, 2e-3).points_m, dtype=np.float64)
        est = estimate(prep, pts, config=cfg)
        e = truth.between(Pose2.from_array(est.values))
        step_ok = est.reliable and math.hypot(e.x, e.y) < 0.1 and abs(math.degrees(e.theta)) < 1.0
        q = QueryScan(pts, cfg)
        found, _ = _search_window(prep, q, cfg, (0.0, 0.0), 0.0, math.pi, cfg.global_init.search.radius_m)
        cands = []
        for f in found:
            r = f.result
            d = truth.between(r.T_target_source)
            cov = covariance(r, cfg)
            cands.append(
                dict(
                    T=r.T_target_source,
                    score=f.score,
                    v=f.violation,
                    rmse=r.rmse_m,
                    sig=largest_sigma_position(cov),
                    sth=math.sqrt(cov[2, 2]),
                    strength=constraint_strength(r),
                    ov=q.overlap(prep, r.T_target_source, cfg)[0],
                    ovn=q.overlap(prep, r.T_target_source, cfg)[1],
                    right=math.hypot(d.x, d.y) < 0.1 and abs(math.degrees(d.theta)) < 1.0,
                    far=math.hypot(d.x, d.y) > 0.15 or abs(math.degrees(d.theta)) > 2.5,
                )
            )
        rivals = [c for c in cands[1:] if _distinct(c["T"], cands[0]["T"], cfg)] if cands else []
        out.append(dict(step_ok=step_ok, cands=cands, rivals=rivals))
    return out


def _shape_verdict(params: tuple, best: dict, rivals: list[dict]) -> bool:
    """Accept when the overlap fitness reaches f, the shared view holds n points and the best distinct rival scores
    below r × the best (or, in "points" mode, the best explains K more points per 180 than it)."""
    mode, k, f_min, n_min = params
    if best["v"] > 0.12 or not best["rmse"] <= 0.05 or best["sig"] > 0.25 or best["sth"] > math.radians(5.0):
        return False
    if best["ov"] < f_min or best["ovn"] < n_min:
        return False
    rival = max((c["score"] for c in rivals), default=0.0)
    return rival < k * best["score"] if mode == "ratio" else 180.0 * (best["score"] - rival) >= k


def _count(rows: list[dict], params: tuple) -> tuple[int, int]:
    rec = far = 0
    for r in rows:
        if r["cands"] and _shape_verdict(params, r["cands"][0], r["rivals"]):
            rec += r["cands"][0]["right"]
            far += r["cands"][0]["far"]
    return rec, far


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("logs", nargs="*", default=list(LOGS))
    ap.add_argument("--data", type=Path, default=DATA)
    args = ap.parse_args()
    data = {n: loops(n, args.data) for n in args.logs}
    for n, rows in data.items():
        m = len(rows)
        print(
            f"{n:10s} loops {m:5d}: the step {sum(r['step_ok'] for r in rows) / m:6.1%}, a perfect verdict "
            f"{sum(bool(r['cands']) and r['cands'][0]['right'] for r in rows) / m:6.1%}, any candidate "
            f"{sum(any(c['right'] for c in r['cands']) for r in rows) / m:6.1%}"
        )
    grid = [("ratio", k, f, nn) for k in (0.6, 0.7, 0.8, 0.9) for f in (0.8, 0.85, 0.9, 0.95) for nn in (20, 40, 60)]
    grid += [("points", k, f, nn) for k in (3, 5, 8, 12) for f in (0.8, 0.85, 0.9, 0.95) for nn in (20, 40, 60)]
    for held in data:
        train = [n for n in data if n != held]

        def objective(p: tuple, train: list[str] = train) -> float:
            return sum((lambda rf: rf[0] - 10 * rf[1])(_count(data[n], p)) / len(data[n]) for n in train)

        best = max(grid, key=objective)
        rec, far = _count(data[held], best)
        step = sum(r["step_ok"] for r in data[held])
        print(
            f"shape verdict fitted without {held}: {best}; on {held}: recovered {rec}, far off and reliable {far}"
            f" (the step recovers {step})"
        )


if __name__ == "__main__":
    main()

"""Tracking through the simulated apartment's places: position/heading RMSE, confidently wrong, flagged, recovery
after kidnappings, latency — on held-out seeds (the tracker's settings were developed on seed 100 only).

A place every metre of a grid over the apartment's free space (360° laser scans, the simulator's real-lidar error
model), a robot driving through it with a scan every 25 cm of travel and one continuous drifting odometry run;
``--kidnaps`` times it is carried to a random free pose.

``--mcl`` also runs the Monte Carlo baseline (:class:`factorloc.baselines.mcl.MonteCarloLocalization`, 2000
particles, random particles over the apartment) on the same queries with the same evidence-gathering policy as the
tracker: each query, the hierarchy against the places in view of its belief (seeded by it); when its belief is
undetermined or two queries went without a reliable estimate, against the top-5 recognized places (seeded there,
heading from Scan Context). MCL's figures count every determined result (it has no flag); CPU time is
``time.process_time`` per query, hierarchy runs included, for both.

Usage::

    nice -n 10 .venv/bin/python benchmarks/bench_track.py                       # seeds 1..3, 200 queries, 3 kidnaps
    nice -n 10 .venv/bin/python benchmarks/bench_track.py --seeds 1 2 3 4 5 --queries 120
    nice -n 10 .venv/bin/python benchmarks/bench_track.py --seeds 1 --mcl       # beside Monte Carlo
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from factorloc.evaluation.places import choice_recall, simulated_place_map, simulated_track, track_figures
from factorloc.places import Tracker, TrackerConfig


def main() -> None:
    from factorloc.sim import apartment

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[1, 2, 3])
    ap.add_argument("--queries", type=int, default=200)
    ap.add_argument("--kidnaps", type=int, default=3)
    ap.add_argument("--mcl", action="store_true", help="also the Monte Carlo baseline on the same queries")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    world = apartment()
    place_map = simulated_place_map(world, 1.0, seed=0)
    rows = []
    head = f"{'seed':>4} {'n':>4} {'RMSE cm':>8} {'RMSE deg':>8} {'all cm':>7} {'wrong':>6} {'flagged':>7}"
    head += f" {'kid':>4} {'rec3':>4} {'med ms':>7} {'choice':>7}"
    print(head)
    for seed in args.seeds:
        t0 = time.perf_counter()
        sc = simulated_track(world, place_map, args.queries, 1000 + seed, kidnaps=args.kidnaps)
        tracker = Tracker(place_map, TrackerConfig())
        c0 = time.process_time()
        results = [tracker.update(q.query) for q in sc.queries]
        cpu = (time.process_time() - c0) / len(sc.queries)
        f = track_figures(sc, results)
        n_choice, choice = choice_recall(sc, results, place_map)
        rows.append(
            {"seed": 1000 + seed, **f.to_dict(), "choice_queries": n_choice, "choice_recall": choice, "cpu_s_per_query": cpu}
            | {"seconds": time.perf_counter() - t0}
        )
        print(
            f"{1000 + seed:>4} {f.queries:>4} {100 * f.rmse_position_m:>8.2f} {f.rmse_heading_deg:>8.2f} "
            f"{100 * f.rmse_position_all_m:>7.1f} {100 * f.confidently_wrong:>5.1f}% {100 * f.flagged:>6.1f}% "
            f"{f.kidnaps:>4} {f.recovered_within_3:>4} {1000 * f.median_seconds:>7.1f} {100 * choice:>6.1f}%",
            flush=True,
        )
        if args.mcl:
            m = run_mcl(world, place_map, sc, tracker)
            rows[-1]["mcl"] = m
            print(
                f"     MCL: RMSE {100 * m['rmse_position_m']:.2f} cm {m['rmse_heading_deg']:.2f} deg, "
                f"recovered within 3: {m['recovered_within_3']}/{m['kidnaps']}, "
                f"CPU {1000 * m['cpu_s_per_query']:.1f} ms/query vs tracker {1000 * cpu:.1f} ms/query",
                flush=True,
            )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


def run_mcl(world, place_map, scenario, tracker) -> dict:  # noqa: ANN001 - the benchmark's own objects
    """The Monte Carlo baseline on the same queries (see the module docstring); its figures."""
    import math
    from dataclasses import replace

    import numpy as np

    from factorloc.baselines.mcl import MonteCarloLocalization
    from factorloc.places import places_in_view
    from factorloc.places.tracker import _seed
    from factorloc.types import Odometry

    mcl = MonteCarloLocalization(2000, bounds_xy=world.bounds_xy, seed=0)
    multi, recognizer, cfg = tracker.multi, tracker.recognizer, tracker.config
    sq_pos, sq_th, good, starved, cpu = [], [], [], 2, 0.0
    belief = None
    for q in scenario.queries:
        c0 = time.process_time()
        reports = []
        if belief is not None and starved < 2:
            ids = [pid for pid, _ in places_in_view(place_map, belief.pose, belief.covariance, cfg.choice)]
            if ids:
                seeded = replace(q.query, odometry=_seed(belief.pose, belief.covariance))
                reports = list(multi.localize(seeded, ids, use_odometry=False).localization.steps)
        if not any(r.estimate is not None and r.estimate.reliable for r in reports):
            for c in recognizer.candidates(q.query, cfg.relocalize_k):
                p = place_map[c.place_id]
                T = p.T_world_reference.compose(type(p.T_world_reference)(0.0, 0.0, c.theta_place_query_rad or 0.0))
                odo = Odometry(T, cfg.relocalize_sigma_m, cfg.relocalize_sigma_m, cfg.relocalize_sigma_rad)
                run = multi.run_place(replace(q.query, odometry=odo), c.place_id)
                reports.extend(run.localization.steps[1:])  # the place's steps, not its (made-up) odometry seed
        belief = mcl.update(q.query, reports)
        cpu += time.process_time() - c0
        starved = 0 if any(r.estimate is not None and r.estimate.reliable for r in reports) else starved + 1
        if belief.undetermined:
            belief = None
            good.append(False)
            continue
        e = np.array([belief.pose.x - q.truth.x, belief.pose.y - q.truth.y])
        eth = abs(math.remainder(belief.pose.theta - q.truth.theta, 2 * math.pi))
        sq_pos.append(float(e @ e))
        sq_th.append(eth * eth)
        good.append(bool(math.hypot(*e) < 0.1 and eth < math.radians(1.0)))
    kid = [i for i, q in enumerate(scenario.queries) if "kidnapped" in q.faults]
    return {
        "rmse_position_m": math.sqrt(np.mean(sq_pos)),
        "rmse_heading_deg": math.degrees(math.sqrt(np.mean(sq_th))),
        "kidnaps": len(kid),
        "recovered_within_3": sum(any(good[j] for j in range(i, min(i + 3, len(good)))) for i in kid),
        "cpu_s_per_query": cpu / len(scenario.queries),
    }


if __name__ == "__main__":
    main()

"""Tracking through the simulated apartment's places: position/heading RMSE, confidently wrong, flagged, recovery
after kidnappings, latency — on held-out seeds (the tracker's settings were developed on seed 100 only).

A place every metre of a grid over the apartment's free space (360° laser scans, the simulator's real-lidar error
model), a robot driving through it with a scan every 25 cm of travel and one continuous drifting odometry run;
``--kidnaps`` times it is carried to a random free pose. Optionally (``--mcl``) the Monte Carlo baseline on the
same queries is not run here: it needs the camera and panorama steps' inputs; see ``docs/places.md``.

Usage::

    nice -n 10 .venv/bin/python benchmarks/bench_track.py                       # seeds 1..3, 200 queries, 3 kidnaps
    nice -n 10 .venv/bin/python benchmarks/bench_track.py --seeds 1 2 3 4 5 --queries 120
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from factorloc.evaluation.places import simulated_place_map, simulated_track, track_figures
from factorloc.places import Tracker, TrackerConfig


def main() -> None:
    from factorloc.sim import apartment

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[1, 2, 3])
    ap.add_argument("--queries", type=int, default=200)
    ap.add_argument("--kidnaps", type=int, default=3)
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    world = apartment()
    place_map = simulated_place_map(world, 1.0, seed=0)
    rows = []
    head = f"{'seed':>4} {'n':>4} {'RMSE cm':>8} {'RMSE deg':>8} {'all cm':>7} {'wrong':>6} {'flagged':>7}"
    head += f" {'kid':>4} {'rec3':>4} {'med ms':>7}"
    print(head)
    for seed in args.seeds:
        t0 = time.perf_counter()
        sc = simulated_track(world, place_map, args.queries, 1000 + seed, kidnaps=args.kidnaps)
        tracker = Tracker(place_map, TrackerConfig())
        results = [tracker.update(q.query) for q in sc.queries]
        f = track_figures(sc, results)
        rows.append({"seed": 1000 + seed, **f.to_dict(), "seconds": time.perf_counter() - t0})
        print(
            f"{1000 + seed:>4} {f.queries:>4} {100 * f.rmse_position_m:>8.2f} {f.rmse_heading_deg:>8.2f} "
            f"{100 * f.rmse_position_all_m:>7.1f} {100 * f.confidently_wrong:>5.1f}% {100 * f.flagged:>6.1f}% "
            f"{f.kidnaps:>4} {f.recovered_within_3:>4} {1000 * f.median_seconds:>7.1f}",
            flush=True,
        )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()

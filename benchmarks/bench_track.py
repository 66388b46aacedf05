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

``recog`` is how many times the tracker ran place recognition (the start-up and each re-localization attempt);
``--recognize-after 2`` gives the rule before recognition on the first query without support (``recognize_after``);
``--track-set NAME=VALUE`` (repeatable) overrides any other :class:`~factorloc.places.TrackerConfig` field, as in
``bench_map.py`` (e.g. ``--track-set confirm_recognition=False``).

``--tour`` uses the multi-place worlds instead (:mod:`factorloc.sim.track`): places in every room of ``--world``
(``apartment`` or ``office``, a grid of ``--place-spacing`` m in each room) and a robot touring the rooms through the
doors (:func:`factorloc.sim.track.generate_track`, occlusion on 10 % of the queries, kidnappings to another room).

Usage::

    nice -n 10 .venv/bin/python benchmarks/bench_track.py                       # seeds 1..3, 200 queries, 3 kidnaps
    nice -n 10 .venv/bin/python benchmarks/bench_track.py --seeds 1 2 3 4 5 --queries 120
    nice -n 10 .venv/bin/python benchmarks/bench_track.py --seeds 1 --mcl       # beside Monte Carlo
    nice -n 10 .venv/bin/python benchmarks/bench_track.py --tour --world office --seeds 1 2 3 --mcl
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

from factorloc.evaluation.places import (
    choice_recall,
    mcl_track,
    recognition_events,
    simulated_place_map,
    simulated_track,
    track_figures,
)
from factorloc.places import Tracker, TrackerConfig


def _scenario(args: argparse.Namespace, world, place_map, seed: int):  # noqa: ANN001, ANN202 - the benchmark's own objects
    if not args.tour:
        return simulated_track(world, place_map, args.queries, seed, kidnaps=args.kidnaps)
    from factorloc.sim.track import generate_track

    return generate_track(world, place_map, args.queries, seed, kidnaps=args.kidnaps)


def main() -> None:
    from factorloc.sim import world_by_name

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="*", default=[1, 2, 3])
    ap.add_argument("--queries", type=int, default=200)
    ap.add_argument("--kidnaps", type=int, default=3)
    ap.add_argument("--mcl", action="store_true", help="also the Monte Carlo baseline on the same queries")
    ap.add_argument("--particles", type=int, default=2000, help="the Monte Carlo baseline's particles")
    ap.add_argument("--tour", action="store_true", help="places in every room and a tour of the rooms (factorloc.sim.track)")
    ap.add_argument("--world", default="apartment", help="with --tour: apartment or office (or a world file)")
    ap.add_argument("--place-spacing", type=float, default=1.5, help="with --tour: grid spacing of the places in a room (m)")
    ap.add_argument(
        "--cover",
        type=float,
        default=None,
        help="without --tour: add places to the 1 m grid until every free pose is this near one (m)",
    )
    ap.add_argument(
        "--recognize-after",
        type=int,
        default=TrackerConfig().recognize_after,
        help="TrackerConfig.recognize_after (default 1; 2 = kidnap_after: recognition only when the kidnap rule fires)",
    )
    ap.add_argument("--track-set", action="append", default=[], metavar="NAME=VALUE", help="override a TrackerConfig field")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    from bench_map import config_from_overrides

    tracker_config = replace(config_from_overrides(args.track_set, TrackerConfig), recognize_after=args.recognize_after)
    print(f"tracker settings: recognize_after={args.recognize_after} {' '.join(args.track_set)}")
    world = world_by_name(args.world if args.tour else "apartment")
    if args.tour:
        from factorloc.sim.track import room_places

        place_map = room_places(world, args.place_spacing, seed=0)
    else:
        place_map = simulated_place_map(world, 1.0, seed=0, cover_m=args.cover)
    print(f"{world.name}: {len(place_map)} places ({'rooms' if args.tour else 'grid'})")
    rows = []
    head = f"{'seed':>4} {'n':>4} {'RMSE cm':>8} {'RMSE deg':>8} {'all cm':>7} {'wrong':>6} {'flagged':>7}"
    head += f" {'kid':>4} {'rec3':>4} {'med ms':>7} {'choice':>7} {'recog':>5}"
    print(head)
    for seed in args.seeds:
        t0 = time.perf_counter()
        sc = _scenario(args, world, place_map, 1000 + seed)
        tracker = Tracker(place_map, tracker_config)
        c0 = time.process_time()
        results = [tracker.update(q.query) for q in sc.queries]
        cpu = (time.process_time() - c0) / len(sc.queries)
        f = track_figures(sc, results)
        n_choice, choice = choice_recall(sc, results, place_map)
        rows.append(
            {"seed": 1000 + seed, **f.to_dict(), "choice_queries": n_choice, "choice_recall": choice, "cpu_s_per_query": cpu}
            | {"recognitions": tracker.recognitions, "events": recognition_events(results).to_dict()}
            | {"seconds": time.perf_counter() - t0}
        )
        print(
            f"{1000 + seed:>4} {f.queries:>4} {100 * f.rmse_position_m:>8.2f} {f.rmse_heading_deg:>8.2f} "
            f"{100 * f.rmse_position_all_m:>7.1f} {100 * f.confidently_wrong:>5.1f}% {100 * f.flagged:>6.1f}% "
            f"{f.kidnaps:>4} {f.recovered_within_3:>4} {1000 * f.median_seconds:>7.1f} {100 * choice:>6.1f}% "
            f"{tracker.recognitions:>5}",
            flush=True,
        )
        print(f"     recognition events: {rows[-1]['events']}", flush=True)
        if args.mcl:
            m = mcl_track(sc, place_map, world.bounds_xy, particles=args.particles, tracker=tracker).to_dict()
            rows[-1]["mcl"] = m
            print(
                f"     MCL: RMSE {100 * m['rmse_position_m']:.2f} cm {m['rmse_heading_deg']:.2f} deg, "
                f"recovered within 3: {m['recovered_within_3']}/{m['kidnaps']}, "
                f"CPU {1000 * m['cpu_s_per_query']:.1f} ms/query vs tracker {1000 * cpu:.1f} ms/query",
                flush=True,
            )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))


if __name__ == "__main__":
    main()

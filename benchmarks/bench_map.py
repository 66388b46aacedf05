"""Benchmark of the mapping (:func:`factorloc.mapping.build_map`) on a real laser log: the relations metric of
Kümmerle et al. (2009) on the map's trajectory of every scan, beside the odometry alone and the published
graph-mapping figures, with the share of relations beyond 3σ of the map's own covariance of that relation,
and the wall time of the mapping.

Usage::

    .venv/bin/python benchmarks/bench_map.py --log intel              # the whole Intel log
    taskset -c 0 .venv/bin/python benchmarks/bench_map.py --log intel # on one core (the ≤ 90 s target)
    .venv/bin/python benchmarks/bench_map.py --log aces --max-scans 2000 --set loop_every=2
    .venv/bin/python benchmarks/bench_map.py --log mit --pairwise     # + today's pairwise "ours" (minutes)
    .venv/bin/python benchmarks/bench_map.py --log intel --track-every 10  # localizing in the map (issue 19.3)
    .venv/bin/python benchmarks/bench_map.py --log aces --track-every 10 --place-covariance local
    .venv/bin/python benchmarks/bench_map.py --log aces --track-every 10 --track-set recognize_after=1
    .venv/bin/python benchmarks/bench_map.py --log aces --track-every 10 --kidnap 40 --place-covariance marginal

``--track-every K`` holds back every K-th scan, maps the rest, tracks the held-back scans through that map with
the :class:`~factorloc.places.Tracker` (:mod:`factorloc.evaluation.map_tracking`) and reports the relations metric
over the relations with a held-back end, the share flagged / lost, the agreement with the map of all scans and the
share of unflagged results beyond 3σ of the tracker's covariance, and the tracking latency.

``--kidnap N`` (with ``--track-every K``) instead starts a tracker with no pose at ``N`` runs of
``--kidnap-length`` consecutive held-back scans spread over the log (:func:`~factorloc.evaluation.map_tracking.kidnapped_starts`):
how often it re-localizes right within 3 scans, vouches for a wrong pose first, never commits, and the share of its
vouched-for results that are wrong (> 1 m or 10° from the scan's pose in the map of the rest).

``--set name=value`` overrides a :class:`~factorloc.mapping.MapConfig` field (numbers, booleans, strings); a
dotted name reaches into a nested config, e.g. ``--set icp.reliability.min_heading_strength=0.001``.
``--track-set name=value`` does the same for the :class:`~factorloc.places.TrackerConfig` of ``--track-every``,
e.g. ``--track-set recognize_after=1`` or ``--track-set recognition.n_candidates=20``.
"""

from __future__ import annotations

import argparse
import ast
import json
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from factorloc.datasets.rosbag import LaserLog, ScanTrack, read_laser_log
from factorloc.evaluation.map_relations import map_relations
from factorloc.evaluation.relations import Relations, format_table, read_relations, relations_benchmark, summarize
from factorloc.evaluation.relations_consistency import relations_consistency
from factorloc.evaluation.relations_lattice import GRID_STEPS_M, SQUARE_MEAN_DISTANCE, find_heading_grid, find_relations_grid
from factorloc.geometry import Pose2
from factorloc.mapping import MapConfig, build_map

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "laser"
NAMES = {"intel": "intel", "aces": "aces", "mit": "mit-csail", "mit-csail": "mit-csail"}
#: Best graph mapping on all relations, Kümmerle et al. (2009) metric, as quoted by Hess et al. (ICRA 2016) beside
#: Cartographer's: (translation mean, std in cm; rotation mean, std in deg; None where not quoted).
PUBLISHED = {
    "intel": (3.1, 2.6, 1.3, 4.7),
    "aces": (4.4, 4.4, 0.4, 0.4),
    "mit-csail": (0.4, 0.9, None, None),
}


def _prefix(log: LaserLog, rel: Relations, max_scans: int | None) -> tuple[LaserLog, Relations]:
    """The first ``max_scans`` scans and the relations inside them."""
    if max_scans is None or max_scans >= len(log.scans):
        return log, rel
    scans = ScanTrack(log.scans.stamps_s[:max_scans], log.scans.scans[:max_scans])
    t_end = float(scans.stamps_s[-1])
    keep = (rel.t1_s <= t_end) & (rel.t2_s <= t_end)
    return LaserLog(log.odometry, scans, log.source), Relations(rel.t1_s[keep], rel.t2_s[keep], rel.poses[keep])


def _overrides(items: list[str]) -> dict:
    out = {}
    for item in items:
        k, _, v = item.partition("=")
        if v.lower() in ("true", "false"):  # the shell's spelling of a boolean: never the (truthy) string "false"
            out[k] = v.lower() == "true"
            continue
        try:
            out[k] = ast.literal_eval(v)
        except (ValueError, SyntaxError):
            out[k] = v
    return out


def _with(obj: object, dotted: str, value: object) -> object:
    """``obj`` (a frozen dataclass) with the field ``dotted`` (``"a.b.c"``) replaced."""
    head, _, rest = dotted.partition(".")
    return replace(obj, **{head: _with(getattr(obj, head), rest, value) if rest else value})


def config_from_overrides(items: list[str], kind: type = MapConfig) -> object:
    """The ``kind`` config (MapConfig, TrackerConfig) of ``--set`` / ``--track-set`` overrides (plain and dotted
    names)."""
    pairs = _overrides(items)
    config = kind(**{k: v for k, v in pairs.items() if "." not in k})
    for k, v in pairs.items():
        if "." in k:
            config = _with(config, k, v)
    return config


def _print_grid(result, rel, log, lattice, rows) -> None:  # noqa: ANN001
    """The map on the relations on the grid, and where it lies between the odometry and the relation."""
    on = np.flatnonzero(lattice.on_lattice)
    print(
        f"map on the {len(on)} relations on the grid: {100 * np.mean([rows[i].error_translation_m for i in on]):.2f} cm "
        f"(the grid's own floor on them: {100 * SQUARE_MEAN_DISTANCE * lattice.step_m:.2f} cm)"
    )
    stamps = result.scan_stamps_s

    def scan_pose(t: float) -> Pose2:
        return Pose2.from_array(result.scan_poses[int(np.argmin(np.abs(stamps - t)))])

    for steps in (0.0, 1.0, math.sqrt(2.0)):
        sel = [i for i in on if abs(lattice.residual_norms_m[i] - steps * lattice.step_m) < lattice.tolerance_m]
        to_odo, to_rel = [], []
        for i in sel:
            t1, t2 = float(rel.t1_s[i]), float(rel.t2_s[i])
            M, D = scan_pose(t1).between(scan_pose(t2)), log.odometry.between(t1, t2)
            to_odo.append(math.hypot(M.x - D.x, M.y - D.y))
            to_rel.append(math.hypot(M.x - rel.poses[i][0], M.y - rel.poses[i][1]))
        if sel:
            print(
                f"  relation = odometry + {100 * steps * lattice.step_m:.2f} cm ({len(sel)}): the map is "
                f"{100 * np.mean(to_odo):.2f} cm from the odometry, {100 * np.mean(to_rel):.2f} cm from the relation"
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--log", required=True, choices=sorted(NAMES))
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--max-scans", type=int, default=None, help="map only the first N scans (and their relations)")
    ap.add_argument("--set", action="append", default=[], metavar="NAME=VALUE", help="override a MapConfig field")
    ap.add_argument(
        "--track-set",
        action="append",
        default=[],
        metavar="NAME=VALUE",
        help="with --track-every: override a TrackerConfig field (dotted names reach nested configs)",
    )
    ap.add_argument("--pairwise", action="store_true", help="also run today's pairwise 'ours' on every relation")
    ap.add_argument("--track-every", type=int, default=None, metavar="K", help="hold back every K-th scan and track it")
    ap.add_argument("--kidnap", type=int, default=None, metavar="N", help="with --track-every: N kidnapped starts")
    ap.add_argument("--kidnap-length", type=int, default=8, metavar="L", help="scans per kidnapped start (default 8)")
    ap.add_argument(
        "--place-covariance",
        choices=("local", "marginal", "none", "all"),
        default="all",
        help="with --track-every: the places carry their covariance relative to their neighbours (local), the map's "
        "marginal, none (poses taken as exact), or all three runs",
    )
    ap.add_argument("--json", type=Path, default=None, help="write the summary rows and stats as JSON")
    args = ap.parse_args()
    name = NAMES[args.log]
    log = read_laser_log(args.data / f"{name}.sort.bag")
    rel = read_relations(args.data / f"{name}.relations")
    log, rel = _prefix(log, rel, args.max_scans)
    config = config_from_overrides(args.set)
    if args.track_every is not None:
        variants = ["local", "marginal", "none"] if args.place_covariance == "all" else [args.place_covariance]
        from factorloc.places import TrackerConfig

        tracker_config = config_from_overrides(args.track_set, TrackerConfig)
        print(f"tracker settings: {', '.join(args.track_set) or 'defaults'}")
        if args.kidnap is not None:
            _kidnap(log, config, tracker_config, args.track_every, args.kidnap, args.kidnap_length, args.json, variants)
            return
        _track(log, rel, config, tracker_config, args.track_every, name, args.json, variants)
        return
    t0, c0 = time.perf_counter(), time.process_time()
    result = build_map(log, config)
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    rows = map_relations(result, rel, log)
    methods = ["odometry"] + (["ours"] if args.pairwise else [])
    base = relations_benchmark(log, rel, methods=methods)
    table = summarize(base + rows, name)
    print(format_table(table))
    pub = PUBLISHED[name]
    rot = "" if pub[2] is None else f" / {pub[2]} ± {pub[3]} deg"
    print(f"\npublished best graph mapping ({name}, all relations): {pub[0]} ± {pub[1]} cm{rot}")
    m = next(r for r in table if r["method"] == "map" and r["subset"] == "all")
    print(
        f"map ({name}, all {m['n']} relations): {m['trans_mean_cm']:.2f} ± {m['trans_std_cm']:.2f} cm / "
        f"{m['rot_mean_deg']:.2f} ± {m['rot_std_deg']:.2f} deg; beyond 3σ of the map's covariance: "
        f"{100 * m['confidently_wrong_rate']:.2f} % (the relations taken as exact: "
        f"{100 * np.mean([r.diagnostics['beyond_3sigma_exact'] for r in rows]):.2f} %)"
    )
    consistency = relations_consistency(rel)
    print(f"the relations' own consistency: {consistency.summary()}")
    if len(consistency.members):
        on_cycles = [rows[i] for i in consistency.members.tolist()]
        print(
            f"map on those {len(on_cycles)} relations: {100 * np.mean([r.error_translation_m for r in on_cycles]):.2f} cm / "
            f"{np.mean([r.error_rotation_deg for r in on_cycles]):.3f} deg"
        )
    lattice = find_relations_grid(rel, log.odometry)
    if lattice is None:
        print(
            "the relations against the odometry: no grid (no step of "
            f"{', '.join(f'{100 * s:g}' for s in GRID_STEPS_M)} cm puts half of them on it beyond chance)"
        )
    else:
        print(f"the relations against the odometry: {lattice.summary()}")
        _print_grid(result, rel, log, lattice, rows)
    heading = find_heading_grid(rel, log.odometry)
    if heading is None:
        print("the relations' headings against the odometry: no grid")
    else:
        print(
            f"the relations' headings against the odometry: {int(heading.on_lattice.sum())} of {len(rel)} turned by whole "
            f"{math.degrees(heading.step_rad):g}° steps about {math.degrees(heading.offset_rad):.3f}° "
            f"(chance {100 * heading.chance_rate:.1f} %)"
        )
    s = result.stats
    print(
        f"{s['places']} places of {len(log.scans)} scans, {s['scan_factors']} consecutive ICP links, "
        f"{s['closures_accepted']} closures accepted / {s['closures_reliable']} reliable / {s['closures_proposed']} "
        f"proposed ({s['closures_recognized']} added by recognition, {s['seconds_recognition']:.1f} s), "
        f"{s['scans_refined']} scans refined; wall time {wall:.1f} s, CPU time {cpu:.1f} s "
        f"(ICP {s['seconds_icp']:.1f}, iSAM2 {s['seconds_isam']:.1f}, batch {s['seconds_batch']:.1f}, "
        f"marginals {s['seconds_marginals']:.1f}, scans {s['seconds_scans']:.1f})"
    )
    if args.json is not None:
        d2 = np.array([r.nees_position for r in rows])
        args.json.write_text(
            json.dumps(
                {"rows": table, "stats": s, "wall_s": wall, "cpu_s": cpu, "mahalanobis2_median": float(np.median(d2))}, indent=1
            )
        )


def _track(
    log: LaserLog,
    rel: Relations,
    config: MapConfig,
    tracker_config: object,
    every: int,
    name: str,
    out: Path | None,
    variants: list[str],
) -> None:
    """Issue 19, item 3: the held-back scans tracked in the map of the rest (see the module docstring)."""
    from factorloc.evaluation.map_tracking import compare_with_map, track_in_map, track_relations
    from factorloc.evaluation.places import recognition_events

    t0 = time.perf_counter()
    full = build_map(log, config)
    full_s = time.perf_counter() - t0
    reduced = None
    summary = {}
    for variant in variants:
        track = track_in_map(log, every, config, tracker_config, place_covariance=variant, map_result=reduced)
        if reduced is None:
            reduced, map_s = track.map, track.map_seconds
        rows = track_relations(track, rel, log)
        same = {r.index for r in rows}  # the map of all scans on the same relations
        full_rows = [
            replace(r, method="map_all_scans") for r in map_relations(full, rel, log, covariance=False) if r.index in same
        ]
        table = summarize(rows + full_rows, name)
        print(f"\n== places with covariance: {variant}")
        print(format_table(table))
        cmp = compare_with_map(track, full)
        n = len(track.results)
        lat = 1000.0 * track.seconds
        print(
            f"{n} of {len(log.scans)} scans held back (every {every}th), tracked in the map of the other "
            f"{len(track.kept)} ({len(track.map)} places, mapped in {map_s:.1f} s); states {track.states()}; "
            f"flagged {100 * track.flagged.mean():.1f} %, lost {100 * track.lost.mean():.1f} %"
        )
        print(
            f"against the map of all scans ({full_s:.1f} s): position RMSE {cmp['position_rmse_cm']:.2f} cm "
            f"(median {cmp['position_median_cm']:.2f}, p95 {cmp['position_p95_cm']:.2f}), heading RMSE "
            f"{cmp['heading_rmse_deg']:.2f} deg; unflagged only: position RMSE {cmp['unflagged_position_rmse_cm']:.2f} cm, "
            f"heading RMSE {cmp['unflagged_heading_rmse_deg']:.2f} deg; beyond 3σ of the tracker's covariance: "
            f"{cmp['beyond_3sigma']} of {cmp['unflagged']} unflagged ({100 * cmp['beyond_3sigma_rate']:.2f} %); "
            f"tracker position σ median {cmp['sigma_position_median_cm']:.2f} cm; the two maps differ on the kept scans by "
            f"{cmp['maps_difference_rmse_cm']:.2f} cm RMSE"
        )
        print(f"tracking latency median {np.median(lat):.1f} ms (p95 {np.percentile(lat, 95):.1f}, max {lat.max():.1f})")
        events = recognition_events(track.results).to_dict()
        print(f"recognition events: {events}")
        summary[variant] = {"rows": table, "compare": cmp, "states": track.states(), "latency_ms_median": float(np.median(lat))}
        summary[variant]["recognition_events"] = events
    if out is not None:
        out.write_text(json.dumps(summary, indent=1))


def _kidnap(
    log: LaserLog,
    config: MapConfig,
    tracker_config: object,
    every: int,
    starts: int,
    length: int,
    out: Path | None,
    variants: list[str],
) -> None:
    """Kidnapped starts in the map of the rest (see the module docstring)."""
    from factorloc.evaluation.map_tracking import kidnap_figures, kidnapped_starts

    reduced, summary = None, {}
    for variant in variants:
        t0 = time.perf_counter()
        found = kidnapped_starts(log, every, starts, length, config, tracker_config, place_covariance=variant, map_result=reduced)
        reduced = found.map
        fig = kidnap_figures(found.runs)
        lat = 1000.0 * np.array([r.seconds for run in found.runs for r in run.results])
        print(
            f"\n== places with covariance: {variant} ({time.perf_counter() - t0:.1f} s): {int(fig['runs'])} starts of "
            f"{length} scans (every {every}th held back): right within 3 scans {100 * fig['right_within']:.1f} %, wrong "
            f"first commitment {100 * fig['wrong_commit']:.1f} %, never committed {100 * fig['never']:.1f} %; vouched-for "
            f"results wrong {100 * fig['unflagged_wrong_rate']:.2f} %; median scans to a right commitment "
            f"{fig['median_scans_to_commit']:g}; latency median {np.median(lat):.1f} ms (p95 {np.percentile(lat, 95):.1f})"
        )
        summary[variant] = fig
    if out is not None:
        out.write_text(json.dumps(summary, indent=1))


if __name__ == "__main__":
    main()

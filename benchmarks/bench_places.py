"""Place recognition on the real laser logs: recall@1 and recall@5 of Scan Context on every loop relation.

Protocol (issue #18; :mod:`factorloc.evaluation.places`): a place every metre along each log's odometry; for every
loop relation (t1, t2) the scan at t2 is the query, the places within 15 s of t2 are left out, a correct place is
built from the scan at t1 or a neighbour in time whose odometry lies within 1 m of t1's. No parameter is fitted
on the logs by default: the signature's defaults (:class:`~factorloc.places.RecognitionConfig`) are the same for all
three. ``--folds`` fits the one parameter that was chosen by looking at data, the D2 radius ``d2_max_range_m``, leave
one log out: for each log, the radius of the grid with the best mean recall@5 on the two others, reported on it.

Usage::

    nice -n 10 .venv/bin/python benchmarks/bench_places.py                 # all three logs, every loop relation
    nice -n 10 .venv/bin/python benchmarks/bench_places.py --every 10      # every 10th relation (quick)
    nice -n 10 .venv/bin/python benchmarks/bench_places.py --json out.json
    nice -n 10 .venv/bin/python benchmarks/bench_places.py --folds            # leave-one-log-out D2 radius
    nice -n 10 .venv/bin/python benchmarks/bench_places.py --sim              # the simulated apartment, seeds 201-203
    nice -n 10 .venv/bin/python benchmarks/bench_places.py --sim --cover 0.9  # its 1 m grid plus places covering it
    nice -n 10 .venv/bin/python benchmarks/bench_places.py --sim --modality both   # scan + 512 px panorama queries
    nice -n 10 .venv/bin/python benchmarks/bench_places.py --verify 0             # retrieval alone (no verified columns)
    nice -n 10 .venv/bin/python benchmarks/bench_places.py --verify-folds --every 10 1 1  # leave-one-log-out shortlist
    nice -n 10 .venv/bin/python benchmarks/bench_places.py --rank-by submap_match   # scan-to-submap matching
    nice -n 10 .venv/bin/python benchmarks/bench_places.py --submap-folds --every 5 1 1  # leave-one-log-out submap grid
    nice -n 10 .venv/bin/python benchmarks/bench_places.py --every 5 1 1 --truth   # is the verified first place right?

The main table gives the recall of retrieval and, beside it, after geometric verification
(:class:`~factorloc.places.PlaceVerifier`: the top ``--verify`` places, default
:data:`~factorloc.places.VERIFY_SHORTLIST`, each verified by the ICP step without a hypothesis, the verified first).
``--verify-folds`` fits that shortlist's length leave one log out over ``--shortlists``.

``--every`` takes one value for all logs or one per log (in ``--logs`` order). ``--submap-folds`` fits the submap
match's two parameters chosen by looking at data — the half-length of the places' local submaps
(``--half-paths``, m of odometry path) and the match's query range (``--match-ranges``, m) — leave one log out: for
each log, the grid point with the best mean recall@5 on the two others (ties: the smaller), reported on it; the
printed "worst held-out" line names the grid point whose worst held-out fold is best (the default's rule).

``--truth`` judges the first place of each verified ranking against the trajectory fitted to all of the log's
relations (:func:`~factorloc.evaluation.truth.log_truth`, places and queries posed within ``--truth-gap`` s of a
relation stamp): a second table with how many such places could be judged, the share whose estimate is more than
0.5 m or 5° off, the share off by more than 90° in heading, and the share beyond 3σ (``docs/places.md``).
"""

from __future__ import annotations

import argparse
import json
import time
from dataclasses import replace
from pathlib import Path

from factorloc.datasets.rosbag import read_laser_log
from factorloc.evaluation.folds import LOGS
from factorloc.evaluation.places import SUBMAP_AHEAD_M, SUBMAP_BEHIND_M, recognition_recall
from factorloc.evaluation.relations import read_relations
from factorloc.evaluation.truth import log_truth
from factorloc.places import VERIFY_SHORTLIST, RecognitionConfig

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "laser"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--logs", nargs="*", default=list(LOGS))
    ap.add_argument("--every", type=int, nargs="*", default=[1], help="every n-th relation (one value, or one per log)")
    ap.add_argument("--max-range", type=float, default=RecognitionConfig().max_range_m)
    ap.add_argument("--rings", type=int, default=RecognitionConfig().n_rings)
    ap.add_argument("--sectors", type=int, default=RecognitionConfig().n_sectors)
    ap.add_argument("--candidates", type=int, default=RecognitionConfig().n_candidates)
    ap.add_argument("--d2-range", type=float, default=RecognitionConfig().d2_max_range_m)
    ap.add_argument("--folds", action="store_true", help="fit the D2 radius leave-one-log-out over --grid")
    ap.add_argument("--grid", type=float, nargs="*", default=[8.0, 15.0, 25.0])
    ap.add_argument("--sim", action="store_true", help="recall on the simulated apartment instead (--seeds, --queries)")
    ap.add_argument("--seeds", type=int, nargs="*", default=[201, 202, 203])
    ap.add_argument("--modality", choices=["scan", "panorama", "both"], default="scan", help="what the simulated queries sense")
    ap.add_argument("--queries", type=int, default=200)
    ap.add_argument(
        "--cover", type=float, default=None, help="with --sim: add places until every free pose is within this many m of one"
    )
    ap.add_argument(
        "--verify", type=int, default=VERIFY_SHORTLIST, help="also the recall after ICP verification of the top N (0: not)"
    )
    ap.add_argument("--verify-folds", action="store_true", help="fit the verified shortlist's length leave-one-log-out")
    ap.add_argument("--shortlists", type=int, nargs="*", default=[10, 20, 30, 40])
    ap.add_argument(
        "--rank-by", choices=["shape_distribution", "scan_context", "submap_match"], default=RecognitionConfig().rank_by
    )
    ap.add_argument(
        "--half-path", type=float, default=SUBMAP_AHEAD_M, help="submap half-length (m of path), --rank-by submap_match"
    )
    ap.add_argument(
        "--behind", type=float, default=SUBMAP_BEHIND_M, help="submap length behind the place (m of path), --rank-by submap_match"
    )
    ap.add_argument("--match-range", type=float, default=RecognitionConfig().match_max_range_m)
    ap.add_argument("--submap-folds", action="store_true", help="fit the submap half-length and match range leave-one-log-out")
    ap.add_argument("--half-paths", type=float, nargs="*", default=[2.0, 4.0, 6.0])
    ap.add_argument("--match-ranges", type=float, nargs="*", default=[12.0, 20.0])
    ap.add_argument("--truth", action="store_true", help="judge the verified first place against the fitted truth")
    ap.add_argument("--truth-gap", type=float, default=1.0, help="how far (s) from a relation stamp --truth poses a scan")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    if len(args.every) not in (1, len(args.logs)):
        ap.error(f"--every takes one value or one per log ({len(args.logs)})")
    args.every_of = dict(zip(args.logs, args.every * len(args.logs) if len(args.every) == 1 else args.every, strict=False))
    cfg = RecognitionConfig(
        n_rings=args.rings,
        n_sectors=args.sectors,
        max_range_m=args.max_range,
        n_candidates=args.candidates,
        d2_max_range_m=args.d2_range,
        rank_by=args.rank_by,
        match_max_range_m=args.match_range,
    )
    if args.submap_folds:
        submap_folds(args, cfg)
        return
    if args.folds:
        folds(args, cfg)
        return
    if args.sim:
        simulated(args, cfg)
        return
    if args.verify_folds:
        verify_folds(args, cfg)
        return
    logs_table(args, cfg)


def fitted(table: dict[str, dict], logs: list[str], grid: list, held: str | None = None) -> object:
    """Leave one log out: the grid point with the best mean recall@5 on the logs other than ``held``; without
    ``held``, the one whose worst log is best (the default's rule). Ties go to the smaller point."""

    def smaller(g: object) -> tuple:
        return tuple(-x for x in g) if isinstance(g, tuple) else (-g,)  # type: ignore[operator]

    if held is None:
        return max(grid, key=lambda g: (min(table[n][g]["recall_at_5"] for n in logs), *smaller(g)))
    train = [n for n in logs if n != held]
    return max(grid, key=lambda g: (sum(table[n][g]["recall_at_5"] for n in train), *smaller(g)))


def held_out(table: dict[str, dict], logs: list[str], grid: list, name: str) -> list[dict]:
    """Each log held out in turn with the grid point :func:`fitted` on the others: printed, and the rows."""
    print(f"{'held out':<10} {name:>16} {'R@1':>6} {'R@5':>6}")
    out = []
    for held in logs:
        best = fitted(table, logs, grid, held)
        row = table[held][best]
        out.append({"held_out": held, name: best, **row})
        print(f"{held:<10} {best!s:>16} {100 * row['recall_at_1']:>5.1f}% {100 * row['recall_at_5']:>5.1f}%")
    return out


def recall_row(
    args: argparse.Namespace,
    cfg: RecognitionConfig,
    name: str,
    log: object,
    rel: object,
    full: object,
    shortlist: int = 0,
    truth: object = None,
) -> dict:
    """:func:`recognition_recall` with the submap lengths of ``args`` (verified when ``shortlist`` > 0), as a row
    with the CPU per query (``time.process_time``, the map's construction included)."""
    c0 = time.process_time()
    res = recognition_recall(
        log,  # type: ignore[arg-type]
        rel,  # type: ignore[arg-type]
        cfg,
        name=name,
        submap_half_path_m=args.half_path,
        related=full,  # type: ignore[arg-type]
        submap_behind_m=args.behind,
        verify_shortlist=shortlist,
        truth=truth,  # type: ignore[arg-type]
    )
    return res.to_dict() | {"cpu_s_per_query": (time.process_time() - c0) / max(res.ranks.size, 1)}


def logs_table(args: argparse.Namespace, cfg: RecognitionConfig) -> None:
    """The main table: per log, the recall of retrieval and (``--verify`` > 0) after verifying the top N."""
    rows = []
    print(
        f"{'log':<10} {'places':>6} {'loops':>6} {'R@1':>6} {'R@5':>6} {'facing':>6} {'R@1f':>6} {'R@5f':>6} {'R@1rel':>6} "
        f"{'R@5rel':>6} {'s':>6} {'cpu ms/q':>8}"
        + (f" | verified top {args.verify}: R@1 R@5 R@1rel R@5rel cpu ms/q" if args.verify else "")
    )
    judged = []
    for name in args.logs:
        t0 = time.perf_counter()
        log = read_laser_log(args.data / f"{name}.sort.bag")
        full = read_relations(args.data / f"{name}.relations")
        rel = full.subset(args.every_of[name])
        row = recall_row(args, cfg, name, log, rel, full) | {"seconds": time.perf_counter() - t0}
        line = (
            f"{name:<10} {row['places']:>6} {row['loop_relations']:>6} {100 * row['recall_at_1']:>5.1f}% "
            f"{100 * row['recall_at_5']:>5.1f}% {row['facing_relations']:>6} {100 * row['recall_at_1_facing']:>5.1f}% "
            f"{100 * row['recall_at_5_facing']:>5.1f}% {100 * row['recall_at_1_related']:>5.1f}% "
            f"{100 * row['recall_at_5_related']:>5.1f}% {row['seconds']:>6.1f} {1000 * row['cpu_s_per_query']:>8.1f}"
        )
        if args.verify:
            truth = log_truth(full, log.odometry, max_gap_s=args.truth_gap) if args.truth else None
            ver = recall_row(args, cfg, name, log, rel, full, args.verify, truth)
            row["verified"] = ver | {"shortlist": args.verify}
            if truth is not None:
                judged.append((name, ver))
            line += (
                f" | {100 * ver['recall_at_1']:>5.1f}% {100 * ver['recall_at_5']:>5.1f}% "
                f"{100 * ver['recall_at_1_related']:>5.1f}% {100 * ver['recall_at_5_related']:>5.1f}% "
                f"{1000 * ver['cpu_s_per_query']:>8.1f}"
            )
        rows.append(row)
        print(line, flush=True)
    if judged:
        print(f"\nverified first place against the fitted truth (scans within {args.truth_gap:g} s of a relation stamp)")
        print(f"{'log':<10} {'verified':>8} {'judged':>6} {'>0.5m/5°':>9} {'>90°':>6} {'>3σ':>6}")
        for name, v in judged:
            print(
                f"{name:<10} {v['top_verified']:>8} {v['top_judged']:>6} {100 * v['top_wrong_share']:>8.1f}% "
                f"{100 * v['top_flipped_share']:>5.1f}% {100 * v['top_confidently_wrong_share']:>5.1f}%"
            )
    if args.json:
        args.json.write_text(json.dumps({"config": cfg.__dict__, "logs": rows}, indent=2))


def verify_folds(args: argparse.Namespace, cfg: RecognitionConfig) -> None:
    """Leave one log out over the verified shortlist's length (``--shortlists``): for each log, the length with the
    best mean recall@5 on the two others (ties: the shorter), reported on it; then the length whose worst log is best
    (the default's rule)."""
    table: dict[str, dict[int, dict]] = {}
    for name in args.logs:
        log = read_laser_log(args.data / f"{name}.sort.bag")
        full = read_relations(args.data / f"{name}.relations")
        rel = full.subset(args.every_of[name])
        table[name] = {}
        for n in args.shortlists:
            row = table[name][n] = recall_row(args, cfg, name, log, rel, full, n)
            print(
                f"  {name:<10} shortlist {n:>3}: loops {row['loop_relations']:>4} R@1 {100 * row['recall_at_1']:5.1f}%  "
                f"R@5 {100 * row['recall_at_5']:5.1f}%  cpu {1000 * row['cpu_s_per_query']:.0f} ms/query",
                flush=True,
            )
    out = held_out(table, args.logs, args.shortlists, "shortlist")
    worst = fitted(table, args.logs, args.shortlists)
    print(f"best on the worst log: shortlist {worst}")
    if args.json:
        args.json.write_text(
            json.dumps({"folds": out, "grid": {n: {str(k): v for k, v in t.items()} for n, t in table.items()}}, indent=2)
        )


def simulated(args: argparse.Namespace, cfg: RecognitionConfig) -> None:
    """recall@1/@5 on random poses of the simulated apartment (a place every metre of a grid; 360° scans)."""
    from factorloc.evaluation.places import simulated_place_map, simulated_recall
    from factorloc.sim import apartment

    world = apartment()
    width = 0 if args.modality == "scan" else 512
    place_map = simulated_place_map(world, 1.0, seed=0, panorama_width_px=width, cover_m=args.cover)
    verify = args.verify if args.modality != "panorama" else 0  # a panorama-only query has no scan to verify with
    print(
        f"{args.modality}: {'seed':>5} {'places':>6} {'queries':>7} {'R@1':>6} {'R@5':>6} {'covered':>7} "
        f"{'R@1cov':>6} {'R@5cov':>6}" + (f" | verified top {verify}: same columns" if verify else "")
    )
    for seed in args.seeds:
        line = f"{seed:>5} {len(place_map):>6} {args.queries:>7}"
        for n in (0, verify) if verify else (0,):
            r = simulated_recall(
                world,
                place_map,
                args.queries,
                seed,
                cfg,
                panorama_width_px=width,
                with_scan=args.modality == "both",
                verify_shortlist=n,
            )
            line += (
                f" {100 * r.recall_at(1):>5.1f}% {100 * r.recall_at(5):>5.1f}% {100 * r.coverage:>6.1f}% "
                f"{100 * r.recall_at_covered(1):>5.1f}% {100 * r.recall_at_covered(5):>5.1f}%"
            )
        print(line, flush=True)


def folds(args: argparse.Namespace, base: RecognitionConfig) -> None:
    """Leave one log out over the D2 radius grid: fit on two logs, report on the third."""
    table: dict[str, dict[float, dict]] = {}
    for name in args.logs:
        log = read_laser_log(args.data / f"{name}.sort.bag")
        rel = read_relations(args.data / f"{name}.relations").subset(args.every_of[name])
        table[name] = {}
        for r in args.grid:
            table[name][r] = recognition_recall(log, rel, replace(base, d2_max_range_m=r), name=name).to_dict()
            print(
                f"  {name:<10} d2 radius {r:>5.1f} m: R@1 {100 * table[name][r]['recall_at_1']:5.1f}%  "
                f"R@5 {100 * table[name][r]['recall_at_5']:5.1f}%",
                flush=True,
            )
    out = held_out(table, args.logs, args.grid, "d2_max_range_m")
    if args.json:
        args.json.write_text(
            json.dumps({"folds": out, "grid": {n: {str(r): v for r, v in t.items()} for n, t in table.items()}}, indent=2)
        )


def submap_folds(args: argparse.Namespace, base: RecognitionConfig) -> None:
    """Leave one log out over the submap half-length × match range grid (``--rank-by submap_match``)."""
    base = replace(base, rank_by="submap_match")
    grid = [(h, r) for h in args.half_paths for r in args.match_ranges]
    table: dict[str, dict[tuple[float, float], dict]] = {}
    for name in args.logs:
        log = read_laser_log(args.data / f"{name}.sort.bag")
        rel = read_relations(args.data / f"{name}.relations").subset(args.every_of[name])
        table[name] = {}
        for h, r in grid:
            c0 = time.process_time()
            res = recognition_recall(
                log, rel, replace(base, match_max_range_m=r), name=name, submap_half_path_m=h, submap_behind_m=h
            )
            row = res.to_dict() | {"cpu_s_per_query": (time.process_time() - c0) / max(res.ranks.size, 1)}
            table[name][(h, r)] = row
            print(
                f"  {name:<10} half-path {h:>4.1f} m, match range {r:>4.1f} m: loops {row['loop_relations']:>4} "
                f"R@1 {100 * row['recall_at_1']:5.1f}%  R@5 {100 * row['recall_at_5']:5.1f}%  "
                f"cpu {1000 * row['cpu_s_per_query']:.0f} ms/query",
                flush=True,
            )
    print(f"{'held out':<10} {'half-path':>9} {'range':>6} {'R@1':>6} {'R@5':>6}")
    out = []
    for held in args.logs:
        best = fitted(table, args.logs, grid, held)
        row = table[held][best]
        out.append({"held_out": held, "half_path_m": best[0], "match_max_range_m": best[1], **row})
        print(f"{held:<10} {best[0]:>9.1f} {best[1]:>6.1f} {100 * row['recall_at_1']:>5.1f}% {100 * row['recall_at_5']:>5.1f}%")
    worst = fitted(table, args.logs, grid)
    print(f"best on the worst log: half-path {worst[0]:g} m, match range {worst[1]:g} m")
    if args.json:
        args.json.write_text(
            json.dumps(
                {"folds": out, "grid": {n: {f"{h},{r}": v for (h, r), v in t.items()} for n, t in table.items()}}, indent=2
            )
        )


if __name__ == "__main__":
    main()

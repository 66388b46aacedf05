"""Benchmark of the ICP step: the relations benchmark on the Intel and ACES laser logs (ours, ours_icp,
odometry, Open3D point-to-point and point-to-plane, same pairs and seeds, one run), the time and error
ratios against Open3D, and the NEES calibration on simulated queries.

Usage::

    .venv/bin/python benchmarks/bench_icp.py                 # every relation of both logs (2–3 min on 2 cores)
    .venv/bin/python benchmarks/bench_icp.py --every 10      # a fixed 10 % subset
    .venv/bin/python benchmarks/bench_icp.py --sim 100       # + 100 simulated queries for the NEES figures
    .venv/bin/python benchmarks/bench_icp.py --datasets "" --kidnapped 30 --kidnapped-seeds 1,2,3
                                                             # kidnapped-robot recovery through localize()
    .venv/bin/python benchmarks/bench_icp.py --folds         # leave-one-log-out over Intel, ACES, MIT CSAIL
    .venv/bin/python benchmarks/bench_icp.py --folds --candidates default,other --every 5
    .venv/bin/python benchmarks/bench_icp.py --folds --emulate noise=0.01      # the logs as a noisier laser's
    .venv/bin/python benchmarks/bench_icp.py --folds --emulate range=5.6 fov=240   # ... a short-range one's

``--folds`` evaluates each candidate setting of :data:`CANDIDATES` on every fold (fit on two logs, report on
the third; :func:`factorloc.evaluation.folds.relations_folds`) and names the one that does best on its worst
held-out fold (the committed default must be it).
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from factorloc.config import Config
from factorloc.datasets.rosbag import read_laser_log
from factorloc.evaluation.folds import (
    LOGS,
    Candidate,
    EmulatedLaser,
    best_on_worst_fold,
    emulated,
    format_folds,
    load_laser_datasets,
    relations_folds,
)
from factorloc.evaluation.relations import (
    format_table,
    read_relations,
    relations_benchmark,
    relations_config,
    summarize,
    unrecovered_breakdown,
)

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "laser"


def _with_covariance(config: Config, **fields: float) -> Config:
    """``config`` with fields of its ICP covariance group replaced."""
    icp = config.icp
    return replace(config, icp=replace(icp, covariance=replace(icp.covariance, **fields)))


def _fit_inflation(train: dict, config: Config) -> Config:
    """The inflation of the ICP covariance that gives the training logs' reliable ICP estimates a mean position
    NEES of 2 (their χ² mean), pooled over the training logs."""
    nees = [r.nees_position for res in train.values() for r in res if r.method == "ours_icp" and r.reliable]
    nees = [v for v in nees if math.isfinite(v)]
    factor = float(np.mean(nees)) / 2.0
    return _with_covariance(config, inflation=config.icp.covariance.inflation * factor)


#: What ``--candidates ablation`` leaves out, one at a time: rule and waiver codes (``IcpConfig.ablate``) and the
#: flow switches of the configuration.
#: The limits of the heading half of the constraint rule (``icp.reliability.min_heading_strength``) ``--folds``
#: can compare as ``heading<limit>`` (0: the rule off; the circle of tests/estimators/test_icp_degenerate.py: 4e-4).
HEADING_LIMITS: tuple[float, ...] = (0.0, 0.002, 0.005, 0.01, 0.02)

ABLATIONS: tuple[str, ...] = (
    "icp.constraint",
    "icp.free_space",
    "icp.score",
    "icp.global.overlap",
    "icp.global.seed_refuted",
    "icp.global.ambiguity",
    "icp.global.ambiguity.overturn",
    "icp.seed.consistency",
    "icp.waiver.dominant_degenerate",
    "icp.waiver.low_but_clear",
    "icp.waiver.overlap_supported",
    "icp.degenerate_skips_global",
    "icp.seed.free_space",
    "icp.seed.fits_near",
    "icp.seed.stays_near",
    "global_init.ignore_degenerate_rivals",
    "global_init.widen",
    "seed.across_walls",
)


def _ablated(config: Config, what: str) -> Config:
    """``config`` without one rule (a code) or with one flow switch (``group.field``) off."""
    icp = config.icp
    if what.startswith("icp."):
        return replace(config, icp=replace(icp, ablate=(*icp.ablate, what)))
    group, name = what.split(".")
    return replace(config, icp=replace(icp, **{group: replace(getattr(icp, group), **{name: False})}))


def candidates() -> dict[str, Candidate]:
    """The candidate settings ``--folds`` compares (the library default first). Names: ``floor<mm>`` a position
    floor (heading floor 0.23°), ``k<ratio>`` the correlated-error ratio, ``fitted`` an inflation fitted on the
    training logs, ``_i<factor>`` an inflation of the pair's two terms (the floors kept),
    ``weak_prior_on`` / ``weak_prior_off`` the ICP's weak prior (``global_init.weak_prior``),
    ``heading<limit>`` the heading half of the constraint rule at that limit (``reliability.min_heading_strength``;
    ``heading0``: off)."""
    base = relations_config()
    out = {"default": Candidate("default", base), "fitted": Candidate("fitted", base, _fit_inflation)}
    for floor_mm in (2.5, 5, 7.5, 10, 12.5, 15, 20):
        for k in (0.5, 0.75):
            for p in (1.0, 1.25, 1.5):
                name = f"floor{floor_mm:g}" + ("" if k == 0.75 else f"_k{k}") + ("" if p == 1.0 else f"_p{p}")
                cfg = _with_covariance(
                    base, sigma_floor_m=floor_mm / 1000, sigma_floor_rad=0.004, bias_rmse_ratio=k, weak_exponent=p
                )
                out[name] = Candidate(name, cfg)
                for inflation in (0.5, 0.65, 0.8):  # the pair's two terms scaled, the floors kept
                    cfg_i = _with_covariance(cfg, inflation=inflation)
                    out[f"{name}_i{inflation:g}"] = Candidate(f"{name}_i{inflation:g}", cfg_i)
    for what in ABLATIONS:
        out[f"-{what}"] = Candidate(f"-{what}", _ablated(base, what))
    for on in (True, False):  # the weak prior (global_init.weak_prior) switched on and off
        icp = base.icp
        cfg = replace(base, icp=replace(icp, global_init=replace(icp.global_init, weak_prior=on)))
        out[f"weak_prior_{'on' if on else 'off'}"] = Candidate(f"weak_prior_{'on' if on else 'off'}", cfg)
    for limit in HEADING_LIMITS:
        icp = base.icp
        cfg = replace(base, icp=replace(icp, reliability=replace(icp.reliability, min_heading_strength=limit)))
        out[f"heading{limit:g}"] = Candidate(f"heading{limit:g}", cfg)
    on = out["weak_prior_on"].config
    out["weak_prior_rivals"] = Candidate(  # the weak prior's window and rivals, not its free-space contest
        "weak_prior_rivals", replace(on, icp=replace(on.icp, ablate=(*on.icp.ablate, "icp.global.seed_refuted.weak")))
    )
    return out


def _laser(spec: list[str]) -> EmulatedLaser | None:
    """``--emulate`` items ``noise=<m>``, ``range=<m>``, ``fov=<deg>``, ``every=<n>`` as an :class:`EmulatedLaser`."""
    if not spec:
        return None
    names = {"noise": "range_noise_m", "range": "max_range_m", "fov": "fov_rad", "every": "every_beam"}
    kw: dict[str, float | int] = {}
    for item in spec:
        key, _, value = item.partition("=")
        if key not in names or not value:
            raise SystemExit(f"--emulate takes noise=<m>, range=<m>, fov=<deg>, every=<n>; got {item!r}")
        kw[names[key]] = int(value) if key == "every" else math.radians(float(value)) if key == "fov" else float(value)
    return EmulatedLaser(**kw)  # type: ignore[arg-type]


def folds(
    data: Path, names: list[str], every: int, chosen: list[str], json_path: Path | None, laser: EmulatedLaser | None = None
) -> None:
    """Every chosen candidate on every leave-one-log-out fold; the fold table and the best on the worst fold."""
    known = candidates()
    if chosen == ["ablation"]:
        chosen = ["default", *(f"-{w}" for w in ABLATIONS)]
    unknown = [c for c in chosen if c not in known]
    if unknown:
        raise SystemExit(f"unknown candidate(s) {unknown}; known: {list(known)}")
    t0 = time.perf_counter()
    datasets = load_laser_datasets(data, names, every=every)
    if laser is not None:
        datasets = [emulated(d, laser) for d in datasets]
        print(f"scans as {laser} would return them")
    reports = relations_folds(
        datasets, [known[c] for c in chosen], progress=lambda line: print(f"[{time.perf_counter() - t0:6.0f} s] {line}")
    )
    print(format_folds(reports))
    best = best_on_worst_fold(reports)
    print(f"best on the worst held-out fold: {best.candidate} (worst shortfall {best.worst_shortfall:.3f})")
    for r in reports:
        print(f"  {r.candidate}: shortfall per fold " + ", ".join(f"{f.dataset} {f.shortfall():.3f}" for f in r.folds))
    if reports and reports[0].candidate == "default" and any(r.candidate.startswith("-") for r in reports):
        print(rule_table(reports))
    if json_path is not None:
        json_path.write_text("[" + ",\n".join(r.to_json() for r in reports) + "]\n")


def rule_table(reports: list) -> str:
    """The leave-one-rule-out table (markdown): per rule left out and held-out log, the confidently-wrong, recovered
    (10 cm, 1°) and flagged shares of all relations, as differences from the default in relations (+: more)."""
    base = {f.dataset: f for f in reports[0].folds}
    names = [f.dataset for f in reports[0].folds]
    head = "| left out | " + " | ".join(f"{n}: c.w. / recovered / flagged" for n in names) + " |"
    lines = [head, "|---|" + "---|" * len(names)]
    n_all = {n: base[n].n_local + base[n].n_loop for n in names}
    lines.append(
        "| (nothing: the default) | "
        + " | ".join(
            f"{100 * base[n].confidently_wrong_all:.2f} % / {100 * base[n].recovered_all:.1f} % / "
            f"{100 * base[n].flagged_all:.1f} %"
            for n in names
        )
        + " |"
    )
    for rep in reports[1:]:
        cells = []
        for f in rep.folds:
            b = base[f.dataset]
            n = n_all[f.dataset]
            cells.append(
                f"{round(n * (f.confidently_wrong_all - b.confidently_wrong_all)):+d} / "
                f"{round(n * (f.recovered_all - b.recovered_all)):+d} / {round(n * (f.flagged_all - b.flagged_all)):+d}"
            )
        lines.append(f"| `{rep.candidate[1:]}` | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _row(rows: list[dict], method: str, subset: str) -> dict:
    return next(r for r in rows if r["method"] == method and r["subset"] == subset)


def _open3d_local_ratios(log, relations, results, repeats: int = 3) -> tuple[float, float]:  # noqa: ANN001
    """Median over the local relations of the per-pair time ratios (a) Open3D ``registration_icp`` point-to-plane
    bare (its clouds, with our normals, built before the clock starts) / ours and (b) Open3D's per-pair job from
    the raw arrays (build both clouds, the reference's normals — our 2D PCA ones: Open3D's ``estimate_normals``
    gives ±z on a planar cloud —, ``registration_icp``, ``get_information_matrix_from_point_clouds``) / ours.

    Ours is the whole ICP step as the relations benchmark times it (``IcpStep.prepare`` + ``IcpStep.estimate``,
    seeded by the odometry hypothesis of ``relations_config``/``OdometryModel``), timed again here in turn with
    the two Open3D figures on the same pairs with the same odometry seeds (the relations benchmark's own times
    run amid the other methods' work), 0.5 m correspondence distance for Open3D; the fastest of ``repeats``
    runs per pair and method, as in ``benchmarks/bench_align.py``.
    """
    import open3d as o3d

    from factorloc.estimators.base import Hypotheses
    from factorloc.estimators.icp import IcpStep
    from factorloc.estimators.odometry import estimate as odometry_estimate
    from factorloc.evaluation.relations import OdometryModel, relations_config
    from factorloc.registration.open3d_peer import open3d_cloud, pose_matrix
    from factorloc.registration.scan2d import estimate_normals_2d
    from factorloc.types import Query, Reference, Scan

    reg = o3d.pipelines.registration
    p2l = reg.TransformationEstimationPointToPlane()
    criteria = reg.ICPConvergenceCriteria(max_iteration=50)
    config = relations_config()
    step = IcpStep(config.icp)
    model = OdometryModel()

    def ours(reference: Reference, query: Query, hyp: Hypotheses) -> None:
        step.estimate(step.prepare(reference), query, hyp)

    def job(ref: np.ndarray, qry: np.ndarray, T0: np.ndarray) -> None:
        src, tgt = open3d_cloud(qry), open3d_cloud(ref, estimate_normals_2d(ref)[0])
        res = reg.registration_icp(src, tgt, 0.5, T0, p2l, criteria)
        reg.get_information_matrix_from_point_clouds(src, tgt, 0.5, res.transformation)

    local = sorted({r.index for r in results if r.method == "ours" and r.kind == "local"})
    bare_r, job_r = [], []
    for i in local:
        t1, t2 = float(relations.t1_s[i]), float(relations.t2_s[i])
        ref_scan, qry_scan = log.scans.at(t1, 2e-3), log.scans.at(t2, 2e-3)
        ref, qry = ref_scan.points_m, qry_scan.points_m
        seed = log.odometry.between(t1, t2)
        odom = model.odometry(seed, *log.odometry.distance_between(t1, t2))
        hyp = Hypotheses().plus(odometry_estimate(odom, config.odometry))
        reference, query = Reference(scan=Scan(ref)), Query(scan=Scan(qry))
        T0 = pose_matrix(seed)
        src, tgt = open3d_cloud(qry), open3d_cloud(ref, estimate_normals_2d(ref)[0])
        calls = (
            (ours, (reference, query, hyp)),
            (reg.registration_icp, (src, tgt, 0.5, T0, p2l, criteria)),
            (job, (ref, qry, T0)),
        )
        best = [math.inf, math.inf, math.inf]
        for _ in range(repeats):
            for k, (f, args) in enumerate(calls):
                t0 = time.perf_counter()
                f(*args)
                best[k] = min(best[k], time.perf_counter() - t0)
        bare_r.append(best[1] / best[0])
        job_r.append(best[2] / best[0])
    return float(np.median(bare_r)), float(np.median(job_r))


def sim_calibration(n: int, seed: int = 2) -> dict:
    """Mean NEES of (x4, y4) and the fraction outside the 99 % ellipse on simulated seeded queries.

    Degenerate views (the step's position is unknown along a wall: largest σ ≥ half of
    ``UNCONSTRAINED_SIGMA_M``) are calibrated apart, on what they measure: the position across the wall
    (1 dof) and the heading.

    Over the reliable full-pose estimates; heading-only estimates (degenerate views) are counted apart, with
    the mean NEES of their heading (1 dof).
    """
    from scipy.spatial import cKDTree  # noqa: F401 - keeps the import cost out of the timed part

    from factorloc.errors import InputError
    from factorloc.estimators.base import Hypotheses
    from factorloc.estimators.icp import UNCONSTRAINED_SIGMA_M, estimate, prepare_reference, query_points
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

    nees: list[float] = []
    errs: list[float] = []
    reliable: list[bool] = []
    partial: dict[str, list[float]] = {"across_cm": [], "nees_across": [], "nees_heading": []}
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
            est = estimate(
                ref, pts, Hypotheses((Estimate.pose("odometry", seed, 0.05, 0.05, math.radians(2)),)), query_from_cloud=True
            )
        except InputError:
            continue
        e = np.array([est.values[0] - truth.x, est.values[1] - truth.y])
        if est.reliable and np.linalg.eigvalsh(est.covariance[:2, :2])[-1] >= (0.5 * UNCONSTRAINED_SIGMA_M) ** 2:
            # a degenerate view (one wall, a corridor): position unknown along the wall. Calibrate what it does
            # measure — the position across the wall (1 dof) and the heading — and keep it out of the 2-dof figures
            w, v = np.linalg.eigh(est.covariance[:2, :2])
            across = float(v[:, 0] @ e)
            partial["across_cm"].append(100 * abs(across))
            partial["nees_across"].append(across**2 / w[0])
            partial["nees_heading"].append((math.remainder(est.values[2] - truth.theta, 2 * math.pi) / est.sigma("theta")) ** 2)
            reliable.append(False)
            continue
        reliable.append(est.reliable)
        if est.reliable:
            nees.append(float(e @ np.linalg.solve(est.covariance[:2, :2], e)))
            errs.append(float(np.hypot(*e)))
    nees_a = np.array(nees)
    k = len(partial["across_cm"])
    return {
        "queries": n,
        "reliable_rate": float(np.mean(reliable)),
        "median_error_cm": 100 * float(np.median(errs)),
        "nees_mean": float(nees_a.mean()),
        "nees_median": float(np.median(nees_a)),
        "outside_99_rate": float(np.mean(nees_a > 9.2103)),
        "along_wall_unknown_rate": k / n,
        "along_wall_unknown_across_median_cm": float(np.median(partial["across_cm"])) if k else math.nan,
        "along_wall_unknown_across_nees_mean": float(np.mean(partial["nees_across"])) if k else math.nan,
        "along_wall_unknown_heading_nees_mean": float(np.mean(partial["nees_heading"])) if k else math.nan,
    }


def kidnapped_recovery(n_queries: int, seeds: list[int]) -> dict:
    """The full pipeline (:class:`factorloc.Localizer`, default config) on the simulated apartment with kidnapped queries.

    ``generate_scenario('apartment', n_queries, seed, faults=('kidnapped',))`` for each seed; a query is
    *recovered* when the fused pose is within 10 cm and 1° of the truth, *confidently wrong* when its position
    error lies outside the fused covariance's 3σ ellipse (χ², 2 dof, 0.9973). Clean queries of the same
    scenarios are counted separately.
    """
    from scipy.stats import chi2

    from factorloc import Localizer
    from factorloc.sim import generate_scenario

    limit = float(chi2.ppf(0.9973, 2))
    out = {k: {"n": 0, "recovered": 0, "position_recovered": 0, "confidently_wrong": 0} for k in ("kidnapped", "clean")}
    for seed in seeds:
        scenario = generate_scenario("apartment", n_queries, seed, faults=("kidnapped",))
        localizer = Localizer(scenario.references[0].reference)
        for sq in scenario.queries:
            row = out["kidnapped" if "kidnapped" in sq.faults else "clean"]
            loc = localizer.localize(sq.query)
            e = np.array([loc.pose.x - sq.truth.x, loc.pose.y - sq.truth.y])
            err = float(np.hypot(*e))
            herr = abs(math.degrees(math.remainder(loc.pose.theta - sq.truth.theta, 2 * math.pi)))
            cov = loc.covariance[:2, :2]
            row["n"] += 1
            row["recovered"] += int(err < 0.1 and herr < 1.0)
            row["position_recovered"] += int(err < 0.1)
            row["confidently_wrong"] += int(bool(np.all(np.isfinite(cov)) and e @ np.linalg.solve(cov, e) > limit))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--every", type=int, default=1, help="use every k-th relation (fixed subset)")
    ap.add_argument("--datasets", default="intel,aces")
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--sim", type=int, default=0, help="number of simulated queries for the NEES figures (0 = skip)")
    ap.add_argument("--kidnapped", type=int, default=0, help="queries per simulated kidnapped scenario (0 = skip)")
    ap.add_argument("--kidnapped-seeds", default="1,2,3")
    ap.add_argument("--json", type=Path, default=None, help="write the table rows here")
    ap.add_argument("--folds", action="store_true", help="leave-one-log-out over --datasets (default: all three logs)")
    ap.add_argument("--candidates", default="default", help="comma-separated candidate settings for --folds")
    ap.add_argument(
        "--emulate",
        nargs="*",
        default=[],
        metavar="KEY=VALUE",
        help="with --folds: the logs' scans as another laser would return them: noise=<m> range=<m> fov=<deg> every=<n>",
    )
    args = ap.parse_args()
    if args.folds:
        names = [d for d in args.datasets.split(",") if d] if args.datasets != "intel,aces" else list(LOGS)
        folds(args.data, names, args.every, [c for c in args.candidates.split(",") if c], args.json, _laser(args.emulate))
        return
    all_rows: list[dict] = []
    for name in [d for d in args.datasets.split(",") if d]:
        log = read_laser_log(args.data / f"{name}.sort.bag")
        rel = read_relations(args.data / f"{name}.relations").subset(args.every)
        t0 = time.perf_counter()
        results = relations_benchmark(log, rel)
        rows = summarize(results, name)
        all_rows += rows
        print(format_table(rows))
        ours, peer = _row(rows, "ours", "local"), _row(rows, "open3d_p2plane", "local")
        icp = _row(rows, "ours_icp", "local")
        bare, job = _open3d_local_ratios(log, rel, results)
        print(
            f"{name}: local translation error ours/open3d_p2plane = {ours['trans_mean_cm'] / peer['trans_mean_cm']:.2f} "
            f"(ICP alone {icp['trans_mean_cm'] / peer['trans_mean_cm']:.2f}); "
            f"time per pair open3d_p2plane/ours = {peer['ms_per_pair'] / ours['ms_per_pair']:.2f} (mean), "
            f"{peer['ms_median'] / ours['ms_median']:.2f} (median); "
            f"loop recovered {100 * _row(rows, 'ours', 'loop')['recovered_rate']:.1f} %, "
            f"unrecovered flagged {100 * _row(rows, 'ours', 'loop')['unrecovered_flagged_rate']:.1f} %; "
            f"{time.perf_counter() - t0:.0f} s"
        )
        print(
            f"{name}: local relations, time per pair against our whole ICP step (prepare + estimate, timed again in "
            f"turn with Open3D, fastest of 3), median of the per-pair ratios: (a) Open3D registration_icp bare / ours "
            f"= {bare:.2f}, (b) Open3D's per-pair job (clouds from arrays, normals, registration_icp, information "
            f"matrix) / ours = {job:.2f}"
        )
        for subset in ("loop", "local"):
            b = unrecovered_breakdown(results, subset)
            rest = ", ".join(f"{k} {v}" for k, v in sorted(b.items(), key=lambda kv: -kv[1]) if k not in ("n", "recovered"))
            print(f"{name} {subset}: {b['recovered']}/{b['n']} recovered; not recovered: {rest}")
        print()
    if args.sim:
        cal = sim_calibration(args.sim)
        print("simulated seeded queries (apartment, single 58° depth view within 2 m of a 360° reference):")
        print("  " + ", ".join(f"{k} {v:.3g}" for k, v in cal.items()))
    if args.kidnapped:
        seeds = [int(v) for v in args.kidnapped_seeds.split(",")]
        res = kidnapped_recovery(args.kidnapped, seeds)
        print(f"simulated apartment, faults=('kidnapped',), {args.kidnapped} queries × seeds {seeds}, full pipeline:")
        for kind, r in res.items():
            n = max(r["n"], 1)
            print(
                f"  {kind:9s} n {r['n']:3d}  recovered (10 cm, 1°) {100 * r['recovered'] / n:5.1f} %  "
                f"position within 10 cm {100 * r['position_recovered'] / n:5.1f} %  "
                f"confidently wrong {100 * r['confidently_wrong'] / n:5.1f} %"
            )
    if args.json:
        args.json.write_text(json.dumps(all_rows, indent=1))


if __name__ == "__main__":
    main()

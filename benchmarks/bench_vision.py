"""The visual heading steps seeded vs unseeded: time per query, false matches, accuracy.

The patent's claim that the hierarchy cuts time and false positives, measured:
each query is run through the compass (θ2) and the correlation (θ3) twice —
*seeded* (the compass gets the odometry estimate, the correlation the odometry
and the compass) and *unseeded* (no hypotheses: whole panorama, no position,
so no parallax correction either).

Data: the shipped sample scenario (``data/sample``) when present, and the two
real panoramas of ``../shared/data/panoramas`` when present (views cut at
random yaws, the robot known to stand at the photo's point in both modes, the seeded
mode adding a heading with σ = 3°). On the real
panoramas the compass's ORB and SIFT detectors are also compared.

Figures per step and mode: median time per query (ms), false-match rate
(compass: share of descriptor matches whose exact, parallax-free vote — from the true
position and the reference cloud — is more than 2° from the true heading; correlation: share of
queries whose best peak is more than 3° from the truth), reliable rate,
median / 95th percentile heading error of the reliable estimates (deg), and the
confidently-wrong rate (reliable and off by > 3σ).

With ``--sim N`` it also prints the accuracy table in the simulated apartment (N queries per
distance band / position σ / fault).

With ``--scenario DIR`` (e.g. ``factorloc simulate --world apartment --queries 300 --seed 7 /tmp/apt300``)
it runs odometry → compass → correlation on the scenario's queries as the pipeline seeds them, for the
default compass (query views detected at half scale) and the full-scale one (``query_scale=1``) in the same run, query by query
(interleaved, so machine load hits both alike), and prints per step: CPU time per query (median, p95;
``time.process_time``, OpenCV on one thread), reliable rate, heading error of the reliable
estimates (median, RMSE) and their heading NEES (1 dof: mean ``(err/σ)²``, ≈ 1 when σ is honest)
with the count beyond 3σ.

With ``--no-depth DIR ...`` it runs the heading-only compass on those scenarios with each reference's cloud left
out, the spread bound (``CompassConfig.parallax_from_spread``) on and off: views from other spots, where the votes'
agreement must not be read as "here".

With ``--pose DIR ...`` it prints the pose-from-bearings table per scenario (the compass with and without its pose,
the correlation after each, a plain ORB vote baseline, CPU ms per query); ``--set name=value ...`` adds a variant of
:class:`CompassConfig` beside them, query by query in the same run (booleans as ``true``/``false``); ``--depth scan``
leaves each reference's cloud out, so that its planar scan is the only depth (``CompassConfig.planar_depth``).
``--same-spot N``: views at the reference spot (the simulated apartment with its cloud, its laser scan only, no
depth; the real panoramas).

Run: ``.venv/bin/python benchmarks/bench_vision.py [--queries N] [--views N] [--sim N] [--scenario DIR]``.
Prints figures; asserts nothing.
"""

from __future__ import annotations

import argparse
import math
import statistics
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from factorloc import CameraImage, Estimate, Query, Reference
from factorloc.estimators import compass, correlation
from factorloc.estimators.base import Hypotheses
from factorloc.estimators.odometry import OdometryStep

#: The robot stands at the photo's point (both modes): only the heading search is seeded or not.
AT_PHOTO = Hypotheses((Estimate.position("position", 0.0, 0.0, 0.01, 0.01),))

REPO = Path(__file__).resolve().parents[1]
SAMPLE = REPO / "data" / "sample"
PANORAMAS = REPO.parent / "shared" / "data" / "panoramas"


@dataclass
class Tally:
    seconds: list[float] = field(default_factory=list)
    errors_deg: list[float] = field(default_factory=list)
    reliable: list[bool] = field(default_factory=list)
    wrong: list[bool] = field(default_factory=list)  # reliable and off by > 3σ
    false_matches: int = 0
    matches: int = 0
    bad_peaks: int = 0
    peaks: int = 0

    def add(self, est: Estimate, truth_rad: float, seconds: float, pair_truth=None) -> None:  # noqa: ANN001
        err = abs(math.remainder(est.value("theta") - truth_rad, 2 * math.pi))
        self.seconds.append(seconds)
        self.reliable.append(est.reliable)
        if est.reliable:
            self.errors_deg.append(math.degrees(err))
            self.wrong.append(err > 3.0 * est.sigma("theta"))
        d = est.diagnostics
        if "pairs_rad" in d and pair_truth is not None:
            pairs = np.asarray(d["pairs_rad"], dtype=np.float64).reshape(-1, 3)
            self.matches += len(pairs)
            self.false_matches += int(np.sum(~pair_truth(pairs)))
        if "peak" in d:
            self.peaks += 1
            self.bad_peaks += int(err > math.radians(PEAK_TOLERANCE_DEG))

    def row(self, label: str) -> str:
        t = 1e3 * statistics.median(self.seconds) if self.seconds else math.nan
        fm = self.false_matches / self.matches if self.matches else (self.bad_peaks / self.peaks if self.peaks else math.nan)
        rel = float(np.mean(self.reliable)) if self.reliable else math.nan
        med = float(np.median(self.errors_deg)) if self.errors_deg else math.nan
        p95 = float(np.percentile(self.errors_deg, 95)) if self.errors_deg else math.nan
        cw = float(np.mean(self.wrong)) if self.wrong else 0.0
        return f"{label:34s} {t:9.1f} {fm:11.3f} {rel:9.2f} {med:9.3f} {p95:9.3f} {cw:9.3f}  (n={len(self.seconds)})"


#: A correlation "false match": the best peak further than this from the truth (deg).
PEAK_TOLERANCE_DEG = 3.0
#: A compass pair is a true match when its exact vote (parallax-free, from the true position) is within this (deg).
PAIR_TOLERANCE_DEG = 2.0

HEADER = (
    f"{'step / mode':34s} {'ms/query':>9s} {'false-match':>11s} {'reliable':>9s} "
    f"{'med err°':>9s} {'p95 err°':>9s} {'conf.wrong':>9s}"
)


def _timed(fn, *args, **kwargs):  # noqa: ANN001, ANN002, ANN003, ANN202
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


def bench_sample(max_queries: int) -> None:
    from factorloc.datasets import load_scenario

    scenario = load_scenario(SAMPLE)
    ref = scenario.reference
    cc, rc = compass.CompassConfig(record_pairs=True), correlation.CorrelationConfig()
    c_step, r_step = compass.CompassStep(cc), correlation.CorrelationStep(rc)
    (pc, tpc), (pr, tpr) = _timed(c_step.prepare, ref), _timed(r_step.prepare, ref)
    odo = OdometryStep()
    tallies = {k: Tally() for k in ("compass seeded", "compass unseeded", "correlation seeded", "correlation unseeded")}
    for sq in scenario.queries[:max_queries]:
        q, truth = sq.query, sq.truth
        if truth is None or (not q.images and q.panorama is None):
            continue
        hyp = Hypotheses()
        if q.odometry is not None:
            hyp = hyp.plus(odo.estimate(None, q, Hypotheses()))

        def pair_truth(pairs: np.ndarray, truth=truth) -> np.ndarray:  # noqa: ANN001
            # the exact vote of each pair: the reference point (from the reference cloud) seen from the true position
            world, _ = pc.depth.world_headings(pairs[:, 0], pairs[:, 2], (truth.x, truth.y), pairs[:, 1])
            return np.abs(np.mod(world - truth.theta + math.pi, 2 * math.pi) - math.pi) <= math.radians(PAIR_TOLERANCE_DEG)

        ec, t = _timed(c_step.estimate, pc, q, hyp)
        tallies["compass seeded"].add(ec, truth.theta, t, pair_truth)
        er, t = _timed(r_step.estimate, pr, q, hyp.plus(ec))
        tallies["correlation seeded"].add(er, truth.theta, t)
        ec, t = _timed(c_step.estimate, pc, q, Hypotheses())
        tallies["compass unseeded"].add(ec, truth.theta, t, pair_truth)
        er, t = _timed(r_step.estimate, pr, q, Hypotheses())
        tallies["correlation unseeded"].add(er, truth.theta, t)
    print(
        f"\n== sample scenario {SAMPLE.relative_to(REPO)} ({len(scenario.queries)} queries; prepare: compass "
        f"{1e3 * tpc:.0f} ms, correlation {1e3 * tpr:.0f} ms) =="
    )
    print(HEADER)
    for k, v in tallies.items():
        print(v.row(k))
    for step in ("compass", "correlation"):
        s, u = tallies[f"{step} seeded"], tallies[f"{step} unseeded"]
        print(f"{step}: unseeded/seeded time ratio {statistics.median(u.seconds) / statistics.median(s.seconds):.2f}")


def bench_real(n_views: int) -> None:
    from factorloc.sim import photo

    for name, (w, h) in {"indoor-bedroom.png": (1024, 180), "outdoor-summit.jpg": (2048, 340)}.items():
        eq = photo.load_equirectangular(PANORAMAS / name)
        ref = Reference(panorama=photo.reference_panorama(eq, w, h))
        rng = np.random.default_rng(5)
        views = []
        for _ in range(n_views):
            theta, yaw = rng.uniform(-math.pi, math.pi), rng.uniform(-0.6, 0.6)
            cam = photo.camera_view(eq, theta, yaw, width_px=320, height_px=240)
            gain, gamma = rng.uniform(0.7, 1.3), rng.uniform(0.8, 1.25)
            img = photo.photometric(cam.image_bgr, gain=gain, gamma=gamma, noise_sigma=3.0, rng=rng)
            seed = Estimate.heading("odometry", theta + rng.normal(0.0, math.radians(3.0)), math.radians(3.0))
            views.append((theta, Query(images=(CameraImage(img, cam.hfov_rad, cam.yaw_in_robot_rad),)), AT_PHOTO.plus(seed)))
        print(f"\n== real panorama {name} ({w}×{h}), {n_views} views 320×240 with lighting changes ==")
        print(HEADER)
        for detector in ("sift", "orb"):
            cfg = compass.CompassConfig(detector=detector, record_pairs=True)
            prep, tp = _timed(compass.prepare, ref, cfg)
            for mode in ("seeded", "unseeded"):
                tally = Tally()
                for theta, q, hyp in views:
                    est, t = _timed(compass.estimate, ref, q, hyp if mode == "seeded" else AT_PHOTO, cfg, prepared=prep)

                    def pair_truth(pairs: np.ndarray, theta=theta) -> np.ndarray:  # noqa: ANN001
                        # no parallax at the photo's point: the exact vote is az_ref − az_query
                        v = np.mod(pairs[:, 0] - pairs[:, 2] - theta + math.pi, 2 * math.pi) - math.pi
                        return np.abs(v) <= math.radians(PAIR_TOLERANCE_DEG)

                    tally.add(est, theta, t, pair_truth)
                print(tally.row(f"compass[{detector}] {mode} (prep {1e3 * tp:.0f} ms)"))
        cfg = correlation.CorrelationConfig()
        prep, tp = _timed(correlation.prepare, ref, cfg)
        for mode in ("seeded", "unseeded"):
            tally = Tally()
            for theta, q, hyp in views:
                est, t = _timed(correlation.estimate, ref, q, hyp if mode == "seeded" else AT_PHOTO, cfg, prepared=prep)
                tally.add(est, theta, t)
            print(tally.row(f"correlation {mode}"))


def bench_sim_accuracy(n: int) -> None:
    """Accuracy in the simulated apartment (parallax!), per distance band, position σ and fault."""
    from factorloc import Pose2
    from factorloc.sim import DepthCamera, PinholeCamera, apartment, photo, render_camera, render_cloud_360, render_panorama

    world = apartment()
    t_ref = Pose2(3.0, 2.2, 0.3)
    pano = render_panorama(world, t_ref, width_px=2048)
    cloud = render_cloud_360(world, t_ref, DepthCamera(stride_px=4), np.random.default_rng(1))
    ref = Reference(panorama=pano, cloud=cloud, T_world_reference=t_ref)
    cc = compass.CompassConfig(record_pairs=True)
    pc, pr = compass.prepare(ref, cc), correlation.prepare(ref)
    print(
        f"\n== simulated apartment, reference {t_ref}, {n} camera queries (320×240) per row; hypotheses: odometry pose "
        "with position σ as given and heading σ 2°; the correlation also gets the compass =="
    )
    print(HEADER)
    cases = [
        ((0.0, 2.0), 0.005, "clean"),
        ((0.0, 2.0), 0.005, "lighting"),
        ((0.0, 2.0), 0.005, "occlusion"),
        ((0.0, 2.0), 0.03, "clean"),
        ((2.0, 3.5), 0.005, "clean"),
    ]
    for (d_lo, d_hi), s_p, fault in cases:
        rng = np.random.default_rng(7)
        tc, tr = Tally(), Tally()
        made = 0
        while made < n:
            d, a = rng.uniform(d_lo, d_hi), rng.uniform(-math.pi, math.pi)
            x, y = t_ref.x + d * math.cos(a), t_ref.y + d * math.sin(a)
            if not world.is_free(np.array([[x, y]]), 0.4)[0]:
                continue
            theta = rng.uniform(-math.pi, math.pi)
            cam = render_camera(world, Pose2(x, y, theta), PinholeCamera(width_px=320, height_px=240))
            img = cam.image_bgr
            if fault == "lighting":
                gain, gamma = rng.uniform(0.6, 1.4), rng.uniform(0.75, 1.3)
                img = photo.photometric(img, gain=gain, gamma=gamma, noise_sigma=4.0, blur_sigma_px=0.7, rng=rng)
            elif fault == "occlusion":
                img = photo.occlude(img, 0.3, rng=rng, n_blocks=2)
            odo = Pose2(x + rng.normal(0, s_p), y + rng.normal(0, s_p), theta + rng.normal(0, math.radians(2.0)))
            hyp = Hypotheses((Estimate.pose("odometry", odo, s_p, s_p, math.radians(2.0)),))
            q = Query(images=(CameraImage(img, cam.hfov_rad),))
            ec, t = _timed(compass.estimate, ref, q, hyp, cc, prepared=pc)

            def pair_truth(pairs: np.ndarray, x=x, y=y, theta=theta) -> np.ndarray:  # noqa: ANN001
                world_h, _ = pc.depth.world_headings(pairs[:, 0], pairs[:, 2], (x, y), pairs[:, 1])
                return np.abs(np.mod(world_h - theta + math.pi, 2 * math.pi) - math.pi) <= math.radians(PAIR_TOLERANCE_DEG)

            tc.add(ec, theta, t, pair_truth)
            er, t = _timed(correlation.estimate, ref, q, hyp.plus(ec), prepared=pr)
            tr.add(er, theta, t)
            made += 1
        label = f"{d_lo:.0f}–{d_hi:.1f} m σp {100 * s_p:.1f} cm {fault}"
        print(tc.row(f"compass {label}"))
        print(tr.row(f"correl. {label}"))


def _compass_then_correlation(prepared: dict, name: str, cfg: Any, ref: Any, case: Any, hyp: Hypotheses) -> tuple:
    """The compass (variant ``name``) then the correlation seeded by it, each reference prepared once per variant:
    ``(compass estimate, correlation estimate, compass CPU s, correlation CPU s)``."""
    key = (name, case.reference_id)
    if key not in prepared:
        t0 = time.process_time()
        pc = compass.prepare(ref, cfg)
        t1 = time.process_time()
        prepared[key] = (pc, correlation.prepare(ref))
        prepared[("prepare CPU s",) + key] = (t1 - t0, time.process_time() - t1)
    pc, pr = prepared[key]
    t0 = time.process_time()
    ec = compass.estimate(ref, case.query, hyp, cfg, prepared=pc)
    t1 = time.process_time()
    er = correlation.estimate(ref, case.query, hyp.plus(ec), prepared=pr)
    return ec, er, t1 - t0, time.process_time() - t1


def bench_scenario(directory: Path, max_queries: int) -> None:
    """Per-step CPU time, availability, accuracy and heading NEES on a scenario, default vs full-scale compass."""
    import cv2

    from factorloc.datasets import load_scenario
    from factorloc.evaluation.runner import evaluation_set

    cv2.setNumThreads(1)  # one core, as the latency target; CPU time below is then this thread's
    data = evaluation_set(load_scenario(directory))
    variants = {
        "default": compass.CompassConfig(),
        "query_scale=1 (full)": compass.CompassConfig(query_scale=1.0, query_sift_sigma=1.6),
    }
    odo = OdometryStep()
    prepared: dict[tuple[str, str], tuple] = {}
    rows: dict[tuple[str, str], list] = {(v, s): [] for v in variants for s in ("compass", "correlation")}
    for case in data.cases[:max_queries]:
        if case.truth is None or (not case.query.images and case.query.panorama is None):
            continue
        ref = data.reference_of(case)
        hyp = Hypotheses().plus(odo.estimate(None, case.query, Hypotheses()))
        for name, cfg in variants.items():
            ec, er, sec_c, sec_r = _compass_then_correlation(prepared, name, cfg, ref, case, hyp)
            for step, est, sec in (("compass", ec, sec_c), ("correlation", er, sec_r)):
                err = math.remainder(est.value("theta") - case.truth.theta, 2 * math.pi)
                rows[(name, step)].append((sec, est.reliable, err, est.sigma("theta")))
    print(f"\n== scenario {directory} ({len(rows[('default', 'compass')])} queries), seeded as in the pipeline ==")
    print(
        f"{'compass variant / step':34s} {'cpu ms med':>10s} {'p95':>7s} {'reliable':>8s} {'med err°':>8s} "
        f"{'rmse°':>7s} {'NEES':>6s} {'>3σ':>4s}"
    )
    for (name, step), r in rows.items():
        sec = np.array([x[0] for x in r]) * 1e3
        rel = [x for x in r if x[1]]
        err = np.degrees(np.abs([x[2] for x in rel])) if rel else np.array([math.nan])
        z2 = np.array([(x[2] / x[3]) ** 2 for x in rel]) if rel else np.array([math.nan])
        print(
            f"{name + ' / ' + step:34s} {np.median(sec):10.1f} {np.percentile(sec, 95):7.1f} {len(rel) / len(r):8.2f} "
            f"{np.median(err):8.3f} {math.sqrt(np.mean(err**2)):7.2f} {np.mean(z2):6.2f} {int(np.sum(z2 > 9.0)):4d}"
        )


# --------------------------------------------------------------------------------------------------------------
# Pose from bearings (beyond the patent): the compass with and without resection, and a plain ORB vote baseline
# --------------------------------------------------------------------------------------------------------------
#: A baseline vote mode is "reliable" with at least this many votes within ±BASELINE_BAND_DEG of it.
BASELINE_MIN_VOTES = 8
BASELINE_BAND_DEG = 1.5


class OrbVote:
    """The plain baseline: OpenCV ORB, Lowe's ratio test, each pair votes ``az_ref − az_query``, the densest 1.5° band.

    Unseeded, no parallax model, no σ: "reliable" when ≥ 8 votes fall in the band; "wrong" when then off by > 3°.
    Query azimuths from the pinhole model (``yaw + atan((cx − u) / f)``), reference ones from the panorama grid.
    """

    def __init__(self, reference: Reference, n_reference: int = 4000, n_query: int = 1500) -> None:
        import cv2

        from factorloc.vision.strips import Grid

        self.cv2 = cv2
        self.grid = Grid.of(reference.panorama)
        self.theta_ref = reference.T_world_reference.theta
        gray = cv2.cvtColor(reference.panorama.image_bgr, cv2.COLOR_BGR2GRAY)
        kps, self.desc = cv2.ORB_create(n_reference).detectAndCompute(gray, None)
        self.az = np.asarray(self.grid.azimuth_of_column(np.array([k.pt[0] for k in kps])), dtype=np.float64)
        self.orb = cv2.ORB_create(n_query)
        self.matcher = cv2.BFMatcher(cv2.NORM_HAMMING)

    def heading(self, query: Query) -> tuple[float, bool]:
        """(world heading, reliable) of the vote mode over the query's camera images."""
        cv2 = self.cv2
        votes = []
        for cam in query.images:
            gray = cv2.cvtColor(cam.image_bgr, cv2.COLOR_BGR2GRAY)
            kps, desc = self.orb.detectAndCompute(gray, None)
            if desc is None or self.desc is None:
                continue
            for m in self.matcher.knnMatch(desc, self.desc, k=2):
                if len(m) == 2 and m[0].distance < 0.8 * m[1].distance:
                    u = kps[m[0].queryIdx].pt[0]
                    az_q = cam.yaw_in_robot_rad + math.atan((cam.principal_x_px - u) / cam.focal_px)
                    votes.append(self.az[m[0].trainIdx] - az_q)
        if len(votes) < BASELINE_MIN_VOTES:
            return self.theta_ref, False
        v = np.mod(np.asarray(votes), 2 * math.pi)
        band = math.radians(BASELINE_BAND_DEG)
        diff = np.abs(np.mod(v[:, None] - v[None, :] + math.pi, 2 * math.pi) - math.pi)
        support = (diff <= band).sum(axis=1)
        k = int(np.argmax(support))
        near = diff[k] <= band
        mode = v[k] + float(np.mean(np.mod(v[near] - v[k] + math.pi, 2 * math.pi) - math.pi))
        return self.theta_ref + mode, bool(support[k] >= BASELINE_MIN_VOTES)


@dataclass
class PoseTally:
    """Per-variant figures of the pose benchmark."""

    ms: list = field(default_factory=list)
    reliable: int = 0
    n: int = 0
    wrong: int = 0  # reliable, heading off by > 3σ (baseline: > 3°), or a pose's position off by d² > 11.83 (2 dof)
    heading_err: list = field(default_factory=list)
    posed: int = 0
    pos_err_near: list = field(default_factory=list)  # the poses' position errors at ≤ 2 m from the reference
    near_n: int = 0
    failed_rules: Counter = field(default_factory=Counter)  # rule code -> unreliable estimates that failed it

    def add(self, est: Estimate | None, truth, seconds: float, distance_m: float, *, baseline=None) -> None:  # noqa: ANN001
        self.n += 1
        self.ms.append(seconds * 1e3)
        self.near_n += distance_m <= 2.0
        if baseline is not None:
            theta, ok = baseline
            err = abs(math.remainder(theta - truth.theta, 2 * math.pi))
            if ok:
                self.reliable += 1
                self.heading_err.append(err)
                self.wrong += err > math.radians(3.0)
            return
        if not est.reliable:
            self.failed_rules.update({c.code for c in est.checks if not c.passed})
            return
        self.reliable += 1
        err = abs(math.remainder(est.value("theta") - truth.theta, 2 * math.pi))
        self.heading_err.append(err)
        wrong = err > 3.0 * est.sigma("theta")
        if est.measures("x"):
            self.posed += 1
            e = np.array([est.value("x") - truth.x, est.value("y") - truth.y])
            cov = np.asarray(est.covariance)[:2, :2]
            wrong = wrong or float(e @ np.linalg.solve(cov, e)) > 11.83
            if distance_m <= 2.0:
                self.pos_err_near.append(float(np.hypot(*e)))
        self.wrong += wrong

    def rules(self) -> str:
        """The rules that kept the estimates from being reliable: the share of the queries failing each (typed
        check codes; an estimate may fail several)."""
        return ", ".join(f"{code} {100 * k / max(self.n, 1):.1f} %" for code, k in self.failed_rules.most_common())

    def row(self, label: str) -> str:
        med = math.degrees(float(np.median(self.heading_err))) if self.heading_err else math.nan
        pos = f"{100 * np.median(self.pos_err_near):.1f} ({len(self.pos_err_near)}/{self.near_n})" if self.pos_err_near else "—"
        return (
            f"| {label} | {self.n} | {100 * self.reliable / max(self.n, 1):.0f} % | {100 * self.wrong / max(self.n, 1):.1f} % "
            f"| {med:.3f} | {100 * self.posed / max(self.n, 1):.0f} % | {pos} | {np.median(self.ms):.1f} |"
        )


POSE_HEADER = (
    "| variant / step | queries | reliable | confidently wrong | median heading error (°) | with a pose "
    "| position error median, cm (poses / queries at ≤ 2 m) | ms / query (median, 1 core) |\n"
    "|---|---|---|---|---|---|---|---|"
)


def _print_ratios(tallies: dict, compass_key: str, correlation_key: str, label: str = "") -> None:
    """The compass's and the correlation's median CPU time per query over the ORB vote baseline's, same run."""
    base = float(np.median(tallies["ORB vote baseline"].ms))
    c, r = float(np.median(tallies[compass_key].ms)), float(np.median(tallies[correlation_key].ms))
    print(
        f"{label + ': ' if label else ''}median CPU ms per query: compass {c:.1f}, correlation {r:.1f}, ORB vote baseline "
        f"{base:.1f} (same run) -> compass / ORB {c / base:.2f}, correlation / ORB {r / base:.2f}"
    )


def _overrides(items: list[str]) -> dict[str, Any]:
    """``name=value`` settings of :class:`CompassConfig`, each value cast to the type of the field's default."""
    base = compass.CompassConfig()
    kw: dict[str, Any] = {}
    for item in items:
        key, value = item.split("=", 1)
        kind = type(getattr(base, key))
        if kind is bool:
            if value.lower() not in ("0", "1", "false", "true"):
                raise SystemExit(f"--set {key}: a boolean is 0, 1, false or true, got {value!r}")
            kw[key] = value.lower() in ("1", "true")
        else:
            kw[key] = kind(float(value)) if kind is int else kind(value) if kind is str else float(value)
    return kw


def _with_depth(reference: Reference, depth: str) -> Reference:
    """``reference`` with the depth ``depth`` names: ``"cloud"`` as it is (the cloud preferred), ``"scan"`` its planar
    scan only (the one-row wall outline :func:`factorloc.vision.depth.depth_map` reads for every elevation)."""
    if depth == "cloud":
        return reference
    if reference.scan is None:
        raise SystemExit(f"--depth scan: reference {reference.name!r} has no scan")
    return Reference(
        panorama=reference.panorama, scan=reference.scan, T_world_reference=reference.T_world_reference, name=reference.name
    )


def bench_pose(directories: list[Path], max_queries: int, overrides: list[str] | None = None, depth: str = "cloud") -> None:
    """The compass with pose from bearings vs heading-only, the correlation after each, and a plain ORB vote.

    With ``overrides`` (``name=value`` settings of :class:`CompassConfig`) a third variant, the default with them,
    runs beside the others, query by query in the same run. ``depth="scan"`` leaves each reference's cloud out, so
    that its planar scan (the laser's outline at its height, furniture included) is the only depth.
    """
    import cv2

    from factorloc.datasets import load_scenario
    from factorloc.evaluation.runner import evaluation_set

    cv2.setNumThreads(1)
    variants = {
        "pose from bearings (default)": compass.CompassConfig(),
        "heading only": compass.CompassConfig(pose_from_bearings=False),
    }
    if overrides:
        kw = _overrides(overrides)
        variants[", ".join(f"{k}={v}" for k, v in kw.items())] = compass.CompassConfig(**kw)
    odo = OdometryStep()
    for directory in directories:
        data = evaluation_set(load_scenario(directory))
        tallies = {
            k: PoseTally() for k in [f"{v} / {s}" for v in variants for s in ("compass", "correlation")] + ["ORB vote baseline"]
        }
        prepared: dict = {}
        for case in data.cases[:max_queries]:
            if case.truth is None or not case.query.images:
                continue
            if ("depth", case.reference_id) not in prepared:
                prepared[("depth", case.reference_id)] = _with_depth(data.reference_of(case), depth)
            ref = prepared[("depth", case.reference_id)]
            dist = math.hypot(case.truth.x - ref.T_world_reference.x, case.truth.y - ref.T_world_reference.y)
            hyp = Hypotheses().plus(odo.estimate(None, case.query, Hypotheses()))
            for name, cfg in variants.items():
                ec, er, sec_c, sec_r = _compass_then_correlation(prepared, name, cfg, ref, case, hyp)
                tallies[f"{name} / compass"].add(ec, case.truth, sec_c, dist)
                tallies[f"{name} / correlation"].add(er, case.truth, sec_r, dist)
            if ("orb", case.reference_id) not in prepared:
                prepared[("orb", case.reference_id)] = OrbVote(ref)
            t0 = time.process_time()
            base = prepared[("orb", case.reference_id)].heading(case.query)
            tallies["ORB vote baseline"].add(None, case.truth, time.process_time() - t0, dist, baseline=base)
        print(f"\n== {directory}, reference depth: {depth} ==")
        print(POSE_HEADER)
        for label, t in tallies.items():
            print(t.row(label))
        for label, t in tallies.items():
            if t.failed_rules:
                print(f"why not reliable, {label}: {t.rules()}")
        for name in [v for v in variants if v != "heading only"]:
            _print_ratios(tallies, f"{name} / compass", f"{name} / correlation", name)
        for key, (tc, tr) in ((k, v) for k, v in prepared.items() if k[0] == "prepare CPU s"):
            print(f"preparation of {key[2]!r} ({key[1]}), CPU ms once: compass {1e3 * tc:.0f}, correlation {1e3 * tr:.0f}")


def bench_same_spot(n_views: int) -> None:
    """Views at the reference spot, the issue's protocol: odometry heading σ 10° and position σ 0.2 m (that much noise drawn).

    Simulated apartment, with its cloud (the pose path applies) and without (the heading-only path), and the two real
    panoramas (no depth: the heading-only path, whose parallax term is the smaller of the 0.2 m the odometry allows
    and what the votes' own spread bounds, ``CompassConfig.parallax_from_spread``).
    """
    import cv2

    from factorloc import Pose2
    from factorloc.sim import (
        DepthCamera,
        PinholeCamera,
        apartment,
        photo,
        render_camera,
        render_cloud_360,
        render_panorama,
        render_scan,
    )

    cv2.setNumThreads(1)
    s_p, s_t = 0.2, math.radians(10.0)
    print(f"\n== same spot: {n_views} views per source, 640×480 57°, gain/gamma/noise/blur; odometry σ 0.2 m / 10° drawn ==")
    print(POSE_HEADER)
    rng = np.random.default_rng(5)

    def photometric(img: np.ndarray) -> np.ndarray:
        gain, gamma = rng.uniform(0.6, 1.4), rng.uniform(0.75, 1.3)
        return photo.photometric(img, gain=gain, gamma=gamma, noise_sigma=4.0, blur_sigma_px=0.7, rng=rng)

    world = apartment()
    t_ref = Pose2(3.0, 2.2, 0.3)
    sources = []
    pano = render_panorama(world, t_ref, width_px=2048)
    cloud = render_cloud_360(world, t_ref, DepthCamera(stride_px=4), np.random.default_rng(1))
    sim_ref = Reference(panorama=pano, cloud=cloud, T_world_reference=t_ref)

    def sim_view(theta: float):  # noqa: ANN202
        cam = render_camera(
            world, Pose2(t_ref.x, t_ref.y, theta), PinholeCamera(width_px=640, height_px=480, hfov_rad=math.radians(57.0))
        )
        return CameraImage(photometric(cam.image_bgr), cam.hfov_rad)

    sources.append(("simulated apartment (cloud)", sim_ref, sim_view))
    scan = render_scan(world, t_ref, 360, 0.3, rng=np.random.default_rng(2))
    sources.append(("simulated apartment (scan only)", Reference(panorama=pano, scan=scan, T_world_reference=t_ref), sim_view))
    sources.append(("simulated apartment (no depth)", Reference(panorama=pano, T_world_reference=t_ref), sim_view))
    for name, (w, h) in {"indoor-bedroom.png": (1024, 180), "outdoor-summit.jpg": (2048, 340)}.items():
        path = PANORAMAS / name
        if not path.is_file():
            continue
        eq = photo.load_equirectangular(path)
        ref = Reference(panorama=photo.reference_panorama(eq, w, h))

        def real_view(theta: float, eq=eq):  # noqa: ANN001, ANN202
            cam = photo.camera_view(eq, theta, 0.0, width_px=640, height_px=480, hfov_rad=math.radians(57.0))
            return CameraImage(photometric(cam.image_bgr), cam.hfov_rad, cam.yaw_in_robot_rad)

        sources.append((f"{name} (no depth)", ref, real_view))
    for label, ref, view in sources:
        cfg = compass.CompassConfig()
        pc, pr = compass.prepare(ref, cfg), correlation.prepare(ref)
        orb = OrbVote(ref)
        tc, tr, tb = PoseTally(), PoseTally(), PoseTally()
        p = ref.T_world_reference
        for _ in range(n_views):
            theta = float(rng.uniform(-math.pi, math.pi))
            q = Query(images=(view(theta),))
            truth = Pose2(p.x, p.y, theta)
            odo = Pose2(p.x + rng.normal(0, s_p), p.y + rng.normal(0, s_p), theta + rng.normal(0, s_t))
            hyp = Hypotheses((Estimate.pose("odometry", odo, s_p, s_p, s_t),))
            t0 = time.process_time()
            ec = compass.estimate(ref, q, hyp, cfg, prepared=pc)
            t1 = time.process_time()
            er = correlation.estimate(ref, q, hyp.plus(ec), prepared=pr)
            t2 = time.process_time()
            base = orb.heading(q)
            t3 = time.process_time()
            tc.add(ec, truth, t1 - t0, 0.0)
            tr.add(er, truth, t2 - t1, 0.0)
            tb.add(None, truth, t3 - t2, 0.0, baseline=base)
        print(tc.row(f"{label} / compass"))
        print(tr.row(f"{label} / correlation"))
        print(tb.row(f"{label} / ORB vote baseline"))
        _print_ratios({"compass": tc, "correlation": tr, "ORB vote baseline": tb}, "compass", "correlation", label)
        for step, t in (("compass", tc), ("correlation", tr)):
            print(f"why not reliable, {label} / {step}: {t.rules()}")


def bench_no_depth(directories: list[Path], max_queries: int, overrides: list[str] | None = None) -> None:
    """The heading-only compass without reference depth, the spread bound on and off, on simulated scenarios.

    Each reference's cloud is left out (its panorama and pose kept), so that only the heading-only path runs and the
    parallax cannot be corrected: views 0.3–3 m from the reference, where the votes' own spread must not be read as
    "here" (``CompassConfig.parallax_from_spread``; the danger is a scene whose points all shift alike). Odometry as
    the pipeline seeds it; same queries, query by query.
    """
    import cv2

    from factorloc.datasets import load_scenario
    from factorloc.evaluation.runner import evaluation_set

    cv2.setNumThreads(1)
    variants = {
        "spread bound (default)": compass.CompassConfig(),
        "no spread bound": compass.CompassConfig(parallax_from_spread=False),
    }
    for item in overrides or []:
        kw = _overrides([item])
        variants[item] = compass.CompassConfig(**kw)
    odo = OdometryStep()
    for directory in directories:
        data = evaluation_set(load_scenario(directory))
        tallies = {k: PoseTally() for k in variants}
        prepared: dict = {}
        for case in data.cases[:max_queries]:
            if case.truth is None or not case.query.images:
                continue
            ref0 = data.reference_of(case)
            ref = Reference(panorama=ref0.panorama, T_world_reference=ref0.T_world_reference, name=ref0.name)
            dist = math.hypot(case.truth.x - ref.T_world_reference.x, case.truth.y - ref.T_world_reference.y)
            hyp = Hypotheses().plus(odo.estimate(None, case.query, Hypotheses()))
            for name, cfg in variants.items():
                key = (name, case.reference_id)
                if key not in prepared:
                    prepared[key] = compass.prepare(ref, cfg)
                t0 = time.process_time()
                est = compass.estimate(ref, case.query, hyp, cfg, prepared=prepared[key])
                tallies[name].add(est, case.truth, time.process_time() - t0, dist)
        print(f"\n== {directory}, references without depth (heading-only compass) ==")
        print(POSE_HEADER)
        for label, t in tallies.items():
            print(t.row(label))


def bench_pose_fit(n: int, overrides: list[str]) -> None:
    """The fitting set of the pose rules: ``n`` views 0–2 m from the apartment's reference, odometry σ 0.2 m / 10°.

    640×480 would be the scenarios' camera; these are the tests' 320×240 views with lighting changes (gain,
    gamma, noise, blur), rendered afresh (``numpy`` seed 7), so none of them is in a held-out scenario.
    ``overrides`` are ``name=value`` settings of :class:`CompassConfig` (e.g. ``pose_threshold_rad=0.005``).
    Prints the reliable rate, the share with a pose, the confidently wrong (> 3σ heading or pose NEES > 14.16),
    the poses' position error (median, p90) and their NEES (3 dof).
    """
    import cv2

    from factorloc import Pose2
    from factorloc.sim import DepthCamera, PinholeCamera, apartment, photo, render_camera, render_cloud_360, render_panorama

    cv2.setNumThreads(1)
    kw = _overrides(overrides)
    cfg = compass.CompassConfig(**kw)
    world = apartment()
    t_ref = Pose2(3.0, 2.2, 0.3)
    pano = render_panorama(world, t_ref, width_px=2048)
    cloud = render_cloud_360(world, t_ref, DepthCamera(stride_px=4), np.random.default_rng(1))
    ref = Reference(panorama=pano, cloud=cloud, T_world_reference=t_ref)
    pc = compass.prepare(ref, cfg)
    rng = np.random.default_rng(7)
    s_p, s_t = 0.2, math.radians(10.0)
    reliable = posed = wrong = made = 0
    perr, nees, ms = [], [], []
    while made < n:
        d, a = rng.uniform(0, 2), rng.uniform(-math.pi, math.pi)
        x, y = t_ref.x + d * math.cos(a), t_ref.y + d * math.sin(a)
        if not world.is_free(np.array([[x, y]]), 0.4)[0]:
            continue
        theta = rng.uniform(-math.pi, math.pi)
        cam = render_camera(world, Pose2(x, y, theta), PinholeCamera(width_px=320, height_px=240))
        gain, gamma = rng.uniform(0.6, 1.4), rng.uniform(0.75, 1.3)
        img = photo.photometric(cam.image_bgr, gain=gain, gamma=gamma, noise_sigma=4.0, blur_sigma_px=0.7, rng=rng)
        odo = Pose2(x + rng.normal(0, s_p), y + rng.normal(0, s_p), theta + rng.normal(0, s_t))
        hyp = Hypotheses((Estimate.pose("odometry", odo, s_p, s_p, s_t),))
        t0 = time.process_time()
        e = compass.estimate(ref, Query(images=(CameraImage(img, cam.hfov_rad),)), hyp, cfg, prepared=pc)
        ms.append(1e3 * (time.process_time() - t0))
        made += 1
        if not e.reliable:
            continue
        reliable += 1
        err = math.remainder(e.value("theta") - theta, 2 * math.pi)
        bad = abs(err) > 3.0 * e.sigma("theta")
        if e.measures("x"):
            posed += 1
            v = np.array([e.value("x") - x, e.value("y") - y, err])
            nees.append(float(v @ np.linalg.solve(e.covariance, v)))
            perr.append(math.hypot(v[0], v[1]))
            bad = bad or nees[-1] > 14.16
        wrong += bad
    print(f"\n== pose fitting set: {n} views, overrides {kw or 'none'} ==")
    if not perr:
        perr, nees = [math.nan], [math.nan]
    print(
        f"reliable {reliable / n:.0%}, with a pose {posed / n:.0%}, confidently wrong {wrong} "
        f"({wrong / n:.1%}); position error median {100 * np.median(perr):.1f} cm, p90 {100 * np.percentile(perr, 90):.1f} cm; "
        f"pose NEES mean {np.mean(nees):.2f}, median {np.median(nees):.2f}; compass ms median {np.median(ms):.1f}"
    )


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--queries", type=int, default=30, help="queries of the sample scenario (default: all 30)")
    parser.add_argument("--views", type=int, default=20, help="views per real panorama")
    parser.add_argument("--sim", type=int, default=0, help="also measure accuracy on N simulated queries per condition")
    parser.add_argument("--scenario", type=Path, default=None, help="also measure per-step CPU time and NEES on this scenario")
    parser.add_argument("--scenario-queries", type=int, default=300, help="queries of --scenario to run")
    parser.add_argument("--pose", type=Path, nargs="+", default=None, help="pose-from-bearings table on these scenarios")
    parser.add_argument("--same-spot", type=int, default=0, help="same-spot views per source (sim + real panoramas)")
    parser.add_argument("--pose-fit", type=int, default=0, help="the pose rules' fitting set: N simulated views")
    parser.add_argument(
        "--depth", choices=("cloud", "scan"), default="cloud", help="--pose: the references' depth (scan: cloud left out)"
    )
    parser.add_argument("--no-depth", type=Path, nargs="+", default=None, help="heading-only compass without depth on these")
    parser.add_argument(
        "--set",
        nargs="*",
        default=[],
        help="CompassConfig overrides name=value: --pose-fit, one variant beside --pose, or one variant each beside --no-depth",
    )
    args = parser.parse_args()
    if args.pose_fit:
        bench_pose_fit(args.pose_fit, args.set)
        return
    if args.pose or args.same_spot or args.no_depth:
        if args.no_depth:
            bench_no_depth(args.no_depth, args.scenario_queries, args.set)
        if args.pose:
            bench_pose(args.pose, args.scenario_queries, args.set, args.depth)
        if args.same_spot:
            bench_same_spot(args.same_spot)
        return
    if args.scenario is not None:
        bench_scenario(args.scenario, args.scenario_queries)
    if args.sim > 0:
        bench_sim_accuracy(args.sim)
    if (SAMPLE / "scenario.yaml").is_file():
        bench_sample(args.queries)
    else:
        print(f"(no sample scenario at {SAMPLE})")
    if PANORAMAS.is_dir():
        bench_real(args.views)
    else:
        print(f"(no real panoramas at {PANORAMAS})")


if __name__ == "__main__":
    main()

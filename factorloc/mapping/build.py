"""Build a pose graph of places from one run: :func:`build_map`.

The robot's run (a :class:`~factorloc.datasets.rosbag.LaserLog`: odometry and laser scans) becomes a graph of
*places* (keyframes), one every ``place_spacing_m`` of odometry path or ``place_turn_rad`` of rotation
(graph SLAM, Lu & Milios 1997; Grisetti et al., "A tutorial on graph-based SLAM", 2010):

* **consecutive places** are linked by the odometry (a between-factor whose σ is the
  :class:`~factorloc.odometry_model.OdometryModel`'s for the path between them) and by the ICP step
  (:func:`factorloc.estimators.icp.estimate`, seeded by that odometry; its global search, when it runs, stays
  in the window the odometry bounds: these links are the back end's known inliers) when its typed verdict is
  reliable, with its covariance;
* **loop closures** are proposed by pose proximity in the streaming estimate (iSAM2, Kaess et al. 2012): older
  places (at least ``loop_min_path_m`` of path behind) within ``loop_radius_m`` + 3σ of the new place's marginal
  position σ, facing the same way. Each is verified by the ICP step seeded with the graph's relative pose and its
  covariance (joint marginal of the two places): seeded only when that σ is below ``fallback_sigma_m``; else
  with the seed's covariance inflated by ``fallback_inflation`` and the step's global search in the window it
  bounds (or, beyond ``global_sigma_m``, without a seed). A reliable one is added with the step's covariance,
  robustified (Cauchy) in the streaming graph;
* **the back end** at the end is a batch optimization from the streaming estimate: GTSAM's graduated
  non-convexity (Yang et al., "Graduated non-convexity for robust spatial perception", RA-L 2020; truncated
  least squares, the odometry and consecutive-scan factors known inliers) so that a wrong closure is switched
  off instead of bending the map, or an M-estimator on the closures, or plain Levenberg–Marquardt.

Each scan's pose is its nearest place's (along the path) composed with its offset from that place: the ICP
step's alignment to it (seeded by the odometry since the place) fused with its alignment to the place on its
other side (``scan_places = 2``; each covariance × 2, as the scan's own error is common to both), or the
odometry when no alignment is reliable, with that offset's covariance;
:meth:`~factorloc.mapping.MapResult.scan_relative` gives the map's relative pose of any two scans with its
covariance from the joint marginal.
"""

from __future__ import annotations

import logging
import math
import time
from dataclasses import dataclass, replace

import numpy as np

from factorloc.datasets.rosbag import LaserLog
from factorloc.errors import InputError
from factorloc.estimators.base import Hypotheses
from factorloc.estimators.icp import IcpReference, estimate
from factorloc.gating import GatingConfig, fixes_full_pose
from factorloc.geometry import Pose2, rotate_covariance
from factorloc.mapping.config import MapConfig
from factorloc.mapping.result import Closure, MapResult, _adjoint, relative_covariance
from factorloc.types import Estimate

log = logging.getLogger(__name__)

__all__ = ["build_map", "select_places"]

_PRIOR_SIGMAS = np.array([1e-4, 1e-4, 1e-5])  # the first place anchors the map frame (m, m, rad)


@dataclass(frozen=True)
class _Link:
    """One between-factor: ``T_i⁻¹T_j`` measured, with its covariance (tangent at the measurement, body frame of j)."""

    kind: str  # "odometry", "scan" or "loop"
    i: int
    j: int
    measured: Pose2
    covariance: np.ndarray


def select_places(log_: LaserLog, config: MapConfig = MapConfig()) -> np.ndarray:
    """Indices of the scans that become places: the first usable scan, then one each ``place_spacing_m`` of
    odometry path or ``place_turn_rad`` of summed absolute rotation since the last place (scans with fewer than
    ``min_scan_points`` points, or outside the odometry's time span, never are)."""
    odom, scans = log_.odometry, log_.scans
    lo, hi = float(odom.stamps_s[0]), float(odom.stamps_s[-1])
    out: list[int] = []
    t_last = None
    for k, (t, s) in enumerate(zip(scans.stamps_s, scans.scans, strict=True)):
        if not (lo <= t <= hi) or len(s.points_m) < config.min_scan_points:
            continue
        if t_last is None:
            out.append(k)
            t_last = float(t)
            continue
        d, r = odom.distance_between(t_last, float(t))
        if d >= config.place_spacing_m or r >= config.place_turn_rad:
            out.append(k)
            t_last = float(t)
    return np.array(out, dtype=np.int64)


def _body_covariance(T_ref_query: Pose2, covariance_ref: np.ndarray) -> np.ndarray:
    """An ICP covariance of (x, y, θ) in the reference frame → GTSAM's tangent at the measurement (query body)."""
    return rotate_covariance(np.asarray(covariance_ref, dtype=np.float64), -T_ref_query.theta)


def _full_position(est: Estimate) -> bool:
    """A reliable full pose whose position is measured in both directions (not degenerate along a corridor)."""
    return fixes_full_pose(est, GatingConfig().undetermined_sigma_m)


def _noise(covariance: np.ndarray):  # noqa: ANN202 - gtsam has no stubs
    from factorloc.fusion.graph import noise_model

    return noise_model(covariance)


def _factor(link: _Link, robust: str | None, scale: float):  # noqa: ANN202
    import gtsam

    model = _noise(link.covariance)
    if robust == "huber":
        model = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(scale), model)
    elif robust == "cauchy":
        model = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(scale), model)
    return gtsam.BetweenFactorPose2(link.i, link.j, link.measured.to_gtsam(), model)


def _prior(pose: Pose2):  # noqa: ANN202
    import gtsam

    return gtsam.PriorFactorPose2(0, pose.to_gtsam(), gtsam.noiseModel.Diagonal.Sigmas(_PRIOR_SIGMAS, False))


def _largest_sigma(cov2: np.ndarray) -> float:
    return math.sqrt(max(float(np.linalg.eigvalsh(cov2)[-1]), 0.0))


def build_map(log_: LaserLog, config: MapConfig = MapConfig(), *, marginals: bool = True) -> MapResult:
    """Build the pose graph of places of one run and optimize it (see the module docstring).

    Parameters
    ----------
    log_
        The run: odometry and laser scans (robot frame = laser frame), e.g.
        :func:`~factorloc.datasets.rosbag.read_laser_log`.
    config
        :class:`~factorloc.mapping.MapConfig`.
    marginals
        Compute the marginal covariances of the final graph (places' covariances, the joint marginals of
        :meth:`MapResult.scan_relative`).

    Returns
    -------
    MapResult
        Places (map frame = the odometry frame at the first place), every scan's pose, the loop closures with
        their verdicts and back-end weights, counts and seconds.

    Raises
    ------
    InputError
        When ``log_`` is not a LaserLog or has fewer than two usable scans.
    """
    if not isinstance(log_, LaserLog):
        raise InputError(f"log must be a LaserLog, got {type(log_).__name__}")
    if not isinstance(config, MapConfig):
        raise InputError(f"config must be a MapConfig, got {type(config).__name__}")
    t_start = time.perf_counter()
    b = _Builder(log_, config)
    for j in range(1, len(b.idx)):
        b.add_place(j)
        if config.loop_max_candidates > 0 and j % config.loop_every == 0:
            b.close_loops(j)
    return b.finish(marginals, t_start)


class _Builder:
    """The streaming state of :func:`build_map`: places, prepared references, links, closures, iSAM2."""

    def __init__(self, log_: LaserLog, config: MapConfig) -> None:
        import gtsam

        self.log, self.config = log_, config
        odom, scans = log_.odometry, log_.scans
        self.idx = select_places(log_, config)
        if len(self.idx) < 2:
            raise InputError(f"log has {len(self.idx)} usable scan(s) for places; need >= 2")
        self.stamps = scans.stamps_s[self.idx]
        self.points = [scans.scans[k].points_m for k in self.idx]
        self.path = np.asarray(odom.path_length_m(self.stamps), dtype=np.float64)
        icp = config.icp
        self.seeded_cfg = replace(icp, global_init=replace(icp.global_init, enabled=False))
        self.fallback_cfg = replace(icp, global_init=replace(icp.global_init, widen=False))
        self.links: list[_Link] = []
        self.closures: list[Closure] = []
        self.robust_stream = None if config.robust == "none" else ("huber" if config.robust == "huber" else "cauchy")
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(0.01)
        params.relinearizeSkip = 1
        self.isam = gtsam.ISAM2(params)
        self.T0 = odom.pose_at(float(self.stamps[0]))
        graph = gtsam.NonlinearFactorGraph()
        graph.add(_prior(self.T0))
        values = gtsam.Values()
        values.insert(0, self.T0.to_gtsam())
        self.isam.update(graph, values)
        self.poses = np.zeros((len(self.idx), 3))
        self.poses[0] = self.T0.as_array()
        self.seconds = {"icp": 0.0, "isam": 0.0}
        self.n_scan = self.n_odom_only = 0
        t0 = time.perf_counter()
        self.refs = [IcpReference(p, Pose2(0.0, 0.0, 0.0), icp) for p in self.points]
        self.seconds["icp"] += time.perf_counter() - t0

    def add_place(self, j: int) -> None:
        """Link place ``j`` to place ``j − 1``: odometry, and the ICP step's pose when reliable."""
        import gtsam

        odom, cfg = self.log.odometry, self.config
        t_i, t_j = float(self.stamps[j - 1]), float(self.stamps[j])
        delta = odom.between(t_i, t_j)
        d, r = odom.distance_between(t_i, t_j)
        o = cfg.odometry.odometry(delta, d, r)
        odo_cov = np.diag([o.sigma_x_m**2, o.sigma_y_m**2, o.sigma_theta_rad**2])
        new = [_Link("odometry", j - 1, j, delta, odo_cov)]
        t0 = time.perf_counter()
        seed = Estimate.pose("odometry", delta, covariance=odo_cov)
        est = estimate(self.refs[j - 1], self.points[j], Hypotheses((seed,)), self.fallback_cfg)  # never widened
        self.seconds["icp"] += time.perf_counter() - t0
        step = delta
        if _full_position(est):
            T_ij = Pose2.from_array(est.values)
            new.append(_Link("scan", j - 1, j, T_ij, _body_covariance(T_ij, est.covariance)))
            step = T_ij
            self.n_scan += 1
        else:
            self.n_odom_only += 1
        guess = Pose2.from_array(self.poses[j - 1]) * step
        self.poses[j] = guess.as_array()
        t0 = time.perf_counter()
        g = gtsam.NonlinearFactorGraph()
        for ln in new:
            g.add(_factor(ln, None, cfg.robust_scale))
        v = gtsam.Values()
        v.insert(j, guess.to_gtsam())
        self.isam.update(g, v)
        self.links.extend(new)
        self.seconds["isam"] += time.perf_counter() - t0

    def _candidates(self, j: int, cov_j: np.ndarray) -> np.ndarray:
        """Older places near place ``j`` in the current estimate, nearest first."""
        cfg, poses = self.config, self.poses
        older = np.flatnonzero(self.path[:j] <= self.path[j] - cfg.loop_min_path_m)
        if len(older) == 0:
            return older
        radius = min(cfg.loop_radius_m + 3.0 * _largest_sigma(cov_j[:2, :2]), cfg.loop_max_search_m)
        dist = np.hypot(poses[older, 0] - poses[j, 0], poses[older, 1] - poses[j, 1])
        dth = np.abs(np.remainder(poses[older, 2] - poses[j, 2] + math.pi, 2.0 * math.pi) - math.pi)
        ok = (dist <= radius) & (dth <= cfg.loop_max_heading_rad + 3.0 * math.sqrt(max(float(cov_j[2, 2]), 0.0)))
        return older[ok][np.argsort(dist[ok], kind="stable")][: cfg.loop_max_candidates]

    def close_loops(self, j: int) -> None:
        """Propose loop closures for place ``j``, verify each with the ICP step, add the reliable ones."""
        import gtsam

        cfg = self.config
        t0 = time.perf_counter()
        self.poses[: j + 1] = gtsam.utilities.extractPose2(self.isam.calculateEstimate())[: j + 1]
        cov_j = self.isam.marginalCovariance(j)
        self.seconds["isam"] += time.perf_counter() - t0
        loops: list[_Link] = []
        Tj = Pose2.from_array(self.poses[j])
        for i in (int(k) for k in self._candidates(j, cov_j)):
            Ti = Pose2.from_array(self.poses[i])
            t0 = time.perf_counter()
            jm = self.isam.jointMarginalCovariance(gtsam.KeyVector([i, j]))
            joint = np.block([[jm.at(i, i), jm.at(i, j)], [jm.at(j, i), jm.at(j, j)]])
            self.seconds["isam"] += time.perf_counter() - t0
            seed_T = Ti.between(Tj)
            rel_ref = rotate_covariance(relative_covariance(Ti, Tj, joint), seed_T.theta)  # → the older place's frame
            sigma = _largest_sigma(rel_ref[:2, :2])
            t0 = time.perf_counter()
            if sigma > cfg.global_sigma_m:
                est = estimate(self.refs[i], self.points[j], Hypotheses(), cfg.icp)
            else:
                if sigma >= cfg.fallback_sigma_m:
                    seed_cov = cfg.fallback_inflation**2 * rel_ref
                    icp = self.fallback_cfg if cfg.fallback_inflation > 1.0 else cfg.icp
                else:
                    seed_cov, icp = rel_ref, self.seeded_cfg
                hyp = Hypotheses((Estimate.pose("map", seed_T, covariance=seed_cov),))
                est = estimate(self.refs[i], self.points[j], hyp, icp)
            self.seconds["icp"] += time.perf_counter() - t0
            link = self._record_closure(i, j, est, seed_T, sigma, "proximity")
            if link is not None:
                loops.append(link)
        if loops:
            t0 = time.perf_counter()
            g = gtsam.NonlinearFactorGraph()
            for ln in loops:
                g.add(_factor(ln, self.robust_stream, cfg.robust_scale))
            self.isam.update(g, gtsam.Values())
            self.isam.update()
            self.links.extend(loops)
            self.seconds["isam"] += time.perf_counter() - t0

    def _record_closure(self, i: int, j: int, est: Estimate, seed: Pose2, seed_sigma_m: float, proposed_by: str) -> _Link | None:
        """Keep the ICP step's answer to a proposed closure (i, j) in ``closures``; its loop link when reliable.

        A partial answer (e.g. the heading alone) measures no pose: recorded at the seed, unreliable."""
        ok = _full_position(est)
        T_ij = Pose2.from_array(est.values) if est.kind == "full" else seed
        used_global = bool(est.diagnostics.get("used_global_init", False))
        self.closures.append(
            Closure(
                i, j, T_ij, np.array(est.covariance), ok, est.reason, est.checks, used_global, seed, seed_sigma_m,
                proposed_by=proposed_by,
            )
        )  # fmt: skip
        return _Link("loop", i, j, T_ij, _body_covariance(T_ij, est.covariance)) if ok else None

    def recognize_loops(self) -> None:
        """Loop closures proposed by place recognition (``recognition_every``), verified, added before the batch."""
        import gtsam

        from factorloc.places import Place, PlaceMap, PlaceRecognizer
        from factorloc.types import Query, Reference, Scan

        cfg = self.config
        t0 = time.perf_counter()
        poses = gtsam.utilities.extractPose2(self.isam.calculateEstimate())
        ids = [f"p{k:05d}" for k in range(len(self.idx))]
        pm = PlaceMap([Place(ids[k], Reference(scan=Scan(self.points[k])), Pose2.from_array(poses[k])) for k in range(len(ids))])
        recognizer = PlaceRecognizer(pm, cfg.recognition)
        proposed = {(c.place_from, c.place_to) for c in self.closures}
        seed_cov = np.diag([cfg.recognition_sigma_m**2, cfg.recognition_sigma_m**2, cfg.recognition_sigma_rad**2])
        self.seconds["recognition"] = time.perf_counter() - t0
        loops: list[_Link] = []
        for j in range(cfg.recognition_every, len(ids), cfg.recognition_every):
            t0 = time.perf_counter()
            older = self.path[j] - cfg.loop_min_path_m
            found = recognizer.candidates(
                Query(scan=Scan(self.points[j]), id=f"q{j}"),
                cfg.recognition_k,
                exclude=lambda pid, older=older: self.path[int(pid[1:])] > older,
            )
            self.seconds["recognition"] += time.perf_counter() - t0
            for cand in found:
                i = int(cand.place_id[1:])
                if (i, j) in proposed or cand.T_place_query is None:
                    continue
                proposed.add((i, j))
                t0 = time.perf_counter()
                hyp = Hypotheses((Estimate.pose("recognition", cand.T_place_query, covariance=seed_cov),))
                est = estimate(self.refs[i], self.points[j], hyp, self.fallback_cfg)
                self.seconds["icp"] += time.perf_counter() - t0
                link = self._record_closure(i, j, est, cand.T_place_query, cfg.recognition_sigma_m, "recognition")
                if link is not None:
                    loops.append(link)
        self.links.extend(loops)
        self.n_recognized = len(loops)

    def finish(self, marginals: bool, t_start: float) -> MapResult:
        """The batch back end, the marginals, every scan's pose."""
        import gtsam

        n = len(self.idx)
        self.n_recognized = 0
        if self.config.recognition_every > 0:
            self.recognize_loops()
        t0 = time.perf_counter()
        final_graph, result, weights = _batch(self.links, self.T0, self.isam.calculateEstimate(), self.config)
        sec_batch = time.perf_counter() - t0
        poses = gtsam.utilities.extractPose2(result)
        closures = _with_weights(self.closures, [w for ln, w in zip(self.links, weights, strict=True) if ln.kind == "loop"])
        t0 = time.perf_counter()
        marg = gtsam.Marginals(final_graph, result) if marginals else None
        covs = np.full((n, 3, 3), np.nan)
        if marg is not None:
            for k in range(n):
                covs[k] = rotate_covariance(marg.marginalCovariance(k), float(poses[k, 2]))
        sec_marg = time.perf_counter() - t0
        t0 = time.perf_counter()

        scan_places, offsets, offset_covs, n_refined = _scan_offsets(
            self.log, self.idx, self.path, self.config, self.refs, self.seeded_cfg, poses, _consecutive_covariances(self.links)
        )
        sec_scans = time.perf_counter() - t0
        scan_poses = np.array(
            [(Pose2.from_array(poses[p]) * Pose2.from_array(offsets[m])).as_array() for m, p in enumerate(scan_places)]
        )
        stats = {
            "places": n,
            "scan_factors": self.n_scan,
            "odometry_only_links": self.n_odom_only,
            "closures_proposed": len(closures),
            "closures_reliable": sum(c.reliable for c in closures),
            "closures_accepted": sum(c.accepted for c in closures),
            "scans_refined": n_refined,
            "closures_recognized": self.n_recognized,
            "seconds_recognition": self.seconds.get("recognition", 0.0),
            "back_end": self.config.robust,
            "seconds_icp": self.seconds["icp"],
            "seconds_isam": self.seconds["isam"],
            "seconds_batch": sec_batch,
            "seconds_marginals": sec_marg,
            "seconds_scans": sec_scans,
            "seconds_total": time.perf_counter() - t_start,
        }
        log.info("map of %d places, %d closures accepted of %d proposed", n, stats["closures_accepted"], len(closures))
        return MapResult(
            place_ids=np.arange(n),
            place_stamps_s=np.asarray(self.stamps, dtype=np.float64),
            place_scan_indices=self.idx,
            place_poses=poses,
            place_covariances=covs,
            place_points=tuple(self.points),
            scan_stamps_s=np.asarray(self.log.scans.stamps_s, dtype=np.float64),
            scan_poses=scan_poses,
            scan_places=scan_places,
            scan_offsets=offsets,
            scan_offset_covariances=offset_covs,
            closures=tuple(closures),
            stats=stats,
            marginals=marg,
        )


def _batch(links: list[_Link], T0: Pose2, initial, config: MapConfig):  # noqa: ANN001, ANN202
    """The final batch optimization: (the graph the marginals use, the solution, each link's weight)."""
    import gtsam

    lm = gtsam.LevenbergMarquardtParams()
    lm.setMaxIterations(100)
    lm.setRelativeErrorTol(1e-8)
    lm.setAbsoluteErrorTol(1e-10)
    if config.robust == "gnc" and any(ln.kind == "loop" for ln in links):
        graph = gtsam.NonlinearFactorGraph()
        graph.add(_prior(T0))
        for ln in links:
            graph.add(_factor(ln, None, config.robust_scale))
        p = gtsam.GncLMParams(lm)
        p.setLossType(gtsam.GncLossType.TLS)
        p.setKnownInliers([k + 1 for k, ln in enumerate(links) if ln.kind != "loop"] + [0])
        opt = gtsam.GncLMOptimizer(graph, initial, p)
        opt.setInlierCostThresholdsAtProbability(config.gnc_inlier_probability)
        result = opt.optimize()
        w = np.asarray(opt.getWeights(), dtype=np.float64)[1:]
        kept = gtsam.NonlinearFactorGraph()
        kept.add(_prior(T0))
        for ln, wk in zip(links, w, strict=True):
            if wk >= 0.5:
                kept.add(_factor(ln, None, config.robust_scale))
        result = gtsam.LevenbergMarquardtOptimizer(kept, result, lm).optimize()
        return kept, result, [float(x) for x in w]
    robust = config.robust if config.robust in ("huber", "cauchy") else None
    graph = gtsam.NonlinearFactorGraph()
    graph.add(_prior(T0))
    for ln in links:
        graph.add(_factor(ln, robust if ln.kind == "loop" else None, config.robust_scale))
    result = gtsam.LevenbergMarquardtOptimizer(graph, initial, lm).optimize()
    weights = []
    for k, ln in enumerate(links):
        f = graph.at(k + 1)
        if ln.kind == "loop" and robust is not None:
            weights.append(_mestimator_weight(robust, config.robust_scale, f, result))
        else:
            weights.append(1.0)
    return graph, result, weights


def _mestimator_weight(kind: str, scale: float, factor, values) -> float:  # noqa: ANN001
    """The IRLS weight of a robustified between-factor at the solution (from its whitened residual)."""
    import gtsam

    gauss = gtsam.BetweenFactorPose2(factor.keys()[0], factor.keys()[1], factor.measured(), factor.noiseModel().noise())
    r = math.sqrt(2.0 * gauss.error(values))
    if kind == "huber":
        return 1.0 if r <= scale else scale / r
    return 1.0 / (1.0 + (r / scale) ** 2)


def _with_weights(closures: list[Closure], loop_weights: list[float]) -> list[Closure]:
    """The back end's weight on each added (reliable) closure, in the order they were added."""
    out, k = [], 0
    for c in closures:
        if c.reliable:
            out.append(Closure(**{**c.__dict__, "weight": loop_weights[k]}))
            k += 1
        else:
            out.append(c)
    return out


def _consecutive_covariances(links: list[_Link]) -> dict[int, np.ndarray]:
    """For each pair of consecutive places (i, i + 1): the covariance of ``T_i⁻¹T_{i+1}`` from the links between
    them alone (odometry and, when reliable, ICP; information summed), keyed by i. The graph's own relative
    covariance is at most this (loop closures only add information): a conservative, cheap stand-in for the joint
    marginal (which costs ~20 ms per pair on the Intel map)."""
    info: dict[int, np.ndarray] = {}
    for ln in links:
        if ln.kind != "loop" and ln.j == ln.i + 1:
            info[ln.i] = info.get(ln.i, np.zeros((3, 3))) + np.linalg.inv(ln.covariance)
    return {i: np.linalg.inv(m) for i, m in info.items()}


def _scan_sides(log_: LaserLog, idx: np.ndarray, path: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per scan: its place (the nearest along the odometry path), the place on its other side along the path
    (-1 when there is none), and the scans' clipped stamps."""
    odom, scans = log_.odometry, log_.scans
    lo, hi = float(odom.stamps_s[0]), float(odom.stamps_s[-1])
    ts = np.clip(scans.stamps_s, lo, hi)
    s_path = np.asarray(odom.path_length_m(ts), dtype=np.float64)
    after = np.clip(np.searchsorted(idx, np.arange(len(ts)), side="left"), 0, len(idx) - 1)
    before = np.clip(after - 1, 0, len(idx) - 1)
    # a scan at or after place `after` with index == idx[after] hangs from it; else choose the nearer in path
    near_after = np.abs(path[after] - s_path) <= np.abs(s_path - path[before])
    places = np.where(near_after, after, before)
    other = np.where(near_after, before, after)
    # only a place on the other side of the scan in time is a second neighbour
    scan_k = np.arange(len(ts))
    between_them = (idx[np.minimum(places, other)] < scan_k) & (scan_k < idx[np.maximum(places, other)])
    other = np.where((other != places) & between_them, other, -1)
    return places.astype(np.int64), other.astype(np.int64), ts


def _align_scan(  # noqa: ANN202
    ref: IcpReference,
    pts: np.ndarray,
    delta: Pose2,
    odo_cov: np.ndarray,
    icp_cfg,  # noqa: ANN001
):
    """The ICP step's offset of a scan from a place (seeded by the odometry offset) and its covariance (tangent at
    the offset), or None when the answer is not a reliable full pose."""
    est = estimate(ref, pts, Hypotheses((Estimate.pose("odometry", delta, covariance=odo_cov),)), icp_cfg)
    if not _full_position(est):
        return None
    T = Pose2.from_array(est.values)
    return T, _body_covariance(T, est.covariance)


def _oriented(cov_i_next: np.ndarray, T_p_q: Pose2, forward: bool) -> np.ndarray:
    """The covariance of ``T_p⁻¹T_q`` (tangent at it) from that of the consecutive pair's forward relative pose:
    itself when q follows p; else that of the inverse, ``Ad(X) Σ Ad(X)ᵀ`` with ``X = T_q⁻¹T_p``."""
    if forward:
        return cov_i_next
    A = _adjoint(T_p_q.inverse())
    return A @ cov_i_next @ A.T


def _fuse_offsets(
    first: tuple[Pose2, np.ndarray], second: tuple[Pose2, np.ndarray], T_p_q: Pose2, cov_p_q: np.ndarray
) -> tuple[Pose2, np.ndarray]:
    """One scan's offset from place p, fused from its alignment to p and its alignment to place q.

    ``second`` (offset from q) is carried into p's frame through the map's ``T_p⁻¹T_q`` (covariance ``cov_p_q``,
    tangent at it): ``δ' = T_pq·δ_q``, ``Σ' = Ad(δ_q⁻¹) Σ_pq Ad(δ_q⁻¹)ᵀ + Σ_q``. The two share the scan's own
    error, so each enters with its covariance × 2 (covariance intersection with equal weights, consistent
    whatever their correlation; the tracker's rule for the factors of one query), and they are fused as two
    measurements of one pose in the tangent at the first: ``ξ = Log(δ_p⁻¹δ')``, ``K = Σ_p(Σ_p + Σ')⁻¹``,
    ``δ = δ_p·Exp(Kξ)``, ``Σ = 2(I − K)Σ_p``.
    """
    import gtsam

    d_p, cov_p = first
    d_q, cov_q = second
    carried = T_p_q * d_q
    B = _adjoint(d_q.inverse())
    cov_c = B @ cov_p_q @ B.T + cov_q
    xi = np.asarray(gtsam.Pose2.Logmap(d_p.between(carried).to_gtsam()), dtype=np.float64)
    K = cov_p @ np.linalg.inv(cov_p + cov_c)
    fused = d_p * Pose2.from_gtsam(gtsam.Pose2.Expmap(K @ xi))
    cov = 2.0 * (np.eye(3) - K) @ cov_p
    return fused, 0.5 * (cov + cov.T)


def _scan_offsets(  # noqa: ANN202, PLR0913
    log_: LaserLog,
    idx: np.ndarray,
    path: np.ndarray,
    config: MapConfig,
    refs: list[IcpReference],
    icp_cfg,
    place_poses: np.ndarray,
    consecutive: dict[int, np.ndarray],
):
    """Each scan's place (the nearest along the path), its offset from that place and that offset's covariance
    (tangent at the offset); and how many were refined by ICP.

    The offset is the ICP step's (seeded by the odometry) when ``refine_scans`` and reliable, else the odometry's;
    with ``scan_places = 2`` a scan between two places is aligned to both and the two offsets fused
    (:func:`_fuse_offsets`; ``consecutive`` from :func:`_consecutive_covariances` gives the covariance of
    ``T_p⁻¹T_q``)."""
    odom, scans = log_.odometry, log_.scans
    places, other, ts = _scan_sides(log_, idx, path)
    offsets = np.zeros((len(ts), 3))
    covs = np.zeros((len(ts), 3, 3))
    model = config.odometry
    place_t = np.clip(scans.stamps_s[idx], float(odom.stamps_s[0]), float(odom.stamps_s[-1]))
    n_refined = 0

    def offset_from(k: int, m: int, align: bool) -> tuple[tuple[Pose2, np.ndarray], tuple[Pose2, np.ndarray] | None]:
        delta = odom.between(float(place_t[k]), float(ts[m]))
        d, r = odom.distance_between(float(place_t[k]), float(ts[m]))
        o = model.odometry(delta, d, r)
        odo_cov = np.diag([o.sigma_x_m**2, o.sigma_y_m**2, o.sigma_theta_rad**2])
        icp = _align_scan(refs[k], scans.scans[m].points_m, delta, odo_cov, icp_cfg) if align else None
        return (delta, odo_cov), icp

    for m in range(len(ts)):
        p = int(places[m])
        if idx[p] == m:
            continue
        refine = config.refine_scans and len(scans.scans[m].points_m) >= config.min_scan_points
        odo, icp = offset_from(p, m, refine)
        best = icp if icp is not None else odo
        q = int(other[m])
        if refine and icp is not None and config.scan_places == 2 and q >= 0:
            T_pq = Pose2.from_array(place_poses[p]).between(Pose2.from_array(place_poses[q]))
            _, icp_q = offset_from(q, m, True)
            if icp_q is not None:
                best = _fuse_offsets(icp, icp_q, T_pq, _oriented(consecutive[min(p, q)], T_pq, p < q))
        offsets[m] = best[0].as_array()
        covs[m] = best[1]
        n_refined += icp is not None
    return places, offsets, covs, n_refined

"""The relations benchmark of Kümmerle et al. (2009) on 2D laser logs (its tables:
:mod:`factorloc.evaluation.relations_report`, re-exported here).

Each ground-truth relation ``(t1, t2, T_12)`` becomes one localization
problem: the reference is the scan at ``t1`` (reference frame = robot frame
at ``t1``, so ``T_world_reference`` is the identity), the query is the scan
at ``t2`` with the odometry's relative motion ``odom(t1)⁻¹·odom(t2)`` and
σ grown with the distance travelled (:meth:`factorloc.types.Odometry.from_distance`).
The error of a method is ``T_12⁻¹ · T_estimated`` — its translation norm
(m) and the absolute angle (deg), averaged as mean ± std like the paper.

Relations are *local* when the odometry path between ``t1`` and ``t2`` is
shorter than ``local_threshold_m`` (the odometry is a good seed), *loop*
otherwise (the robot came back: only a global initialization helps).

Methods compared side by side in one run, all seeded by the same odometry:

* ``ours`` — :func:`factorloc.localize` with the odometry and ICP steps;
  reliable when the localization fused at least one reliable estimate;
* ``ours_icp`` — the ICP step's own estimate in that same run, with its own
  covariance and reliability verdict (what the estimator is responsible for,
  without the odometry it is fused with); requested together with ``ours``.
  A degenerate ICP result (heading-only, or a position unknown along a
  corridor) vouches for no full position: its row is unreliable and shows the
  pose ICP slid to;
* ``odometry`` — the odometry alone (reliable per the odometry step's σ test);
* ``open3d_p2p`` / ``open3d_p2plane`` — Open3D's ICP
  (:mod:`factorloc.registration.open3d_peer`), reliable when its fitness
  reaches ``IcpConfig.reliability.min_fitness``, with the odometry's σ (it has none of its own).

A result is *confidently wrong* when it is reliable and its position error
exceeds the 3σ ellipse (squared Mahalanobis distance above the 2-DoF χ²
quantile of 0.9973) or its heading error exceeds 3σθ. Where the relations were
rounded to a matcher's grid (:func:`~factorloc.evaluation.relations_lattice.truth_rounding`:
MIT CSAIL's local relations, 5 cm and 0.25°), the rounding's covariance is added
to the estimate's for that test and for the NEES; the verdict against the
relation taken as exact is kept in the diagnostics (``confidently_wrong_exact``,
``icp_nees_position_exact``).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
from scipy.stats import chi2

from factorloc.config import Config
from factorloc.datasets.rosbag import LaserLog
from factorloc.errors import DatasetError, InputError
from factorloc.estimators.icp import IcpStep
from factorloc.estimators.odometry import OdometryStep
from factorloc.estimators.odometry import estimate as odometry_estimate
from factorloc.evaluation.relations_data import Relations, read_relations
from factorloc.evaluation.relations_lattice import TruthRounding
from factorloc.evaluation.relations_lattice import truth_rounding as find_truth_rounding
from factorloc.evaluation.relations_report import METHODS, RelationResult, format_table, summarize, unrecovered_breakdown
from factorloc.gating import GatingConfig, measures_position
from factorloc.geometry import Pose2
from factorloc.odometry_model import OdometryModel
from factorloc.parallel import Executor, SerialExecutor, TaskFailure
from factorloc.parallel.base import failure_of
from factorloc.pipeline import Localizer
from factorloc.registration.icp2d import prepare_target
from factorloc.registration.open3d_peer import open3d_icp
from factorloc.types import Estimate, Query, Reference, Scan, StepStatus

__all__ = [
    "METHODS",
    "OdometryModel",
    "RelationResult",
    "Relations",
    "format_table",
    "read_relations",
    "relations_benchmark",
    "summarize",
    "unrecovered_breakdown",
]

_CHI2_3SIGMA_2DOF = float(chi2.ppf(0.9973002039367398, 2))


def _position_not_measured(est: Estimate) -> bool:
    """A degenerate ICP result: heading-only, or a pose whose position is unknown along a corridor."""
    return not measures_position(est, GatingConfig().undetermined_sigma_m)


def _errors(true: Pose2, est: Pose2) -> tuple[float, float]:
    e = true.between(est)
    return math.hypot(e.x, e.y), abs(math.degrees(e.theta))


def _position_error_world(true: Pose2, est: Pose2) -> np.ndarray:
    return np.array([est.x - true.x, est.y - true.y])


def _wrong(true: Pose2, est: Pose2, cov: np.ndarray, truth_cov: np.ndarray | None = None) -> tuple[bool, float]:
    """(beyond 3σ in position or heading, squared Mahalanobis position error) of ``est`` against ``true``, with
    ``cov`` (the estimate's: 3×3 (x, y, θ), or 2×2 for a position-only estimate, whose heading is not judged) plus
    ``truth_cov`` (the relation's rounding, position isotropic; None: exact)."""
    c = np.asarray(cov, dtype=float)
    if c.shape == (2, 2):
        c = np.block([[c, np.zeros((2, 1))], [np.zeros((1, 2)), np.full((1, 1), math.inf)]])
    if truth_cov is not None:
        c = c + truth_cov
    e = _position_error_world(true, est)
    if not np.all(np.isfinite(c[:2, :2])):
        return False, math.nan
    d2 = float(e @ np.linalg.solve(c[:2, :2], e))
    st = math.sqrt(float(c[2, 2])) if math.isfinite(float(c[2, 2])) else math.inf
    dth = abs(math.remainder(est.theta - true.theta, 2 * math.pi))
    return (d2 > _CHI2_3SIGMA_2DOF) or (dth > 3.0 * st), d2


def relations_config(base: Config | None = None) -> Config:
    """The configuration ``ours`` runs with on the laser logs.

    ``base`` (default :class:`Config`) with two changes. (It used to also
    raise ``icp.covariance.bias_rmse_ratio`` to 0.75 for real laser scans; that is now
    the library default, see :class:`~factorloc.estimators.icp.IcpConfig`.)

    * ``odometry.max_sigma_position_m = 1.0``: with the :class:`OdometryModel`
      σ (20 % of the path) the odometry stays a reliable seed up to a 5 m
      path, the local/loop boundary of the benchmark.
    * ``odometry.max_sigma_heading_rad = 0.55``: the model's σθ is 1.6× the
      earlier model's on a long path (0.08 vs 0.05 rad/m), and the heading
      limit grows with it so that about the same local relations keep a
      reliable seed.
    """
    base = base or Config()
    return replace(
        base,
        odometry=replace(base.odometry, max_sigma_position_m=1.0, max_sigma_heading_rad=0.55),
    )


@dataclass(frozen=True, eq=False)
class _RelationInput:
    """One relation's inputs, cut from the log on the driver (a worker gets two scans, not the whole log)."""

    index: int
    t1: float
    t2: float
    true: Pose2
    ref_scan: Scan
    qry_scan: Scan
    seed: Pose2
    distance_m: float
    rotation_rad: float
    truth_cov: np.ndarray | None = None  # the relation's rounding (3×3), None: exact


@dataclass(frozen=True, eq=False)
class _RelationsBatch:
    """What every chunk of a :func:`relations_benchmark` needs."""

    methods: tuple[str, ...]
    config: Config
    local_threshold_m: float
    open3d_max_correspondence_m: float
    model: OdometryModel
    warmed: list[bool] = field(default_factory=list)  # filled by the process running the chunks (its own copy)


def _relations_chunk(chunk: Sequence[_RelationInput], batch: _RelationsBatch) -> list[list[RelationResult] | TaskFailure]:
    """The rows of each relation of one chunk; a relation that raises gives a :class:`TaskFailure`. The first
    chunk a process runs starts with its first relation once untimed (start-up costs: numba's cache, Open3D's
    warm-up)."""
    warm_up = [] if batch.warmed else list(chunk[:1])
    batch.warmed.append(True)
    out: list[list[RelationResult] | TaskFailure] = []
    for k, item in enumerate([*warm_up, *chunk]):
        try:
            rows = _relation_rows(item, batch)
        except Exception as exc:  # counted and reported by index; the batch goes on
            rows = failure_of(exc)
        if k >= len(warm_up):
            out.append(rows)
    return out


def _relation_rows(item: _RelationInput, batch: _RelationsBatch) -> list[RelationResult]:
    """Every method of ``batch.methods`` on one relation."""
    methods, config, i = batch.methods, batch.config, item.index
    icp_cfg = config.icp
    true, ref_scan, qry_scan, seed = item.true, item.ref_scan, item.qry_scan, item.seed
    t1, t2 = item.t1, item.t2
    kind = "local" if item.distance_m < batch.local_threshold_m else "loop"
    odom = batch.model.odometry(seed, item.distance_m, item.rotation_rad)
    odom_cov = np.diag([odom.sigma_x_m**2, odom.sigma_y_m**2, odom.sigma_theta_rad**2])
    open3d_max_correspondence_m = batch.open3d_max_correspondence_m
    out: list[RelationResult] = []
    for m in methods:
        if m == "ours_icp":
            continue  # produced with "ours"
        if m == "odometry":
            t0 = time.perf_counter()
            est = odometry_estimate(odom, config.odometry)
            dt = time.perf_counter() - t0
            et, er = _errors(true, seed)
            wrong, d2 = _wrong(true, seed, odom_cov, item.truth_cov)
            out.append(RelationResult(m, i, kind, et, er, est.reliable, est.reliable and wrong, dt, d2))
        elif m == "ours":
            t0 = time.perf_counter()
            reference = Reference(scan=ref_scan, name=f"t1={t1:.6f}")
            localizer = Localizer(reference, config, steps=[OdometryStep(config.odometry), IcpStep(icp_cfg)])
            loc = localizer.localize(Query(scan=qry_scan, odometry=odom, id=f"t2={t2:.6f}"))
            dt = time.perf_counter() - t0
            icp_rep = loc.step("icp")
            icp_seconds = localizer.prepare_seconds.get("icp", 0.0) + icp_rep.seconds
            reliable = any(r.status is StepStatus.FUSED for r in loc.steps) and loc.determined
            et, er = _errors(true, loc.pose)
            wrong, d2 = _wrong(true, loc.pose, loc.covariance, item.truth_cov) if reliable else (False, math.nan)
            icp_est = icp_rep.estimate
            diag = {
                "truth_rounded": item.truth_cov is not None,
                "confidently_wrong_exact": reliable and _wrong(true, loc.pose, loc.covariance)[0],
                "icp_status": icp_rep.status.value,
                "icp_reason": icp_rep.reason,
                "icp_failed_checks": ()
                if icp_rep.estimate is None
                else tuple(c.code for c in icp_rep.estimate.checks if not c.passed),
                "icp_seconds": icp_seconds,
                "localize_seconds": dt,
            }
            nees_icp = math.nan
            # degenerate geometry (heading-only, or a position unknown along a corridor): the step vouches for no
            # full position; its row shows the pose ICP converged to (slid along the corridor), unreliable
            no_full_position = icp_est is not None and _position_not_measured(icp_est)
            if icp_est is not None:
                # the reference sits at the origin of the world here; a position-only estimate (heading unconstrained)
                # carries the pose ICP converged to in its diagnostics too
                T_icp = Pose2.from_array(icp_est.diagnostics["T_reference_query"])
                eti, eri = _errors(true, T_icp)
                diag.update(
                    icp_error_translation_m=eti,
                    icp_error_rotation_deg=eri,
                    icp_heading_error_rad=abs(math.remainder(T_icp.theta - true.theta, 2 * math.pi)),
                    icp_reliable=icp_est.reliable and not no_full_position,
                )
            if no_full_position:
                diag.update(icp_no_full_position=True)
            elif icp_est is not None:
                wrong_i, nees_icp = _wrong(true, T_icp, icp_est.covariance, item.truth_cov)
                wrong_exact_i, nees_exact = _wrong(true, T_icp, icp_est.covariance)
                diag.update(
                    icp_nees_position=nees_icp,
                    icp_nees_position_exact=nees_exact,
                    icp_confidently_wrong_exact=icp_est.reliable and wrong_exact_i,
                    icp_covariance_position=icp_est.covariance[:2, :2].tolist(),
                    icp_sigma_theta_rad=icp_est.sigma("theta") if icp_est.measures("theta") else math.inf,
                    **{
                        k: v
                        for k, v in icp_est.diagnostics.items()
                        if k in ("fitness", "rmse_m", "chamfer_m", "violation", "global_score", "rival_score")
                    },
                )
            used_global = bool(icp_est is not None and icp_est.diagnostics.get("used_global_init", False))
            out.append(RelationResult(m, i, kind, et, er, reliable, reliable and wrong, icp_seconds, d2, used_global, diag))
            if "ours_icp" in methods:
                if no_full_position:
                    out.append(RelationResult("ours_icp", i, kind, eti, eri, False, False, icp_seconds, math.nan, False, diag))
                elif icp_est is None:
                    out.append(RelationResult("ours_icp", i, kind, math.inf, math.inf, False, False, icp_seconds))
                else:
                    out.append(
                        RelationResult(
                            "ours_icp",
                            i,
                            kind,
                            eti,
                            eri,
                            icp_est.reliable,
                            icp_est.reliable and wrong_i,
                            icp_seconds,
                            nees_icp,
                            used_global,
                            diag,
                        )
                    )
        else:
            method = "point_to_point" if m == "open3d_p2p" else "point_to_plane"
            t0 = time.perf_counter()
            normals = prepare_target(ref_scan.points_m, icp_cfg.alignment.icp).normals if method == "point_to_plane" else None
            res = open3d_icp(
                ref_scan.points_m,
                qry_scan.points_m,
                seed,
                method=method,
                target_normals=normals,
                max_correspondence_m=open3d_max_correspondence_m,
            )
            dt = time.perf_counter() - t0
            est = res.T_target_source
            reliable = res.fitness >= icp_cfg.reliability.min_fitness
            et, er = _errors(true, est)
            wrong, d2 = _wrong(true, est, odom_cov, item.truth_cov)
            out.append(RelationResult(m, i, kind, et, er, reliable, reliable and wrong, dt, d2, False, {"fitness": res.fitness}))
    return out


def relations_benchmark(
    log: LaserLog,
    relations: Relations,
    *,
    methods: Sequence[str] = METHODS,
    config: Config | None = None,
    local_threshold_m: float = 5.0,
    tolerance_s: float = 2e-3,
    open3d_max_correspondence_m: float = 0.5,
    odometry_model: OdometryModel | None = None,
    executor: Executor | None = None,
    chunk_size: int | None = None,
    progress: Callable[[int, int], None] | None = None,
    on_failure: Callable[[int, str], None] | None = None,
    truth_rounding: TruthRounding | Literal["auto"] | None = "auto",
) -> list[RelationResult]:
    """Run every method of ``methods`` on every relation; one :class:`RelationResult` per (method, relation).

        Parameters
        ----------
        log
            The laser log (scans and odometry).
        relations
            Its ground-truth relations.
        methods
            Any of :data:`METHODS`.
        config
            The configuration of ``ours`` (and the fitness threshold of the Open3D peers);
            default :func:`relations_config`.
        local_threshold_m
            Odometry path length separating local from loop relations.
        tolerance_s
            Largest difference between a relation time and its scan's stamp.
        open3d_max_correspondence_m
            Open3D's correspondence distance.
        odometry_model
            How the odometry σ grows with the motion (default :class:`OdometryModel`).
        executor
            Where the relations run (:mod:`factorloc.parallel`; default in this process), in chunks of
            ``chunk_size`` relations (default: the executor's choice; in process, one chunk). The rows do not
            depend on the executor, except the measured times.
        progress
            Called as ``progress(done, total)`` with relation counts as chunks finish.
        on_failure
            Called as ``on_failure(relation_index, error)`` for a relation that raised (its rows are left out);
            without it, such a relation raises a :class:`~factorloc.errors.DatasetError` once the batch is done.
        truth_rounding
            The relations' own rounding to a matcher's grid, added to every method's covariance when judging
            (confidently wrong, NEES): ``"auto"`` (default) finds it from the relations and the odometry
            (:func:`~factorloc.evaluation.relations_lattice.truth_rounding`; none on a log whose relations are not
            gridded), None takes the relations as exact, or a given
            :class:`~factorloc.evaluation.relations_lattice.TruthRounding` of these relations.

        Notes
        -----
        Summarize with :func:`summarize` (the table) and :func:`format_table`. The first relation is run
        once untimed before the timed pass (start-up costs: numba cache load, Open3D warm-up): the first relation of
    every chunk, on an executor that splits them.
    """
    methods = list(methods)
    if "ours_icp" in methods and "ours" not in methods:
        methods.append("ours")
    bad = [m for m in methods if m not in METHODS]
    if bad:
        raise InputError(f"unknown method(s) {bad}; known: {list(METHODS)}")
    config = config or relations_config()
    if truth_rounding == "auto":
        truth_rounding = find_truth_rounding(relations, log.odometry)
    elif truth_rounding is not None and not isinstance(truth_rounding, TruthRounding):
        raise InputError(f"truth_rounding must be 'auto', None or a TruthRounding, got {truth_rounding!r}")
    rounded = None if truth_rounding is None else truth_rounding.rounded()
    if rounded is not None and len(rounded) not in (0, len(relations)):
        raise InputError(f"truth_rounding is for {len(rounded)} relations, not these {len(relations)}")
    batch = _RelationsBatch(
        tuple(methods), config, float(local_threshold_m), float(open3d_max_correspondence_m), odometry_model or OdometryModel()
    )
    items = []
    for i in range(len(relations)):
        t1, t2 = float(relations.t1_s[i]), float(relations.t2_s[i])
        dist, rot = log.odometry.distance_between(t1, t2)
        items.append(
            _RelationInput(
                i,
                t1,
                t2,
                Pose2.from_array(relations.poses[i]),
                log.scans.at(t1, tolerance_s),
                log.scans.at(t2, tolerance_s),
                log.odometry.between(t1, t2),
                dist,
                rot,
                None if rounded is None or not len(rounded) or not rounded[i] else truth_rounding.covariance(i),
            )
        )
    ex = executor if executor is not None else SerialExecutor()
    cb = None if progress is None else (lambda done, total, failed: progress(done, total))
    out: list[RelationResult] = []
    failed: list[tuple[int, str]] = []
    for item, rows in zip(items, ex.map_chunks(_relations_chunk, items, chunk_size, shared=batch, progress=cb), strict=True):
        if isinstance(rows, TaskFailure):
            failed.append((item.index, rows.error))
            if on_failure is not None:
                on_failure(item.index, rows.error)
            continue
        out.extend(rows)
    if failed and on_failure is None:
        raise DatasetError(f"{len(failed)} relation(s) failed: " + "; ".join(f"relation {i}: {e}" for i, e in failed[:5]))
    return out

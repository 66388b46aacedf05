"""The relations metric (Kümmerle et al., "On measuring the accuracy of SLAM algorithms", Autonomous Robots 2009)
on a built map (:func:`factorloc.mapping.build_map`): for every ground-truth relation ``(t1, t2, T_12)`` the map's
``T(t1)⁻¹·T(t2)`` of the two scans against ``T_12`` — translation norm (m) and absolute rotation (deg) — as
:class:`~factorloc.evaluation.relations_report.RelationResult` rows of method ``"map"`` (summarize them with
:func:`~factorloc.evaluation.relations_report.summarize` and :func:`~factorloc.evaluation.relations_report.format_table`
beside the pairwise methods of :func:`~factorloc.evaluation.relations.relations_benchmark`).

A relation is *beyond 3σ* (the table's ``conf.wrong`` column: every map relation is reported reliable) when
its full error ``ξ = Log(T̂_12⁻¹·T_12)`` has a squared Mahalanobis distance under the map's own covariance of that
relative pose (:meth:`~factorloc.mapping.MapResult.scan_relative`: the joint marginal of the two places and the
odometry offsets of the scans) above the 3-DoF χ² quantile of 0.9973; where the relations were rounded to a
matcher's grid (MIT CSAIL's local relations), the rounding's covariance is added
(:func:`~factorloc.evaluation.relations_lattice.truth_rounding`, as in the pairwise benchmark; the verdict against
the relation taken as exact is ``diagnostics["beyond_3sigma_exact"]``).
"""

from __future__ import annotations

import math
import time
from typing import Literal

import numpy as np
from scipy.stats import chi2

from factorloc.datasets.rosbag import LaserLog
from factorloc.evaluation.relations_data import Relations
from factorloc.evaluation.relations_lattice import TruthRounding
from factorloc.evaluation.relations_lattice import truth_rounding as find_truth_rounding
from factorloc.evaluation.relations_report import RelationResult
from factorloc.geometry import Pose2
from factorloc.mapping import MapResult

__all__ = ["CHI2_3SIGMA_3DOF", "map_relations"]

#: The 3-DoF χ² quantile of probability 0.9973 (the "3σ" region of a full (x, y, θ) error), 14.16.
CHI2_3SIGMA_3DOF = float(chi2.ppf(0.9973002039367398, 3))


def _log_se2(T: Pose2) -> np.ndarray:
    """SE(2) logarithm (x, y, θ) in GTSAM's convention."""
    import gtsam

    return np.asarray(gtsam.Pose2.Logmap(T.to_gtsam()), dtype=np.float64)


def map_relations(
    result: MapResult,
    relations: Relations,
    log: LaserLog,
    *,
    method: str = "map",
    local_threshold_m: float = 5.0,
    tolerance_s: float = 2e-3,
    covariance: bool = True,
    truth_rounding: TruthRounding | Literal["auto"] | None = "auto",
) -> list[RelationResult]:
    """One :class:`RelationResult` per relation for the map's trajectory of every scan.

    ``log`` is the run the map was built from (its scans locate the relation times; its odometry path length
    sets ``kind``: ``"local"`` below ``local_threshold_m``, else ``"loop"``, as the pairwise benchmark).
    ``covariance=False`` skips the 3σ test (``nees_position`` NaN, nothing beyond 3σ). ``seconds`` is the time of
    the covariance query. ``truth_rounding`` as in :func:`~factorloc.evaluation.relations.relations_benchmark`.
    """
    if truth_rounding == "auto":
        truth_rounding = find_truth_rounding(relations, log.odometry)
    rounded = np.zeros(0, dtype=bool) if truth_rounding is None else truth_rounding.rounded()
    out: list[RelationResult] = []
    for i in range(len(relations)):
        t1, t2 = float(relations.t1_s[i]), float(relations.t2_s[i])
        a = log.scans.index_at(t1, tolerance_s)
        b = log.scans.index_at(t2, tolerance_s)
        true = Pose2.from_array(relations.poses[i])
        dist, _ = log.odometry.distance_between(t1, t2)
        kind = "local" if dist < local_threshold_m else "loop"
        t0 = time.perf_counter()
        if covariance:
            T, cov = result.scan_relative(a, b)
            xi = _log_se2(T.between(true))
            d2_exact = _mahalanobis2(xi, cov)
            d2 = d2_exact if not (len(rounded) and rounded[i]) else _mahalanobis2(xi, cov + truth_rounding.covariance(i))
        else:
            T = Pose2.from_array(result.scan_poses[a]).between(Pose2.from_array(result.scan_poses[b]))
            d2 = d2_exact = math.nan
        dt = time.perf_counter() - t0
        e = true.between(T)
        et, er = math.hypot(e.x, e.y), abs(math.degrees(e.theta))
        wrong = bool(covariance and d2 > CHI2_3SIGMA_3DOF)
        diag = {"mahalanobis2": d2, "beyond_3sigma_exact": bool(covariance and d2_exact > CHI2_3SIGMA_3DOF)}
        out.append(RelationResult(method, i, kind, et, er, True, wrong, dt, d2, False, diag))
    return out


def _mahalanobis2(xi: np.ndarray, cov: np.ndarray) -> float:
    try:
        return float(xi @ np.linalg.solve(cov, xi))
    except np.linalg.LinAlgError:
        return math.inf

"""A globally consistent ground truth of a laser log from its relations, to judge any pair of its scans.

The relations of Kümmerle et al. ("On measuring the accuracy of SLAM algorithms", Autonomous Robots 2009) give the
true relative pose of chosen pairs of scans only. A benchmark that pairs scans the relations do not — a query
against every place of a map taken along the log (:mod:`factorloc.evaluation.places`) — needs the truth between
any two times. :func:`log_truth` fits one trajectory to all the relations at once (a pose graph over the relation
stamps, solved by GTSAM Levenberg–Marquardt):

* a **between factor per relation**, σ ``relation_sigma`` (2 cm, 2 cm, 0.005 rad by default: the relations are
  precise to about a centimetre, :mod:`~factorloc.evaluation.relations_consistency`) under a Huber kernel (k =
  1.345), so that the few inconsistent relations of a log do not bend the rest;
* a **weak odometry chain** between consecutive stamps, σ ``link_sigma`` (0.5 m, 0.5 m, 0.1 rad per link), which
  only fixes the gauge of the parts of the log the relations do not connect — the truth between two such parts
  is the odometry's, not the relations', so :meth:`LogTruth.relative` refuses pairs whose ends lie in different
  connected components of the relation graph;
* a prior on the first stamp at its odometry pose (the world frame is the odometry frame there).

A time between stamps is posed by the nearest stamp composed with the odometry between the two, within
``max_gap_s`` (1 s by default; farther, :meth:`LogTruth.pose_at` returns None: the odometry's drift over longer
gaps would enter the truth). :attr:`LogTruth.residual_m` — the translational residual of every relation against
the fitted trajectory — says how consistent the relations are with one trajectory (measured on the shipped logs,
``docs/places.md``: median 0.66 / 0.03 / 0.04 cm, 99th percentile 27 / 3.9 / 3.2 cm on Intel / ACES / MIT CSAIL).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from factorloc.datasets.rosbag import OdometryTrack
from factorloc.errors import InputError
from factorloc.evaluation.relations_data import Relations
from factorloc.geometry import Pose2

__all__ = ["LogTruth", "log_truth"]

#: Relation σ (x m, y m, θ rad) of :func:`log_truth`'s between factors.
RELATION_SIGMA = (0.02, 0.02, 0.005)
#: σ (x m, y m, θ rad) of the weak odometry link between consecutive stamps (it fixes the gauge of unrelated parts).
LINK_SIGMA = (0.5, 0.5, 0.1)
#: Huber threshold (in σ) of the relation factors.
HUBER_K = 1.345


@dataclass(frozen=True, eq=False)
class LogTruth:
    """A trajectory fitted to a log's relations (:func:`log_truth`).

    ``stamps_s`` (N,) the relation stamps (s, sorted, one per distinct stamp within the tolerance); ``poses`` (N, 3)
    the fitted robot poses ``[x_m, y_m, θ_rad]`` in the world frame (the odometry frame at the first stamp);
    ``component`` (N,) the connected component of the relation graph each stamp belongs to; ``residual_m`` (R,) the
    translational residual (m) of every relation against the fitted trajectory; ``odometry`` the log's odometry
    (poses times between stamps); ``max_gap_s`` how far from a stamp a time may be posed; ``sigma`` (3,) the σ (x m,
    y m, θ rad) a judge adds per end of a pair for the truth's own error (the relations' σ, ``relation_sigma``).
    """

    stamps_s: np.ndarray
    poses: np.ndarray
    component: np.ndarray
    residual_m: np.ndarray
    odometry: OdometryTrack
    max_gap_s: float
    sigma: np.ndarray

    def _nearest(self, t_s: float) -> int | None:
        t = float(t_s)
        if not math.isfinite(t):
            raise InputError(f"time must be finite, got {t_s!r}")
        i = int(np.searchsorted(self.stamps_s, t))
        best = None
        for j in (i - 1, i):
            if 0 <= j < len(self.stamps_s) and (best is None or abs(self.stamps_s[j] - t) < abs(self.stamps_s[best] - t)):
                best = j
        if best is None or abs(self.stamps_s[best] - t) > self.max_gap_s:
            return None
        return best

    def pose_at(self, t_s: float) -> Pose2 | None:
        """The true robot pose (world frame) at ``t_s``: the nearest stamp's fitted pose composed with the odometry
        from it; None when no stamp lies within ``max_gap_s``."""
        j = self._nearest(t_s)
        if j is None:
            return None
        return Pose2.from_array(self.poses[j]).compose(self.odometry.between(float(self.stamps_s[j]), float(t_s)))

    def relative(self, t_a_s: float, t_b_s: float) -> Pose2 | None:
        """The true pose of the robot at ``t_b_s`` in its frame at ``t_a_s``; None when either time lies farther than
        ``max_gap_s`` from every stamp or the two lie in different components of the relation graph (their
        relative pose would be the odometry's)."""
        ja, jb = self._nearest(t_a_s), self._nearest(t_b_s)
        if ja is None or jb is None or self.component[ja] != self.component[jb]:
            return None
        a, b = self.pose_at(t_a_s), self.pose_at(t_b_s)
        assert a is not None and b is not None  # both have a stamp within max_gap_s
        return a.between(b)


def _components(k1: np.ndarray, k2: np.ndarray, n: int) -> np.ndarray:
    """Connected-component labels (the smallest member index) of ``n`` nodes joined by the edges ``k1[i]–k2[i]``."""
    parent = list(range(n))

    def find(a: int) -> int:
        while parent[a] != a:
            parent[a] = parent[parent[a]]
            a = parent[a]
        return a

    for a, b in zip(k1.tolist(), k2.tolist(), strict=True):
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    return np.array([find(i) for i in range(n)], dtype=np.int64)


def _sigmas(name: str, value: tuple[float, float, float]) -> np.ndarray:
    s = np.asarray(value, dtype=np.float64)
    if s.shape != (3,) or not np.all(np.isfinite(s)) or np.any(s <= 0):
        raise InputError(f"{name} must be three finite σ > 0 (x m, y m, θ rad), got {value!r}")
    return s


def log_truth(
    relations: Relations,
    odometry: OdometryTrack,
    *,
    tolerance_s: float = 1e-3,
    max_gap_s: float = 1.0,
    relation_sigma: tuple[float, float, float] = RELATION_SIGMA,
    link_sigma: tuple[float, float, float] = LINK_SIGMA,
) -> LogTruth:
    """Fit one trajectory to every relation of a log (the module docstring): the ground truth between any two times.

    ``relations`` the log's relations (all of them: a subset connects less); ``odometry`` its odometry, which must
    cover every relation stamp; ``tolerance_s`` stamps closer than this are one node. Raises
    :class:`~factorloc.errors.InputError` on no relations, non-finite relations or a stamp outside the odometry.
    """
    import gtsam

    if not isinstance(relations, Relations) or len(relations) == 0:
        raise InputError("log_truth needs at least one relation")
    if not isinstance(odometry, OdometryTrack):
        raise InputError(f"odometry must be an OdometryTrack, got {type(odometry).__name__}")
    poses = np.asarray(relations.poses, dtype=np.float64)
    t1, t2 = np.asarray(relations.t1_s, dtype=np.float64), np.asarray(relations.t2_s, dtype=np.float64)
    if not (np.all(np.isfinite(poses)) and np.all(np.isfinite(t1)) and np.all(np.isfinite(t2))):
        raise InputError("relations contain NaN or infinite stamps or poses")
    if not (tolerance_s > 0 and math.isfinite(tolerance_s)) or not (max_gap_s >= 0 and math.isfinite(max_gap_s)):
        raise InputError(f"tolerance_s must be > 0 and max_gap_s >= 0, got {tolerance_s!r}, {max_gap_s!r}")
    rel_s, link_s = _sigmas("relation_sigma", relation_sigma), _sigmas("link_sigma", link_sigma)
    keys = np.round(np.concatenate([t1, t2]) / tolerance_s).astype(np.int64)
    uniq, first = np.unique(keys, return_index=True)
    stamps = np.concatenate([t1, t2])[first]
    k1, k2 = np.searchsorted(uniq, keys[: len(t1)]), np.searchsorted(uniq, keys[len(t1) :])
    init = [odometry.pose_at(float(t)) for t in stamps]  # raises on a stamp outside the odometry

    graph = gtsam.NonlinearFactorGraph()
    robust = gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(HUBER_K), gtsam.noiseModel.Diagonal.Sigmas(rel_s)
    )
    for a, b, p in zip(k1.tolist(), k2.tolist(), poses, strict=True):
        graph.add(gtsam.BetweenFactorPose2(a, b, gtsam.Pose2(*p), robust))
    link = gtsam.noiseModel.Diagonal.Sigmas(link_s)
    for j in range(len(stamps) - 1):
        graph.add(gtsam.BetweenFactorPose2(j, j + 1, init[j].between(init[j + 1]).to_gtsam(), link))
    graph.add(gtsam.PriorFactorPose2(0, init[0].to_gtsam(), gtsam.noiseModel.Isotropic.Sigma(3, 1e-3)))
    values = gtsam.Values()
    for j, p in enumerate(init):
        values.insert(j, p.to_gtsam())
    fitted = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    out = np.array([[q.x(), q.y(), q.theta()] for q in (fitted.atPose2(j) for j in range(len(stamps)))])
    residual = np.empty(len(t1))
    for i, (a, b, p) in enumerate(zip(k1.tolist(), k2.tolist(), poses, strict=True)):
        d = fitted.atPose2(a).between(fitted.atPose2(b))
        residual[i] = math.hypot(d.x() - p[0], d.y() - p[1])
    for arr in (stamps, out, residual):
        arr.setflags(write=False)
    comp = _components(k1, k2, len(stamps))
    comp.setflags(write=False)
    rel_s.setflags(write=False)
    return LogTruth(stamps, out, comp, residual, odometry, float(max_gap_s), rel_s)

"""How precise is a log's ground truth? The relations' own consistency around their cycles.

The relations of Kümmerle et al. ("On measuring the accuracy of SLAM algorithms", Autonomous Robots 2009) were
obtained by matching scans by hand; every method's error on a log is measured against them, so their own error is
part of every figure (and the part no statistic of a scan pair shows: the ICP covariance's floors,
:mod:`factorloc.estimators.icp.covariance`). Where three relations close a cycle — ``(a, b)``, ``(b, c)`` and
``(a, c)`` — the composition ``T_ac⁻¹ · T_ab · T_bc`` is the identity for the true poses, so its size measures the
relations' error without any estimate:

* :attr:`RelationsConsistency.closures` — the closure ``Log``-free error (x, y in m, θ in rad) of every triangle;
* :attr:`RelationsConsistency.sigma_position_m` — the per-relation, per-axis position σ those closures imply
  (first order, three independent errors per closure, lever arms ignored: ``σ = median|c_xy| / (1.1774 √3)``, the
  Rayleigh median, robust to a few wrong relations), and :attr:`~RelationsConsistency.sigma_heading_rad` likewise
  (half-normal median 0.6745 σ);
* :attr:`RelationsConsistency.implied_mean_error_m` — the mean translational error, ``σ √(π/2)``, that an
  *exact* trajectory would show on relations with that noise: the floor of the benchmark's metric on such
  relations;
* :attr:`RelationsConsistency.best_fit_mean_error_m` — the mean error on the cycle relations of the trajectory
  fitted to those relations alone (GTSAM Levenberg–Marquardt, Huber kernel): what no estimate can go far below
  on them, whatever its accuracy.

Only relations that lie on a cycle are seen (on these logs they involve a loop relation: they say how precise the
loop relations are, not the short local ones).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from factorloc.errors import InputError
from factorloc.evaluation.relations import Relations

__all__ = ["RelationsConsistency", "relations_consistency"]

#: Median of a Rayleigh variable over its σ, √(2 ln 2).
_RAYLEIGH_MEDIAN = math.sqrt(2.0 * math.log(2.0))
#: Median of a half-normal variable over its σ (the 0.75 normal quantile).
_HALF_NORMAL_MEDIAN = 0.6744897501960817


@dataclass(frozen=True, eq=False)
class RelationsConsistency:
    """The relations' own consistency around their triangles (see the module docstring).

    ``triangles`` (T, 3) holds the indices ``(ab, bc, ac)`` into the relations of each cycle, ``closures`` (T, 3)
    the closure ``T_ac⁻¹ · T_ab · T_bc`` as (x m, y m, θ rad); ``members`` the sorted indices of the relations on
    at least one triangle. The σ and mean errors are NaN when there is no triangle.
    """

    n_relations: int
    triangles: np.ndarray
    closures: np.ndarray
    members: np.ndarray
    sigma_position_m: float
    sigma_heading_rad: float
    implied_mean_error_m: float
    best_fit_mean_error_m: float
    best_fit_mean_error_rad: float

    @property
    def closure_mean_m(self) -> float:
        """Mean translational size of the triangle closures (m); NaN without triangles."""
        return float(np.hypot(self.closures[:, 0], self.closures[:, 1]).mean()) if len(self.closures) else math.nan

    def summary(self) -> str:
        """One line for a report (cm and degrees)."""
        if not len(self.triangles):
            return f"{self.n_relations} relations, no triangle: their consistency cannot be measured"
        return (
            f"{len(self.triangles)} triangles over {len(self.members)} of {self.n_relations} relations: closure "
            f"{100 * self.closure_mean_m:.2f} cm mean; implied per-relation σ {100 * self.sigma_position_m:.2f} cm "
            f"per axis, {math.degrees(self.sigma_heading_rad):.3f} deg (an exact trajectory would err "
            f"{100 * self.implied_mean_error_m:.2f} cm on such relations); the trajectory fitted to those relations "
            f"alone errs {100 * self.best_fit_mean_error_m:.2f} cm / {math.degrees(self.best_fit_mean_error_rad):.3f} deg "
            f"on them"
        )


def _matrix(p: np.ndarray) -> np.ndarray:
    """(…, 3) poses (x, y, θ) as (…, 3, 3) homogeneous matrices."""
    c, s = np.cos(p[..., 2]), np.sin(p[..., 2])
    out = np.zeros(p.shape[:-1] + (3, 3))
    out[..., 0, 0], out[..., 0, 1], out[..., 1, 0], out[..., 1, 1] = c, -s, s, c
    out[..., 0, 2], out[..., 1, 2], out[..., 2, 2] = p[..., 0], p[..., 1], 1.0
    return out


def _pose_of(m: np.ndarray) -> np.ndarray:
    """(…, 3, 3) homogeneous matrices as (…, 3) poses (x, y, θ)."""
    return np.stack([m[..., 0, 2], m[..., 1, 2], np.arctan2(m[..., 1, 0], m[..., 0, 0])], axis=-1)


def _stamp_keys(t_s: np.ndarray, tolerance_s: float) -> np.ndarray:
    """Integer keys of the stamps: stamps within ``tolerance_s`` of each other share a key."""
    return np.round(np.asarray(t_s, dtype=np.float64) / tolerance_s).astype(np.int64)


def _find_triangles(k1: np.ndarray, k2: np.ndarray) -> np.ndarray:
    """(T, 3) indices ``(ab, bc, ac)`` of relations whose ends close a cycle ``a → b → c`` (first listing of a
    repeated pair)."""
    index: dict[tuple[int, int], int] = {}
    starts: dict[int, list[int]] = {}
    for i, (a, b) in enumerate(zip(k1.tolist(), k2.tolist(), strict=True)):
        if a == b or (a, b) in index:
            continue
        index[(a, b)] = i
        starts.setdefault(a, []).append(i)
    out = []
    for (a, c), i_ac in index.items():
        for i_ab in starts.get(a, ()):
            b = int(k2[i_ab])
            i_bc = index.get((b, c))
            if b != c and i_bc is not None:
                out.append((i_ab, i_bc, i_ac))
    return np.array(out, dtype=np.int64).reshape(-1, 3)


def _best_fit(k1: np.ndarray, k2: np.ndarray, poses: np.ndarray, members: np.ndarray) -> tuple[float, float]:
    """Mean translational (m) and rotational (rad) error on ``members`` of the trajectory fitted to them alone."""
    import gtsam

    nodes = {s: i for i, s in enumerate(sorted(set(k1[members].tolist()) | set(k2[members].tolist())))}
    graph = gtsam.NonlinearFactorGraph()
    base = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.01, 0.01, math.radians(0.2)]))
    robust = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Huber.Create(1.0), base)
    mats = _matrix(poses)
    # initial values by walking the relations from each component's first node; a weak prior fixes its gauge
    adjacency: dict[int, list[tuple[int, np.ndarray]]] = {}
    for i in members.tolist():
        a, b = nodes[int(k1[i])], nodes[int(k2[i])]
        adjacency.setdefault(a, []).append((b, mats[i]))
        adjacency.setdefault(b, []).append((a, np.linalg.inv(mats[i])))
        graph.add(gtsam.BetweenFactorPose2(a, b, gtsam.Pose2(*poses[i]), robust))
    world: dict[int, np.ndarray] = {}
    for start in range(len(nodes)):
        if start in world:
            continue
        world[start] = np.eye(3)
        graph.add(gtsam.PriorFactorPose2(start, gtsam.Pose2(), gtsam.noiseModel.Isotropic.Sigma(3, 1e3)))
        stack = [start]
        while stack:
            u = stack.pop()
            for v, m in adjacency[u]:
                if v not in world:
                    world[v] = world[u] @ m
                    stack.append(v)
    values = gtsam.Values()
    for n, m in world.items():
        values.insert(n, gtsam.Pose2(*_pose_of(m)))
    fitted = gtsam.LevenbergMarquardtOptimizer(graph, values).optimize()
    rel = [fitted.atPose2(nodes[int(k1[i])]).between(fitted.atPose2(nodes[int(k2[i])])) for i in members.tolist()]
    est = np.array([(r.x(), r.y(), r.theta()) for r in rel])
    err = _pose_of(np.linalg.inv(mats[members]) @ _matrix(est))
    return float(np.hypot(err[:, 0], err[:, 1]).mean()), float(np.abs(err[:, 2]).mean())


def relations_consistency(relations: Relations, *, tolerance_s: float = 1e-3) -> RelationsConsistency:
    """The triangles of ``relations`` and what their closures say of the relations' error (module docstring).

    Stamps within ``tolerance_s`` (s) are the same pose (the relations name scans to the millisecond).
    """
    if not (math.isfinite(tolerance_s) and tolerance_s > 0.0):
        raise InputError(f"tolerance_s must be a positive number of seconds, got {tolerance_s!r}")
    poses = np.asarray(relations.poses, dtype=np.float64)
    if not np.all(np.isfinite(poses)):
        raise InputError("the relations hold a non-finite pose")
    k1, k2 = _stamp_keys(relations.t1_s, tolerance_s), _stamp_keys(relations.t2_s, tolerance_s)
    tri = _find_triangles(k1, k2)
    nan = math.nan
    if not len(tri):
        empty = np.zeros((0, 3))
        return RelationsConsistency(len(relations), tri, empty, np.zeros(0, np.int64), nan, nan, nan, nan, nan)
    m = _matrix(poses)
    closures = _pose_of(np.linalg.inv(m[tri[:, 2]]) @ m[tri[:, 0]] @ m[tri[:, 1]])
    members = np.unique(tri)
    # first order: a closure is the sum of its three relations' errors
    sigma_xy = float(np.median(np.hypot(closures[:, 0], closures[:, 1]))) / (_RAYLEIGH_MEDIAN * math.sqrt(3.0))
    sigma_th = float(np.median(np.abs(closures[:, 2]))) / (_HALF_NORMAL_MEDIAN * math.sqrt(3.0))
    fit_m, fit_rad = _best_fit(k1, k2, poses, members)
    return RelationsConsistency(
        n_relations=len(relations),
        triangles=tri,
        closures=closures,
        members=members,
        sigma_position_m=sigma_xy,
        sigma_heading_rad=sigma_th,
        implied_mean_error_m=sigma_xy * math.sqrt(math.pi / 2.0),
        best_fit_mean_error_m=fit_m,
        best_fit_mean_error_rad=fit_rad,
    )

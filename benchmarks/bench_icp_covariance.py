"""Covariance candidates for the ICP step, measured on the seeded local relations of the real laser logs.

For every local relation (path < 5 m) of each log, the ICP step's seeded attempt is run as the relations
benchmark seeds it (odometry with :class:`~factorloc.evaluation.relations.OdometryModel` σ); over its reliable
solutions the script prints the position NEES (2 dof) under the covariance without the floor (Censi + the
correlated term, as before issue 14) and under the candidates
that read a per-pair noise level from the pair itself (all rejected, see ``docs/calibration/icp.md``):

* ``sandwich k`` — the residual sandwich clustered over k consecutive correspondences,
  ``H⁻¹ (Σ_g s_g s_gᵀ) H⁻¹`` with ``s_g = Σ_{i∈g} wᵢ rᵢ Jᵢ``;
* ``surfaces σ_s`` — an unknown range offset of σ_s per wall segment (consecutive correspondences with close
  points and normals), ``σ_s² H⁻¹ (Σ_g u_g u_gᵀ) H⁻¹`` with ``u_g = Σ_{i∈g} wᵢ Jᵢ``, plus Censi's white term;
* ``split-half`` — the disagreement of the query's even and odd beams aligned apart, ``Δᵀ (4Σ)⁻¹ Δ`` (its
  mean is what the NEES would be if the error were the beams' own);
* and the Spearman correlation of the NEES with the fit's RMSE.

Usage::

    .venv/bin/python benchmarks/bench_icp_covariance.py                 # Intel, ACES, MIT CSAIL (~2 min)
    .venv/bin/python benchmarks/bench_icp_covariance.py --every 3 mit-csail
"""

from __future__ import annotations

import argparse
import math
from dataclasses import replace
from pathlib import Path

import numpy as np

from factorloc.datasets.rosbag import read_laser_log
from factorloc.estimators.base import Hypotheses
from factorloc.estimators.icp import IcpReference
from factorloc.estimators.icp.candidates import QueryScan, Seeds, kernel, seeded_attempt
from factorloc.estimators.odometry import estimate as odometry_estimate
from factorloc.evaluation.folds import LOGS
from factorloc.evaluation.relations import OdometryModel, read_relations, relations_config
from factorloc.geometry import Pose2
from factorloc.registration.icp2d import align

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "laser"


def _segments(q: np.ndarray, n: np.ndarray, gap_m: float = 0.25, angle_rad: float = math.radians(30)) -> np.ndarray:
    """Group index of each correspondence: consecutive points closer than ``gap_m`` with normals within ``angle_rad``."""
    g = np.zeros(len(q), dtype=np.int64)
    for i in range(1, len(q)):
        new = np.hypot(*(q[i] - q[i - 1])) > gap_m or abs(float(n[i] @ n[i - 1])) < math.cos(angle_rad)
        g[i] = g[i - 1] + int(new)
    return g


def _nees(e: np.ndarray, c: np.ndarray) -> float:
    return float(e @ np.linalg.solve(c[:2, :2], e))


def measure(name: str, every: int, data: Path) -> dict[str, list[float]]:
    cfg = relations_config()
    # the covariance before the floor and the weak-direction term (what these candidates were measured against)
    icp = replace(cfg.icp, covariance=replace(cfg.icp.covariance, sigma_floor_m=0.001, sigma_floor_rad=0.001, weak_exponent=1.0))
    model = OdometryModel()
    log = read_laser_log(data / f"{name}.sort.bag")
    rel = read_relations(data / f"{name}.relations")
    out: dict[str, list[float]] = {k: [] for k in ("nees", "rmse", "sandwich", "surfaces", "split")}
    for i in range(0, len(rel), every):
        t1, t2 = float(rel.t1_s[i]), float(rel.t2_s[i])
        dist, rot = log.odometry.distance_between(t1, t2)
        if dist >= 5.0:
            continue
        hyp = Hypotheses().plus(odometry_estimate(model.odometry(log.odometry.between(t1, t2), dist, rot), cfg.odometry))
        if not hyp.estimates:
            continue
        ref = log.scans.at(t1, 2e-3).points_m
        qry = np.asarray(log.scans.at(t2, 2e-3).points_m, dtype=np.float64)
        prep = IcpReference(ref, Pose2(), icp)
        sol = seeded_attempt(prep, QueryScan(qry, icp), Seeds(hyp.position(), hyp.heading()), icp)
        if not sol.reliable:
            continue
        r, T = sol.result, sol.T_reference_query
        truth = Pose2.from_array(rel.poses[i])
        e = np.array([T.x - truth.x, T.y - truth.y])
        out["nees"].append(_nees(e, sol.covariance))
        out["rmse"].append(r.rmse_m)
        h_inv = np.linalg.inv(r.hessian)
        J, w, res = np.asarray(r.jacobians), np.asarray(r.weights), np.asarray(r.residuals_m)
        s = np.add.reduceat(w[:, None] * res[:, None] * J, np.arange(0, len(w), 10), axis=0)
        out["sandwich"].append(_nees(e, h_inv @ (s.T @ s) @ h_inv + 1e-6 * np.eye(3)))
        # the correspondences' aligned query points and target normals, for the wall segments
        aligned = T.transform_points(qry)
        d, j = prep.target.tree.query(aligned, 1)
        sel = np.flatnonzero((np.asarray(d) < icp.alignment.icp.min_correspondence_m) & (prep.target.quality[j] >= 0.5))
        white = h_inv @ ((J * (w * w * (np.asarray(r.variances_m2) + res * res))[:, None]).T @ J) @ h_inv
        if len(sel) == len(w):
            g = _segments(aligned[sel], prep.target.normals[np.asarray(j)[sel]])
            u = np.zeros((int(g.max()) + 1, 3))
            np.add.at(u, g, w[:, None] * J)
            out["surfaces"].append(_nees(e, 0.01**2 * h_inv @ (u.T @ u) @ h_inv + white + 1e-6 * np.eye(3)))
        k = kernel(icp)
        a = align(prep.target, qry[0::2], T, icp.alignment.icp, k, 0.2).T_target_source
        b = align(prep.target, qry[1::2], T, icp.alignment.icp, k, 0.2).T_target_source
        delta = np.array([a.x - b.x, a.y - b.y])
        out["split"].append(_nees(delta, 4.0 * sol.covariance))
    return out


def _spearman(a: list[float], b: list[float]) -> float:
    ra, rb = np.argsort(np.argsort(a)), np.argsort(np.argsort(b))
    return float(np.corrcoef(ra, rb)[0, 1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("logs", nargs="*", default=list(LOGS))
    ap.add_argument("--every", type=int, default=1)
    ap.add_argument("--data", type=Path, default=DATA)
    args = ap.parse_args()
    print(
        f"{'log':10s} {'n':>5s} {'NEES mean':>9s} {'med':>5s} {'>3σ':>6s}  {'sandwich k=10 med':>17s}  "
        f"{'surfaces 1 cm med':>17s}  "
        f"{'split-half mean':>15s}  {'ρ(NEES, rmse)':>13s}"
    )
    for name in args.logs:
        m = measure(name, args.every, args.data)
        n = np.array(m["nees"])
        print(
            f"{name:10s} {len(n):5d} {n.mean():9.2f} {np.median(n):5.2f} {100 * np.mean(n > 11.83):5.2f}%  "
            f"{np.median(m['sandwich']):17.1f}  {np.median(m['surfaces']):17.1f}  {np.mean(m['split']):15.3f}  "
            f"{_spearman(m['nees'], m['rmse']):13.2f}",
            flush=True,
        )


if __name__ == "__main__":
    main()

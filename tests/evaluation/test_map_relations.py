"""The relations metric on a map: errors against simulated ground-truth relations and the 3σ test."""

from __future__ import annotations

import math

import numpy as np

from factorloc.evaluation.map_relations import CHI2_3SIGMA_3DOF, map_relations
from factorloc.evaluation.relations import Relations, summarize
from factorloc.geometry import Pose2
from factorloc.mapping import MapConfig, build_map
from factorloc.sim.laser import simulate_laser_log
from factorloc.sim.motion import random_walk
from factorloc.sim.world import apartment


def test_the_map_relations_are_near_the_truth_and_rarely_beyond_3_sigma() -> None:
    rng = np.random.default_rng(3)
    traj = random_walk(apartment(), Pose2(2.6, 2.2, 0.0), 8.0, rng)
    log, true = simulate_laser_log(apartment(), traj, rng, scan_every=3)
    result = build_map(log, MapConfig())
    pairs = [(a, a + k) for k in (1, 7, 25) for a in range(0, len(true) - k, 4)]
    t = log.scans.stamps_s
    poses = np.array([Pose2.from_array(true[a]).between(Pose2.from_array(true[b])).as_array() for a, b in pairs])
    rel = Relations(np.array([t[a] for a, _ in pairs]), np.array([t[b] for _, b in pairs]), poses)
    rows = map_relations(result, rel, log)
    assert len(rows) == len(pairs) and all(r.method == "map" and r.reliable for r in rows)
    row = next(r for r in summarize(rows, "sim") if r["subset"] == "all")
    assert row["trans_mean_cm"] < 3.0 and row["rot_mean_deg"] < 0.5, row
    d2 = np.array([r.nees_position for r in rows])
    assert np.all(np.isfinite(d2)) and np.mean(d2 > CHI2_3SIGMA_3DOF) <= 0.02
    # on the longest relations the odometry alone is far worse (the metric tells them apart)
    far = [i for i, (a, b) in enumerate(pairs) if b - a == 25]
    odo = [Pose2.from_array(rel.poses[i]).between(log.odometry.between(rel.t1_s[i], rel.t2_s[i])) for i in far]
    map_far = np.mean([rows[i].error_translation_m for i in far])
    assert np.mean([math.hypot(e.x, e.y) for e in odo]) > 2 * map_far
    no_cov = map_relations(result, rel, log, covariance=False)
    assert all(math.isnan(r.nees_position) and not r.confidently_wrong for r in no_cov)
    assert np.allclose([r.error_translation_m for r in no_cov], [r.error_translation_m for r in rows])

"""A map built from one run, then localized in: the scans that are not places, tracked through the map's places.

Issue 19, item 3: the map (``MapResult.place_map``) is a :class:`~factorloc.places.PlaceMap` whose places carry the
graph's marginal covariance; the :class:`~factorloc.places.Tracker` follows the held-back scans of the same
simulated run through it. The truth is the simulator's; the map frame is the odometry frame at the first place,
so the track is compared after the one rigid transform that takes the first place to its true pose.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.mapping import MapResult
from factorloc.mapping.result import relative_covariance
from factorloc.places import PlaceMap, Tracker, TrackerConfig, TrackState
from factorloc.types import Odometry, Query


def _held_back(sim_map: MapResult, n: int) -> list[int]:
    places = set(int(i) for i in sim_map.place_scan_indices)
    return [i for i in range(len(sim_map.scan_poses)) if i not in places][:n]


def test_the_map_is_a_place_map_with_its_marginals(sim_map: MapResult, tmp_path) -> None:
    pm = sim_map.place_map()
    assert len(pm) == len(sim_map)
    first = next(iter(pm))
    assert np.allclose(first.T_world_reference.as_array(), sim_map.place_poses[0])
    assert np.allclose(first.covariance, sim_map.place_covariances[0])
    loaded = PlaceMap.load(pm.save(tmp_path / "map"))
    assert loaded.same_as(pm)


def test_local_covariances_are_the_places_relative_uncertainty(sim_run, sim_map: MapResult) -> None:
    """Each place's local covariance is its uncertainty relative to a neighbour, at least that to the place before
    it, and honest about the map's true relative error of the two places."""
    log, true = sim_run
    local = sim_map.local_covariances()
    P = len(sim_map)
    assert local.shape == (P, 3, 3) and np.all(np.linalg.eigvalsh(local) > 0)
    # the place before each place: the map's relative pose of the two against the truth, under that covariance
    beyond = 0
    for p in range(1, P):
        q = p - 1
        Tq, Tp = sim_map.pose(q), sim_map.pose(p)
        body = relative_covariance(Tq, Tp, sim_map.joint_marginal(q, p))
        assert np.trace(local[p][:2, :2]) >= np.trace(body[:2, :2]) - 1e-15  # the larger of the neighbours
        tq, tp = (Pose2.from_array(true[int(sim_map.place_scan_indices[k])]) for k in (q, p))
        err = tq.between(tp).between(Tq.between(Tp))  # estimate in the truth's relative frame (body of p)
        e = np.array([err.x, err.y, err.theta])
        beyond += float(e @ np.linalg.solve(body, e)) > 14.16  # χ²(3 dof) at 3σ
    assert beyond <= max(1, 0.02 * P), f"{beyond} of {P - 1} neighbouring place pairs beyond 3σ"
    with pytest.raises(InputError, match="covariance must be one of"):
        sim_map.place_map(covariance="absolute")


@pytest.mark.parametrize("covariance", ["marginal", "local"])
def test_held_back_scans_are_tracked_through_the_map_within_centimetres(sim_run, sim_map: MapResult, covariance) -> None:
    log, true = sim_run
    pm = sim_map.place_map(covariance=covariance)
    held = _held_back(sim_map, 40)
    assert len(held) == 40
    i0 = int(sim_map.place_scan_indices[0])
    T_true_map = Pose2.from_array(true[i0]).compose(Pose2.from_array(sim_map.place_poses[0]).inverse())
    tracker = Tracker(pm, TrackerConfig(initial_pose=Pose2.from_array(sim_map.scan_poses[held[0]])))
    pos_err, head_err, wrong = [], [], 0
    for i in held:
        t = float(log.scans.stamps_s[i])
        odo = Odometry(log.odometry.pose_at(t), 1.0, 1.0, 1.0)
        r = tracker.update(Query(scan=log.scans.scans[i], odometry=odo))
        assert r.state is not TrackState.LOST, r.checks
        est = T_true_map.compose(r.pose)
        d = est.translation - true[i][:2]
        pos_err.append(float(np.hypot(*d)))
        head_err.append(abs(math.remainder(est.theta - true[i][2], 2 * math.pi)))
        # the map frame's covariance turned into the truth's frame: a rotation by T_true_map.theta
        c, s = math.cos(T_true_map.theta), math.sin(T_true_map.theta)
        R = np.array([[c, -s], [s, c]])
        cov = R @ r.covariance[:2, :2] @ R.T
        if not r.flagged and float(d @ np.linalg.solve(cov, d)) > 11.83:  # χ²(2 dof) at 3σ (p = 0.9973)
            wrong += 1
    rmse = math.sqrt(np.mean(np.square(pos_err)))
    heading_rmse = math.degrees(math.sqrt(np.mean(np.square(head_err))))
    assert rmse <= 0.03, f"position RMSE {100 * rmse:.2f} cm"
    assert heading_rmse <= 0.5, f"heading RMSE {heading_rmse:.2f}°"
    assert wrong <= 1, f"{wrong} of {len(held)} unflagged results beyond 3σ"

"""The place-recognition protocol on a real log: places every metre, the correct window around t1, recall@5."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc.errors import InputError


@pytest.fixture(scope="module")
def intel(shared_data):
    from factorloc.datasets.rosbag import read_laser_log
    from factorloc.evaluation.relations import read_relations

    d = shared_data / "laser"
    return read_laser_log(d / "intel.sort.bag"), read_relations(d / "intel.relations")


def test_places_are_a_metre_of_odometry_path_apart(intel) -> None:
    from factorloc.evaluation.places import places_along_log

    log, _ = intel
    m, t = places_along_log(log, 1.0)
    path = np.asarray(log.odometry.path_length_m(t))
    gaps = np.diff(path)
    assert len(m) == len(t) > 600
    assert np.all(np.diff(np.floor(path)) >= 1)  # one place per metre mark passed (the first scan past it)
    assert abs(np.median(gaps) - 1.0) < 0.05
    assert m[m.ids[3]].T_world_reference == log.odometry.pose_at(float(t[3]))


def test_the_correct_window_holds_t1_and_stays_within_a_metre(intel) -> None:
    from factorloc.evaluation.places import correct_window_s

    log, rel = intel
    t1 = float(rel.t1_s[1800])
    lo, hi = correct_window_s(log, t1, 1.0)
    assert lo <= t1 <= hi
    p1 = log.odometry.pose_at(t1).translation
    inside = log.scans.stamps_s[(log.scans.stamps_s >= lo) & (log.scans.stamps_s <= hi)]
    assert max(np.linalg.norm(log.odometry.pose_at(float(t)).translation - p1) for t in inside) <= 1.0 + 1e-6


@pytest.mark.slow
def test_recall_at_5_on_every_tenth_intel_loop(intel) -> None:
    from factorloc.evaluation.places import recognition_recall

    log, rel = intel
    r = recognition_recall(log, rel.subset(10), name="intel")
    assert r.ranks.size == 121
    # measured with the submap match (the default: submaps 4 m of path ahead of the place, 8 m behind): recall@1
    # 17.4 %, recall@5 48.8 % (on every relation 55.6 %; 4 m both ways: 54.5 % here, 60.9 % on every relation — the
    # default was chosen on the worst log, MIT CSAIL: docs/places.md); random choice would give about 1.5 %
    assert r.recall_at(5) >= 0.45
    assert r.recall_at(1) <= r.recall_at(5)
    assert r.ranks_related is not None and np.all(r.ranks_related <= r.ranks)  # a superset of the correct places


def test_path_submaps_stitch_the_scans_around_each_place_by_odometry(intel) -> None:
    from factorloc.evaluation.places import path_submaps, places_along_log
    from factorloc.places import PlaceMap

    log, _ = intel
    m, t = places_along_log(log, 1.0)
    i = 200
    sub = m.ids[i]
    submaps, spans = path_submaps(log, PlaceMap([m[sub]]), t[i : i + 1], 3.0)
    a, b = spans[0]
    assert a <= t[i] <= b
    # the span is the scans within 3 m of odometry path of the place's
    s = np.asarray(log.odometry.path_length_m(np.array([a, t[i], b])))
    assert s[1] - s[0] <= 3.0 + 1e-9 and s[2] - s[1] <= 3.0 + 1e-9
    assert s[2] - s[0] > 4.0  # the robot moved through: both sides are there
    # the place's own scan lies in its submap (the submap frame is the place's): each of its points within a
    # voxel of a submap point
    own = m[sub].reference.scan.points_m
    d = np.min(np.linalg.norm(own[:, None, :] - submaps[sub][None, :, :], axis=2), axis=1)
    assert np.max(d) <= 0.1 * math.sqrt(2) + 1e-9
    assert len(submaps[sub]) > 2 * len(own)
    # a longer stretch behind the place (the scans taken before it) than ahead
    _, spans_b = path_submaps(log, PlaceMap([m[sub]]), t[i : i + 1], 3.0, behind_m=6.0)
    a2, b2 = spans_b[0]
    s2 = np.asarray(log.odometry.path_length_m(np.array([a2, t[i], b2])))
    assert b2 == b and a2 < a and 3.0 < s2[1] - s2[0] <= 6.0 + 1e-9
    with pytest.raises(InputError, match="behind_m"):
        path_submaps(log, PlaceMap([m[sub]]), t[i : i + 1], 3.0, behind_m=-1.0)


@pytest.mark.slow
def test_a_place_of_another_pass_the_ground_truth_relates_counts_only_in_ranks_related(shared_data) -> None:
    """MIT CSAIL relation 1118 (t1 = ...4689.43, t2 = ...5029.36): the submap match retrieves, within its top 5, a place
    of the pass at ...4647.18, which the ground truth relates to the same t2 (measured: recall@5 50.0 % strict,
    61.7 % related on every MIT CSAIL loop, docs/places.md). The strict rank misses it; ranks_related finds it, and
    only when the relations searched hold that other relation."""
    from factorloc.datasets.rosbag import read_laser_log
    from factorloc.evaluation.places import recognition_recall
    from factorloc.evaluation.relations import Relations, read_relations

    d = shared_data / "laser"
    log, full = read_laser_log(d / "mit-csail.sort.bag"), read_relations(d / "mit-csail.relations")
    r = recognition_recall(log, full, name="mit-csail", indices=[1118])
    assert r.ranks.size == 1 and r.ranks_related is not None
    assert r.ranks[0] > 5 and r.ranks_related[0] <= 5
    assert r.recall_at(5) == 0.0 and r.recall_at_related(5) == 1.0
    alone = Relations(full.t1_s[1118:1119], full.t2_s[1118:1119], full.poses[1118:1119])
    r_alone = recognition_recall(log, alone, name="mit-csail", related=alone)
    assert np.array_equal(r_alone.ranks, r.ranks) and np.array_equal(r_alone.ranks_related, r_alone.ranks)

"""Telling a kidnapping from an aliased place: the tracker's ``tracker.confirmation`` and ``tracker.unique`` rules.

A synthetic building (a room beside a long corridor of look-alike places, as in ``test_tracker_states.py``) in which
the hierarchy is replaced by a model of what it does: seeded within 1 m of the robot's true pose it returns one
factor per place in view at that pose (2 cm, 0.3°), seeded farther it finds nothing. Place recognition is replaced
by fixed answers. So the tests check the tracker's rules, not the estimators:

* an **aliased twin** — one query whose places give nothing (a degenerate scan), recognized on two look-alike places
  4 m away — is refused when the next query's places around the old prediction explain that query again (the
  chain goes on, no new chain, the recognized pose never enters the graph);
* a **kidnapping** — recognized on the kidnapped query itself — is confirmed by the next query: the recognized
  pose moved by the odometry finds its places, the old prediction finds none: a new chain there, ``RELOCALIZED``;
* a **start-up by recognition from one scan** is flagged (``tracker.confirmed``) until a later query's places pass
  the gate against its prediction: the right start is confirmed by the next query, a wrong one (places of one pass
  that agree with each other, 4 m off) never is, and the kidnap rule re-localizes it;
* an **ambiguous** recognition — two groups of agreeing places on two poses (the two readings of a
  point-symmetric room, office tour seed 1014, docs/places.md) — starts no chain, whichever group is larger.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from corridor_building import ROOM_Y_M, building, ring_scan  # beside this file

from factorloc.evaluation.places import recognition_events
from factorloc.geometry import Pose2
from factorloc.pipeline import fuse
from factorloc.places import Tracker, TrackerConfig, TrackState
from factorloc.places.multi import PlaceLocalization
from factorloc.types import FULL, Estimate, Odometry, Query

STEP_M = 0.25  # the robot drives +x, 25 cm per query
SIGMA_M, SIGMA_RAD = 0.02, math.radians(0.3)


def _factors(pose: Pose2, places: tuple[str, ...]) -> list[Estimate]:
    cov = np.diag([SIGMA_M**2, SIGMA_M**2, SIGMA_RAD**2])
    return [Estimate(f"icp@{p}", FULL, pose.as_array() + 0.002 * (i - 0.5), cov) for i, p in enumerate(places)]


def _recognized(pose: Pose2, places: tuple[str, ...], rival: tuple[Pose2, tuple[str, ...]] | None = None):
    """Recognition's answer: the places' factors at ``pose`` (and a rival group at another pose, which the
    consistency gate drops when it is the smaller)."""
    factors = _factors(pose, places) + ([] if rival is None else _factors(*rival))
    loc = fuse(factors)
    assert loc.determined
    used = tuple(p for p in places)
    return PlaceLocalization(loc, used, (), ())


def _run(
    monkeypatch: pytest.MonkeyPatch,
    truths: list[Pose2],
    answers: list,
    *,
    blind: set[int] = frozenset(),
    **config,
) -> tuple[Tracker, list]:
    """Track queries whose true poses are ``truths`` (odometry: +x by STEP_M each, whatever the truth does) from a
    known start at ``truths[0]`` (``initial_pose=None`` in ``config``: a start by recognition); ``blind``: queries
    whose places give nothing wherever the hierarchy is seeded."""
    tracker = Tracker(building(), TrackerConfig(**{"initial_pose": truths[0], **config}))
    k = {"now": 0}

    def localize(query, place_ids, use_odometry=True):  # noqa: ANN001, ANN202 - the MultiPlaceLocalizer's shape
        truth = truths[k["now"]]
        seed = query.odometry.T_world_robot
        if k["now"] in blind or math.hypot(seed.x - truth.x, seed.y - truth.y) > 1.0:
            return SimpleNamespace(localization=SimpleNamespace(steps=()))
        return SimpleNamespace(localization=fuse(_factors(truth, tuple(place_ids[:2]))))

    monkeypatch.setattr(tracker.multi, "localize", localize)
    queue = list(answers)
    monkeypatch.setattr(tracker, "_recognize", lambda query: queue.pop(0) if queue else None)
    results = []
    for i in range(len(truths)):
        k["now"] = i
        odo = Odometry(Pose2(STEP_M * i, 0.0, 0.0), 0.05, 0.05, 0.01)
        results.append(tracker.update(Query(scan=ring_scan(), odometry=odo, id=f"q{i}")))
    return tracker, results


def _room(i: int) -> Pose2:
    return Pose2(2.0 + STEP_M * i, ROOM_Y_M, 0.0)


def _checks(result) -> dict:  # noqa: ANN001
    return {c.code: c for c in result.checks}


def test_an_aliased_twin_recognized_from_one_blind_query_is_refuted_by_the_next(monkeypatch) -> None:
    truths = [_room(i) for i in range(4)]
    twin = Pose2(truths[1].x + 4.0, ROOM_Y_M, 0.0)  # two look-alike places 4 m along
    tracker, results = _run(monkeypatch, truths, [_recognized(twin, ("r3", "r4"))], blind={1}, recognize_after=1)
    assert results[1].state is TrackState.TRACKING and results[1].flagged  # held, not switched
    assert _checks(results[1])["tracker.confirmation"].passed is False
    r = results[2]
    assert r.state is TrackState.TRACKING and not r.flagged and tracker.chains == 1
    assert _checks(r)["tracker.confirmation"].passed is True and "refuted" in _checks(r)["tracker.confirmation"].note
    assert all(abs(x.pose.x - t.x) < 0.05 for x, t in zip(results, truths, strict=True))  # never at the twin
    events = recognition_events(results)
    assert (events.held, events.refuted, events.confirmed, events.relocalized) == (1, 1, 0, 0)
    # the rule is what refuses it: without it the twin starts a new chain on the blind query, 4 m off
    tracker, results = _run(
        monkeypatch, truths, [_recognized(twin, ("r3", "r4"))], blind={1}, recognize_after=1, confirm_recognition=False
    )
    assert results[1].state is TrackState.RELOCALIZED and abs(results[1].pose.x - twin.x) < 0.05 and tracker.chains == 2


def test_a_kidnapping_recognized_on_the_kidnapped_query_is_confirmed_by_the_next(monkeypatch) -> None:
    corridor = [Pose2(20.0 + STEP_M * i, 0.0, 0.0) for i in range(3)]
    truths = [_room(0), *corridor]  # carried into the corridor after query 0
    tracker, results = _run(monkeypatch, truths, [_recognized(corridor[0], ("c13", "c14"))], recognize_after=1)
    assert results[1].state is TrackState.TRACKING and results[1].flagged  # recognized, waiting for confirmation
    r = results[2]
    assert r.state is TrackState.RELOCALIZED and r.flagged and tracker.chains == 2
    checks = _checks(r)
    assert checks["tracker.confirmation"].passed is True and checks["tracker.confirmation"].value >= 1
    assert checks["tracker.kidnap"].passed is False and checks["tracker.relocalized"].passed is True
    assert math.hypot(r.pose.x - corridor[1].x, r.pose.y - corridor[1].y) < 0.03
    assert results[3].state is TrackState.TRACKING and not results[3].flagged  # the new chain goes on
    assert abs(results[3].pose.x - corridor[2].x) < 0.03
    assert tracker.recognitions == 1  # the kidnap rule's recognition was not needed
    events = recognition_events(results)
    assert (events.held, events.refuted, events.confirmed, events.relocalized) == (1, 0, 1, 1)


def test_an_unconfirmed_recognition_leaves_the_kidnap_rule_its_own_recognition(monkeypatch) -> None:
    # recognized 4 m off on the kidnapped query (a look-alike), the next query finds nothing around it either: the
    # kidnap rule fires and its own recognition (the right place) starts the chain
    corridor = [Pose2(20.0 + STEP_M * i, 0.0, 0.0) for i in range(3)]
    truths = [_room(0), *corridor]
    wrong = Pose2(corridor[0].x - 4.5, 0.0, 0.0)
    answers = [_recognized(wrong, ("c10", "c11")), _recognized(corridor[1], ("c13", "c14"))]
    tracker, results = _run(monkeypatch, truths, answers, recognize_after=1)
    r = results[2]
    assert _checks(r)["tracker.confirmation"].passed is False and _checks(r)["tracker.confirmation"].value == 0
    assert r.state is TrackState.RELOCALIZED and tracker.recognitions == 2
    assert math.hypot(r.pose.x - corridor[1].x, r.pose.y) < 0.03


def test_two_groups_of_agreeing_places_on_two_poses_start_no_chain(monkeypatch) -> None:
    # the kidnap rule's recognition (recognize_after = 2): three places on the mirrored reading (5.8 m off), two on
    # the true one; the majority would win the consistency gate
    corridor = [Pose2(20.0 + STEP_M * i, 0.0, 0.0) for i in range(4)]
    truths = [_room(0), *corridor]
    mirror = Pose2(corridor[1].x - 5.8, 0.0, math.pi)
    ambiguous = _recognized(mirror, ("c9", "c10", "c11"), rival=(corridor[1], ("c13", "c14")))
    unique = _recognized(corridor[2], ("c13", "c14", "c15"))
    tracker, results = _run(monkeypatch, truths, [ambiguous, unique], recognize_after=2)
    r = results[2]
    assert r.state is TrackState.LOST and r.flagged and recognition_events(results).ambiguous == 1
    assert _checks(r)["tracker.unique"].passed is False and _checks(r)["tracker.unique"].value == 2
    assert results[3].state is TrackState.RELOCALIZED and _checks(results[3])["tracker.unique"].passed is True
    assert math.hypot(results[3].pose.x - corridor[2].x, results[3].pose.y) < 0.03
    # without the rule the majority wins: a new chain on the mirrored reading, 5.8 m off
    _, results = _run(monkeypatch, truths, [ambiguous, unique], recognize_after=2, refuse_ambiguous=False)
    assert results[2].state is TrackState.RELOCALIZED and abs(results[2].pose.x - mirror.x) < 0.05


def test_a_start_recognized_from_one_scan_is_flagged_until_the_next_query_confirms_it(monkeypatch) -> None:
    truths = [_room(i) for i in range(3)]
    tracker, results = _run(monkeypatch, truths, [_recognized(truths[0], ("r1", "r2"))], initial_pose=None)
    assert results[0].state is TrackState.RELOCALIZED and results[0].flagged
    assert [c.code for c in results[0].checks if not c.passed] == ["tracker.confirmed"]
    r = results[1]  # its places pass the gate against the prediction: confirmed, vouched for from here
    assert r.state is TrackState.TRACKING and not r.flagged
    assert _checks(r)["tracker.confirmed"].passed is True and _checks(r)["tracker.confirmed"].value >= 1
    assert "tracker.confirmed" not in _checks(results[2]) and not results[2].flagged
    # without the rule the first scan is vouched for at once
    _, results = _run(
        monkeypatch, truths, [_recognized(truths[0], ("r1", "r2"))], initial_pose=None, confirm_relocalization=False
    )
    assert results[0].state is TrackState.RELOCALIZED and not results[0].flagged


def test_a_wrong_start_recognized_from_one_scan_is_never_vouched_for(monkeypatch) -> None:
    # two look-alike places agree on a pose 4 m off: the next queries' places, seeded there, find nothing; every
    # result is flagged until the kidnap rule's recognition (the right room) starts a chain of its own
    truths = [_room(i) for i in range(5)]
    wrong = Pose2(truths[0].x + 4.0, ROOM_Y_M, 0.0)
    answers = [_recognized(wrong, ("r3", "r4")), _recognized(truths[2], ("r1", "r2"))]
    tracker, results = _run(monkeypatch, truths, answers, initial_pose=None, recognize_after=2)
    j = next(j for j in range(1, 5) if results[j].state is TrackState.RELOCALIZED)
    assert j == 2  # kidnap_after = 2 queries without a consistent factor
    assert all(r.flagged for r in results[:j]) and all(_checks(r)["tracker.confirmed"].passed is False for r in results[:j])
    assert abs(results[j].pose.x - truths[j].x) < 0.05 and tracker.recognitions == 2
    # one tracker.confirmed on the new chain's first result: about the new chain, not the abandoned one
    confirmed = [c for c in results[j].checks if c.code == "tracker.confirmed"]
    assert len(confirmed) == 1 and not confirmed[0].passed and "r1" in confirmed[0].note


def test_places_reading_a_corridor_both_ways_start_no_chain(monkeypatch) -> None:
    # recognition on a start-up: two places read the query one way along the corridor, three the other (turned by
    # 180°, the majority, with the more certain headings); every factor vague along the corridor (σx 10 m), so all
    # positions agree. With recognition_whole_pose the turned-away pair loses its position with its heading and is
    # a rival group: tracker.unique refuses the start (the shape of ACES scan 5139, docs/places.md)
    def factor(place: str, x_m: float, theta_rad: float, sigma_rad: float) -> Estimate:
        return Estimate(f"icp@{place}", FULL, np.array([x_m, 0.05, theta_rad]), np.diag([10.0**2, 0.1**2, sigma_rad**2]))

    runs = {
        "c3": factor("c3", 4.5, 0.0, 0.08),
        "c4": factor("c4", 4.6, 0.0, 0.07),
        "c10": factor("c10", 15.0, math.pi, 0.016),
        "c11": factor("c11", 16.0, math.pi - 0.01, 0.02),
        "c12": factor("c12", 17.0, math.pi + 0.01, 0.02),
    }

    def start(**config):  # noqa: ANN003, ANN202
        tracker = Tracker(building(), TrackerConfig(**config))
        cands = [SimpleNamespace(place_id=p, T_place_query=None, theta_place_query_rad=0.0) for p in runs]
        monkeypatch.setattr(tracker.recognizer, "candidates", lambda query, k: cands)
        monkeypatch.setattr(
            tracker.relocalizer,
            "run_place",
            lambda query, pid: SimpleNamespace(localization=SimpleNamespace(determined=True), factors=(runs[pid],)),
        )
        return tracker.update(Query(scan=ring_scan(), odometry=Odometry(Pose2(), 0.05, 0.05, 0.01), id="q0"))

    r = start()
    assert r.state is TrackState.LOST and _checks(r)["tracker.unique"].passed is False
    # without the rule the pair keeps its positions and the start fuses the majority's heading with all five positions
    r = start(recognition_whole_pose=False)
    assert r.state is TrackState.RELOCALIZED and _checks(r)["tracker.unique"].passed is True

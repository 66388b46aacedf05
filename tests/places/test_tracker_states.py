"""The tracker's states on a synthetic building: a pose that place recognition puts outside what the prediction
vouches for is ``RELOCALIZED`` (a new chain), even when the prediction's large covariance would let it pass the
gate; a kidnap suspicion that recognition refutes continues the chain as ``TRACKING``, without a jump.

The situation of the office tour, seed 1004, queries 10-13 (docs/places.md), made small: a known start in a room,
two queries whose places give nothing (the robot was carried into the corridor), a first re-localization on two
look-alike corridor places 11 m off with a large along-corridor σ, then a right one. The hierarchy and place
recognition are replaced by fixed answers (the factors they would give), so the tests check the tracker's rules.

With ``TrackerConfig.recognize_after = 1`` (the default; 2 = the kidnap rule alone) recognition is already tried on
the first query without support, under the same acceptance rules: a pose that disagrees with the prediction starts a
new chain at once (with ``confirm_recognition = False``; with it, the default, it waits for the next query:
``test_tracker_confirmation.py``), one that agrees continues it, a failure leaves the query ``TRACKING`` (flagged)
and the kidnap rule still fires later.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np
import pytest
from corridor_building import ROOM_Y_M, building, ring_scan  # beside this file

from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.pipeline import fuse
from factorloc.places import Tracker, TrackerConfig, TrackState
from factorloc.places.multi import PlaceLocalization
from factorloc.types import FULL, Estimate, Odometry, Query

STEP_M = 0.25  # the robot drives +x, 25 cm per query


def _query(k: int) -> Query:
    odo = Odometry(Pose2(2.0 + STEP_M * k, 0.0, 0.0), 0.05, 0.05, 0.01)  # the odometry's own frame: only increments count
    return Query(scan=ring_scan(), odometry=odo, id=f"q{k}")


def _recognized(x_m: float, y_m: float, sigma_x_m: float, places: tuple[str, str]) -> PlaceLocalization:
    """Two place factors at (x_m, y_m, 0) as the hierarchy gives them against recognized places."""
    cov = np.diag([sigma_x_m**2, 0.02**2, 0.005**2])
    factors = [
        Estimate(f"icp@{p}", FULL, np.array([x_m + dx, y_m, 0.0]), cov) for p, dx in zip(places, (-0.01, 0.01), strict=True)
    ]
    loc = fuse(factors)
    assert loc.determined
    return PlaceLocalization(loc, places, (), ())


def _track(
    monkeypatch: pytest.MonkeyPatch, answers: list[PlaceLocalization | None], n: int, recognize_after: int = 2, **config
) -> tuple[Tracker, list]:
    """``n`` queries from a known start; ``recognize_after = 2`` (= ``kidnap_after``): recognition only when the
    kidnap rule fires, the rule these tests check; 1 also on the first query without support."""
    config = TrackerConfig(initial_pose=Pose2(2.0, ROOM_Y_M, 0.0), recognize_after=recognize_after, **config)
    tracker = Tracker(building(), config)
    # the places in view of every prediction give no factor (the robot is elsewhere), recognition gives the answers
    monkeypatch.setattr(tracker.multi, "localize", lambda *a, **k: SimpleNamespace(localization=SimpleNamespace(steps=())))
    queue = list(answers)
    monkeypatch.setattr(tracker, "_recognize", lambda query: queue.pop(0))
    return tracker, [tracker.update(_query(k)) for k in range(n)]


def test_a_correction_of_a_flagged_relocalization_under_the_lost_rule_is_relocalized(monkeypatch) -> None:
    truth_x = 20.0 + STEP_M * np.arange(4)  # carried into the corridor, to x = 20 m, after query 0
    wrong = _recognized(9.0 + STEP_M * 2, 0.0, 4.0, ("c6", "c7"))  # look-alikes 11 m off, σx 4 m along the corridor
    right = _recognized(truth_x[3], 0.0, 0.03, ("c13", "c14"))
    tracker, results = _track(monkeypatch, [wrong, right], 4)
    assert [r.state for r in results[:2]] == [TrackState.TRACKING] * 2 and results[1].flagged  # no support at q1
    # query 2: the kidnap rule fires, recognition lands on the look-alikes, 4 m across the room's prediction: a new chain
    assert results[2].state is TrackState.RELOCALIZED and results[2].flagged
    assert math.sqrt(results[2].covariance[0, 0]) > TrackerConfig().lost_sigma_m  # honest: σx above the lost limit
    # query 3: σx > lost_sigma_m fires the lost rule; the right pose is 11 m from the prediction yet passes the gate
    # against it (11 m inside a prediction of σx ≈ 2.8 m: d² ≈ 15 < 16.27): not the chain continuing
    r = results[3]
    predicted_x = results[2].pose.x + STEP_M  # heading 0: the increment is along x
    assert abs(r.pose.x - truth_x[3]) < 0.05 and abs(r.pose.x - predicted_x) > 10.0
    assert (r.pose.x - predicted_x) ** 2 / results[2].covariance[0, 0] < 16.27
    assert r.state is TrackState.RELOCALIZED, (r.state, [c.to_dict() for c in r.checks])
    checks = {c.code: c for c in r.checks}
    assert checks["tracker.kidnap"].passed is False and checks["tracker.relocalized"].passed is True
    assert "not vouched for" in checks["tracker.relocalized"].note
    assert r.flagged and r.to_dict()["state"] == "relocalized"
    assert tracker.chains == 1 + sum(x.state is TrackState.RELOCALIZED for x in results)  # the start and each new chain


def test_a_vague_recognized_pose_that_passes_the_gate_does_not_drag_a_tight_prediction(monkeypatch) -> None:
    # kidnap rule with a tight prediction (σ of cm); recognition 7 m along x with its own σx of 2.8 m passes the gate
    # (covariance P̂ + R): the chain goes on and the pose stays inside the prediction's 3σ region (no jump)
    x = 2.0 + STEP_M * 2
    tracker, results = _track(monkeypatch, [_recognized(x + 7.0, ROOM_Y_M, 4.0, ("r3", "r4"))], 3)
    r = results[2]
    codes = {c.code: c.passed for c in r.checks}
    assert codes["tracker.prediction"] is True and codes["tracker.jump"] is True
    assert r.state is TrackState.TRACKING and tracker.chains == 1 and r.flagged  # the kidnap rule fired: said
    assert abs(r.pose.x - x) < 0.05  # 7 m of a 2.8 m σ against a 2 cm prediction: a few mm


def test_a_refuted_kidnap_suspicion_continues_the_chain_as_tracking(monkeypatch) -> None:
    # two queries without support (occlusion, not a kidnapping): recognition confirms the prediction
    x = 2.0 + STEP_M * 2
    tracker, results = _track(monkeypatch, [_recognized(x + 0.02, ROOM_Y_M, 0.03, ("r1", "r2"))], 3)
    r = results[2]
    assert r.state is TrackState.TRACKING and tracker.chains == 1
    assert {c.code: c.passed for c in r.checks}["tracker.jump"] is True
    assert abs(r.pose.x - x) < 0.03 and abs(r.pose.y - ROOM_Y_M) < 0.03
    assert r.flagged  # the kidnap rule fired on this query: said, not silent


def test_recognition_on_the_first_query_without_support_relocalizes_at_once(monkeypatch) -> None:
    # carried into the corridor after query 0: query 1's places give nothing; recognition on query 1 itself finds two
    # agreeing corridor places 4 m from the prediction: without confirmation (confirm_recognition = False) a new chain
    # there, a query before the kidnap rule would fire (with it: test_tracker_confirmation.py)
    right = _recognized(20.0 + STEP_M, 0.0, 0.03, ("c13", "c14"))
    tracker, results = _track(monkeypatch, [right], 2, recognize_after=1, confirm_recognition=False)
    r = results[1]
    assert r.state is TrackState.RELOCALIZED and tracker.chains == 2 and tracker.recognitions == 1
    assert abs(r.pose.x - (20.0 + STEP_M)) < 0.03 and abs(r.pose.y) < 0.03
    checks = {c.code: c for c in r.checks}
    assert checks["tracker.supported"].passed is False and checks["tracker.prediction"].passed is False
    assert checks["tracker.kidnap"].passed is False and checks["tracker.relocalized"].passed is True
    assert r.flagged  # a jump: said
    # the same query under the kidnap rule alone (recognize_after = 2): still tracking, recognition not asked yet
    _, late = _track(monkeypatch, [right], 2, recognize_after=2)
    assert late[1].state is TrackState.TRACKING and late[1].flagged


def test_a_one_off_query_without_support_that_recognition_confirms_continues_the_chain(monkeypatch) -> None:
    x = 2.0 + STEP_M
    for confirm in (True, False):
        answer = _recognized(x + 0.02, ROOM_Y_M, 0.03, ("r1", "r2"))
        tracker, results = _track(monkeypatch, [answer], 2, recognize_after=1, confirm_recognition=confirm)
        r = results[1]
        assert r.state is TrackState.TRACKING and tracker.chains == 1  # no new chain
        assert {c.code: c.passed for c in r.checks}["tracker.jump"] is True
        assert abs(r.pose.x - x) < 0.03 and abs(r.pose.y - ROOM_Y_M) < 0.03
        # with confirmation (the default) the early recognition's factors do not enter the graph: it only refutes
        # the kidnap suspicion; without it they do
        assert r.places_used == (() if confirm else ("r1", "r2")), (confirm, r.places_used)


def test_a_failed_early_recognition_keeps_tracking_and_the_kidnap_rule_still_fires(monkeypatch) -> None:
    # query 1: recognition finds nothing -> tracking (flagged, unsupported), not lost; query 2: the kidnap rule
    # fires, recognition finds nothing again -> lost
    tracker, results = _track(monkeypatch, [None, None], 3, recognize_after=1)
    assert results[1].state is TrackState.TRACKING and results[1].flagged
    assert "tracker.relocalized" not in {c.code for c in results[1].checks}
    assert results[2].state is TrackState.LOST and tracker.chains == 1
    assert {c.code: c.passed for c in results[2].checks}["tracker.kidnap"] is False


def test_recognize_after_must_not_exceed_kidnap_after() -> None:
    with pytest.raises(InputError, match="recognize_after"):
        TrackerConfig(recognize_after=3, kidnap_after=2)
    with pytest.raises(InputError, match="recognize_after"):
        TrackerConfig(recognize_after=0)

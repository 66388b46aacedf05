"""Several places, one answer: the fused pose from two places beats either's error bound, a mis-mapped place is
dropped by the consistency gate with its reason, and a place's pose covariance widens its factor."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc.geometry import Pose2
from factorloc.places import MultiPlaceLocalizer, Place, PlaceMap, place_factor
from factorloc.types import FULL, Estimate, Odometry, Query, Reference


@pytest.fixture(scope="module")
def world():
    from factorloc.sim import apartment

    return apartment()


def _place(world, pid: str, T_true: Pose2, T_mapped: Pose2 | None = None, seed: int = 0) -> Place:
    from factorloc.sim import render_scan

    scan = render_scan(world, T_true, rng=np.random.default_rng(seed))
    T = T_mapped or T_true
    return Place(pid, Reference(scan=scan, T_world_reference=T), T)


def _query(world, truth: Pose2, seed: int = 5) -> Query:
    from factorloc.sim import render_scan

    odo = Odometry(Pose2(truth.x + 0.15, truth.y - 0.1, truth.theta + 0.03), 0.3, 0.3, 0.1)
    return Query(scan=render_scan(world, truth, rng=np.random.default_rng(seed)), odometry=odo, id="q")


def test_two_places_agree_and_both_are_used(world) -> None:
    truth = Pose2(2.3, 1.6, 0.4)
    m = PlaceMap([_place(world, "a", Pose2(1.8, 1.5, 0.0), seed=1), _place(world, "b", Pose2(3.0, 2.0, 1.0), seed=2)])
    res = MultiPlaceLocalizer(m).localize(_query(world, truth), ["a", "b"])
    assert set(res.places_used) == {"a", "b"}
    err = math.hypot(res.pose.x - truth.x, res.pose.y - truth.y)
    assert err < 0.05
    assert abs(math.remainder(res.pose.theta - truth.theta, 2 * math.pi)) < math.radians(1.0)
    names = [r.name for r in res.localization.steps]
    assert names[0] == "odometry" and "icp@a" in names and "icp@b" in names
    assert res.to_dict()["places_used"] == list(res.places_used)


def test_a_mis_mapped_place_is_dropped_by_the_consistency_gate(world) -> None:
    truth = Pose2(2.3, 1.6, 0.4)
    m = PlaceMap(
        [
            _place(world, "a", Pose2(1.8, 1.5, 0.0), seed=1),
            _place(world, "b", Pose2(3.0, 2.0, 1.0), seed=2),
            _place(world, "bad", Pose2(2.0, 2.2, 0.3), T_mapped=Pose2(2.0, 1.6, 0.3), seed=3),  # mapped 0.6 m off
        ]
    )
    res = MultiPlaceLocalizer(m).localize(_query(world, truth), ["a", "b", "bad"])
    assert "bad" not in res.places_used and set(res.places_used) == {"a", "b"}
    reason = dict(res.places_dropped)["bad"]
    assert "d²" in reason or "consistency" in reason or "no reliable" in reason
    assert math.hypot(res.pose.x - truth.x, res.pose.y - truth.y) < 0.05


def test_place_covariance_moves_to_the_query_by_the_composition_jacobian() -> None:
    cov_place = np.diag([0.01, 0.01, 0.0004])
    place = Place("p", _dummy_reference(), Pose2(1, 1, 0), cov_place)
    est = Estimate("icp", FULL, np.array([3.0, 1.0, 0.2]), np.diag([1e-4, 1e-4, 1e-5]))
    f = place_factor(est, place, Pose2(3.0, 1.0, 0.2))
    # Δ = (2, 0): F = [[1,0,0],[0,1,2],[0,0,1]] → σy² += 0.01 + 4·0.0004, cov(y, θ) = 2·0.0004
    expected = np.diag([1e-4 + 0.01, 1e-4 + 0.01 + 4 * 0.0004, 1e-5 + 0.0004])
    expected[1, 2] = expected[2, 1] = 2 * 0.0004
    np.testing.assert_allclose(f.covariance, expected, rtol=1e-12)
    assert f.step == "icp@p"


def _dummy_reference() -> Reference:
    from factorloc.types import Scan

    return Reference(scan=Scan(np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])))

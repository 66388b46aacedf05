"""Trajectory scenarios: one odometry run along consecutive queries; a kidnapping moves the truth, not the odometry."""

from __future__ import annotations

import math

import pytest

from factorloc.baselines import generate_trajectory_scenario
from factorloc.errors import InputError


@pytest.fixture(scope="module")
def scenario():
    return generate_trajectory_scenario("apartment", 6, 11, kidnaps=1, no_depth_stretches=((1, 1),), spacing_m=0.5)


def test_consecutive_odometry_follows_the_true_motion_except_at_the_kidnapping(scenario) -> None:
    qs = scenario.queries
    kid = [i for i, q in enumerate(qs) if "kidnapped" in q.faults]
    assert len(kid) == 1
    k = kid[0]
    for i in range(1, len(qs)):
        true = qs[i - 1].truth.between(qs[i].truth)
        odo = qs[i - 1].query.odometry.T_world_robot.between(qs[i].query.odometry.T_world_robot)
        moved = math.hypot(true.x, true.y)
        if i == k:
            assert moved >= 0.7  # carried away…
            assert math.hypot(odo.x, odo.y) < 1e-9  # …and the odometry did not notice
        else:
            assert moved <= 0.5 + 1e-6
            assert math.hypot(odo.x - true.x, odo.y - true.y) <= 0.2 * max(moved, 0.05)


def test_no_depth_stretch_has_images_but_no_cloud_or_scan(scenario) -> None:
    q = scenario.queries[1]
    assert "no_depth" in q.faults
    assert q.query.cloud is None and q.query.scan is None and len(q.query.images) == 1
    assert scenario.queries[0].query.cloud is not None


def test_same_seed_same_scenario() -> None:
    a = generate_trajectory_scenario("apartment", 3, 5)
    b = generate_trajectory_scenario("apartment", 3, 5)
    assert [q.truth for q in a.queries] == [q.truth for q in b.queries]
    assert a.queries[2].query.odometry == b.queries[2].query.odometry


def test_unknown_fault_is_refused() -> None:
    with pytest.raises(InputError, match="unknown fault"):
        generate_trajectory_scenario("apartment", 3, 5, faults=("corridor",))

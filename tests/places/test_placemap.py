"""PlaceMap: built one by one or from a scenario, saved as a scenario without queries, loaded back equal."""

from __future__ import annotations

import math

import numpy as np
import pytest

import factorloc
from factorloc.datasets import Scenario, ScenarioReference, load_scenario
from factorloc.errors import InputError, UnknownIdError
from factorloc.geometry import Pose2
from factorloc.places import PLACE_COVARIANCE_KEY, ChoiceConfig, Place, PlaceMap, places_in_view
from factorloc.places.choose import view_overlap
from factorloc.types import Reference, Scan


def _ring_scan(radius_m: float, n: int = 90) -> Scan:
    a = np.linspace(-math.pi, math.pi, n, endpoint=False)
    return Scan(np.column_stack([radius_m * np.cos(a), radius_m * np.sin(a)]))


def _place(pid: str, x: float, y: float, radius_m: float = 3.0, cov: np.ndarray | None = None) -> Place:
    return Place(pid, Reference(scan=_ring_scan(radius_m)), Pose2(x, y, 0.3), cov)


def test_place_carries_its_pose_into_the_reference() -> None:
    p = Place("a", Reference(scan=_ring_scan(2.0), T_world_reference=Pose2(9, 9, 0)), Pose2(1.0, 2.0, 0.5))
    assert p.reference.T_world_reference == Pose2(1.0, 2.0, 0.5)
    assert p.footprint_m == pytest.approx(2.0)


def test_place_rejects_a_bad_id_and_a_bad_covariance() -> None:
    with pytest.raises(InputError, match="Place.id"):
        _place("a b", 0, 0)
    with pytest.raises(InputError, match="positive definite"):
        _place("a", 0, 0, cov=np.diag([1.0, -1.0, 1.0]))
    with pytest.raises(InputError, match="3×3"):
        _place("a", 0, 0, cov=np.eye(2))


def test_map_built_one_by_one_looks_up_and_refuses_duplicates() -> None:
    m = PlaceMap([_place("a", 0, 0)])
    m.add(_place("b", 4, 0))
    assert m.ids == ("a", "b") and len(m) == 2 and "b" in m
    assert m["b"].position_m.tolist() == [4.0, 0.0]
    np.testing.assert_array_equal(m.positions_m(), [[0.0, 0.0], [4.0, 0.0]])
    with pytest.raises(InputError, match="already"):
        m.add(_place("a", 1, 1))
    with pytest.raises(UnknownIdError):
        m["zz"]
    assert factorloc.PlaceMap is PlaceMap


def test_map_round_trips_through_a_scenario_directory_without_queries(tmp_path) -> None:
    cov = np.diag([0.01, 0.02, 0.001])
    m = PlaceMap([_place("a", 0, 0, cov=cov), _place("b", 4, 1)])
    path = m.save(tmp_path / "map")
    back = PlaceMap.load(path)
    assert back.same_as(m)
    np.testing.assert_array_equal(back["a"].covariance, cov)
    assert back["b"].covariance is None
    s = load_scenario(path)  # a plain scenario: the format's reader reads it
    assert len(s.queries) == 0 and s.references[0].metadata[PLACE_COVARIANCE_KEY] == cov.tolist()


def test_map_from_any_scenario_takes_its_references() -> None:
    refs = (
        ScenarioReference("r0", Reference(scan=_ring_scan(2.0), T_world_reference=Pose2(1, 0, 0))),
        ScenarioReference("r1", Reference(scan=_ring_scan(2.0), T_world_reference=Pose2(5, 0, 0))),
    )
    m = PlaceMap.from_scenario(Scenario("s", refs, ()))
    assert m.ids == ("r0", "r1") and m["r1"].T_world_reference == Pose2(5, 0, 0)


def test_places_in_view_nearest_first_within_reach_plus_uncertainty() -> None:
    m = PlaceMap([_place("far", 10, 0, radius_m=3.0), _place("near", 1, 0, radius_m=3.0), _place("mid", 3.5, 0, radius_m=3.0)])
    found = places_in_view(m, Pose2(0, 0, 0))
    assert [pid for pid, _ in found] == ["near"]  # mid is 3.5 m away, its scan reaches 3 m
    assert found[0][1] == pytest.approx(1.0)
    found = places_in_view(m, Pose2(0, 0, 0), np.diag([0.04, 0.01, 0.01]))  # 3σ = 0.6 m more
    assert [pid for pid, _ in found] == ["near", "mid"]
    assert len(places_in_view(m, Pose2(0, 0, 0), np.diag([100.0, 1, 1]), ChoiceConfig(k=2))) == 2


def _half_scan(radius_m: float = 3.0, n: int = 180) -> np.ndarray:
    """A 180° scan (x forward, bearings −90°…+90°) of a round room, robot frame."""
    a = np.linspace(-math.pi / 2, math.pi / 2, n)
    return np.column_stack([radius_m * np.cos(a), radius_m * np.sin(a)])


def test_view_overlap_counts_the_place_points_in_the_directions_the_query_sees() -> None:
    half = _half_scan()
    here = Pose2(0.0, 0.0, 0.0)
    assert view_overlap(half, here, here, half) == 1.0
    assert view_overlap(half, Pose2(0.0, 0.0, math.pi), here, half) < 0.05  # facing apart: only the edge sectors
    turned = view_overlap(half, Pose2(0.0, 0.0, math.pi / 2), here, half)
    assert turned == pytest.approx(0.5, abs=0.03)  # a quarter turn shares half the view
    ring = _ring_scan(3.0).points_m
    assert view_overlap(ring, Pose2(0.0, 0.0, 1.0), here, ring) == 1.0  # 360° scans: always the whole view
    assert view_overlap(np.zeros((0, 2)), here, here, half) == 0.0


def test_places_facing_away_come_after_those_sharing_the_view() -> None:
    """180° scans: of three places within reach, the nearest faces the other way; with the query's scan given the
    two that share its view are chosen (k = 2), nearest first; without it, the distance alone decides."""
    half = Scan(_half_scan())
    m = PlaceMap(
        [
            Place("behind", Reference(scan=half), Pose2(0.1, 0.0, math.pi)),
            Place("ahead", Reference(scan=half), Pose2(0.5, 0.0, 0.1)),
            Place("side", Reference(scan=half), Pose2(0.3, 0.2, -0.2)),
        ]
    )
    cfg = ChoiceConfig(k=2)
    assert [pid for pid, _ in places_in_view(m, Pose2(0, 0, 0), None, cfg)] == ["behind", "side"]
    chosen = places_in_view(m, Pose2(0, 0, 0), None, cfg, half.points_m)
    assert [pid for pid, _ in chosen] == ["side", "ahead"]
    assert chosen[0][1] == pytest.approx(math.hypot(0.3, 0.2))
    with pytest.raises(InputError, match="min_overlap"):
        ChoiceConfig(min_overlap=1.5)

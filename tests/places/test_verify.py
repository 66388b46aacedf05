"""Geometric verification of retrieved places: the ICP step without a hypothesis puts the place the query was taken
in first, with its pose; degenerate places (a corridor, a round room) are not verified; bad input is a typed error."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.places import Place, PlaceCandidate, PlaceMap, PlaceRecognizer, PlaceVerifier, RecognitionConfig
from factorloc.types import Query, Reference, Scan


def _walls(T_world_robot: Pose2, segments: list[tuple[float, float, float, float]], step: float = 0.04) -> np.ndarray:
    """Points every ``step`` m on wall segments (world frame), in the robot frame of ``T_world_robot``."""
    pts = []
    for x0, y0, x1, y1 in segments:
        n = max(2, int(math.hypot(x1 - x0, y1 - y0) / step))
        t = np.linspace(0.0, 1.0, n, endpoint=False)
        pts.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)]))
    return T_world_robot.inverse().transform_points(np.vstack(pts))


#: an L-shaped room with a pillar-like box: constrained in every direction, no symmetry
ROOM = [(0, 0, 6, 0), (6, 0, 6, 2.5), (6, 2.5, 3.5, 2.5), (3.5, 2.5, 3.5, 4.5), (3.5, 4.5, 0, 4.5), (0, 4.5, 0, 0)]
ROOM += [(1.2, 1.0, 1.8, 1.0), (1.8, 1.0, 1.8, 1.6), (1.8, 1.6, 1.2, 1.6), (1.2, 1.6, 1.2, 1.0)]
#: a featureless corridor: two parallel walls 2 m apart (the position along it is unknown)
CORRIDOR = [(-8, -1, 8, -1), (8, 1, -8, 1)]


def _place(pid: str, T_world: Pose2, segments: list, at: Pose2) -> Place:
    return Place(pid, Reference(scan=Scan(_walls(at, segments)), name=pid), T_world)


def _map() -> PlaceMap:
    # each place's scan seen from the place's own pose in its own world layout; the room place sits at (10, 5) in
    # the map with a 30° turn, so the verified estimate must carry the place's pose into the map's frame
    at_room = Pose2(2.0, 2.0, 0.0)
    return PlaceMap(
        [
            _place("corridor", Pose2(-20.0, 0.0, 0.0), CORRIDOR, Pose2(0.0, 0.0, 0.0)),
            _place("room", Pose2(10.0, 5.0, math.radians(30.0)), ROOM, at_room),
        ]
    )


def test_the_place_the_query_was_taken_in_comes_first_with_its_pose_in_the_map_frame() -> None:
    pm = _map()
    T_place_query = Pose2(0.35, -0.25, math.radians(25.0))  # the query 43 cm and 25° from the room place's pose
    query = Query(scan=Scan(_walls(Pose2(2.0, 2.0, 0.0).compose(T_place_query), ROOM)), id="q")
    cands = [PlaceCandidate("corridor", 0.1, "submap_match"), PlaceCandidate("room", 0.2, "submap_match")]
    out = PlaceVerifier(pm).verify(query, cands)
    assert [v.place_id for v in out] == ["room", "corridor"]
    room, corridor = out
    assert room.verified and room.check.code == "places.verified"
    truth = pm["room"].T_world_reference.compose(T_place_query)
    d = truth.between(Pose2(room.estimate.value("x"), room.estimate.value("y"), room.estimate.value("theta")))
    assert math.hypot(d.x, d.y) < 0.02 and abs(d.theta) < math.radians(0.5)
    assert 0.8 < room.score <= 1.0  # the icp.score value: fitness − violation on an exact copy of the walls
    # the corridor: the query does not fit it, and even a fit could not fix the position along it
    assert not corridor.verified and corridor.check.note


def test_unverified_places_keep_their_retrieval_order_after_the_verified() -> None:
    pm = PlaceMap([*_map(), _place("corridor2", Pose2(-40.0, 0.0, 0.0), CORRIDOR, Pose2(1.0, 0.0, 0.0))])
    query = Query(scan=Scan(_walls(Pose2(2.1, 1.9, 0.1), ROOM)), id="q")
    cands = [PlaceCandidate(p, 0.1 * i, "submap_match") for i, p in enumerate(["corridor2", "corridor", "room"])]
    out = PlaceVerifier(pm).verify(query, cands)
    assert [v.place_id for v in out] == ["room", "corridor2", "corridor"]
    assert [v.verified for v in out] == [True, False, False]


def test_rank_takes_the_shortlist_from_the_recognizer_and_returns_the_first_k() -> None:
    pm = _map()
    rec = PlaceRecognizer(pm, RecognitionConfig(rank_by="submap_match"))
    query = Query(scan=Scan(_walls(Pose2(2.2, 2.1, -0.3), ROOM)), id="q")
    out = PlaceVerifier(pm).rank(rec, query, k=1, shortlist=2)
    assert len(out) == 1 and out[0].place_id == "room" and out[0].verified


def test_bad_input_is_a_typed_error_naming_it() -> None:
    pm = _map()
    v = PlaceVerifier(pm)
    scan_query = Query(scan=Scan(_walls(Pose2(2.0, 2.0, 0.0), ROOM)), id="q")
    with pytest.raises(InputError, match="no scan or cloud"):
        v.verify(Query(id="empty", odometry=None), [PlaceCandidate("room", 0.1, "submap_match")])
    with pytest.raises(InputError, match="'nowhere' is not in the place map"):
        v.verify(scan_query, [PlaceCandidate("nowhere", 0.1, "submap_match")])
    with pytest.raises(InputError, match="PlaceCandidate"):
        v.verify(scan_query, ["room"])  # type: ignore[list-item]
    with pytest.raises(InputError, match="PlaceMap"):
        PlaceVerifier([pm["room"]])  # type: ignore[arg-type]
    with pytest.raises(InputError, match="same PlaceMap"):
        v.rank(PlaceRecognizer(_map()), scan_query)
    with pytest.raises(InputError, match="shortlist"):
        v.rank(PlaceRecognizer(pm), scan_query, shortlist=0)


@pytest.mark.slow
def test_on_real_loops_verification_puts_more_correct_places_in_the_top_5(shared_data) -> None:
    """Intel, every 25th relation from the 4th (49 loops): the shortlist of 20 verified against retrieval alone."""
    from factorloc.datasets.rosbag import read_laser_log
    from factorloc.evaluation.places import recognition_recall
    from factorloc.evaluation.relations import read_relations

    d = shared_data / "laser"
    log, full = read_laser_log(d / "intel.sort.bag"), read_relations(d / "intel.relations")
    rel = full.subset(25, 3)
    cfg = RecognitionConfig(rank_by="submap_match")
    plain = recognition_recall(log, rel, cfg, name="intel", related=full)
    verified = recognition_recall(log, rel, cfg, name="intel", related=full, verify_shortlist=20)
    assert plain.ranks.size == verified.ranks.size == 49
    # measured: recall@5 63.3 -> 71.4 % (31 -> 35 of 49), recall@1 26.5 -> 28.6 % (on every 10th relation, 121
    # loops: 48.8 -> 69.4 % and 17.4 -> 35.5 %; docs/places.md)
    assert verified.recall_at(5) >= plain.recall_at(5) + 2 / 49
    assert verified.recall_at(1) >= plain.recall_at(1)


def test_on_the_simulated_apartment_verification_puts_the_near_place_first() -> None:
    """The covering map (every free pose within 0.9 m of a place), seed 7, 40 queries: verification against
    retrieval alone, on the same queries."""
    from factorloc.evaluation.places import simulated_place_map, simulated_recall
    from factorloc.sim import apartment

    world = apartment()
    m = simulated_place_map(world, 1.0, seed=0, cover_m=0.9)
    plain = simulated_recall(world, m, 40, seed=7)
    verified = simulated_recall(world, m, 40, seed=7, verify_shortlist=20)
    # measured on seeds 301-303, 200 queries each: recall@1 88.0-90.5 -> 95.5-98.5 %, recall@5 100 % both
    # (docs/places.md). Here recall@1 is 36 -> 35 of 40: a place just beyond the protocol's 1 m can verify with a
    # better ICP score than the nearest one (small samples: the docs' seeds are the figure)
    assert plain.recall_at(5) == verified.recall_at(5) == 1.0
    assert verified.recall_at(1) >= 0.8
    with pytest.raises(InputError, match="need queries with a scan|needs queries with a scan"):
        simulated_recall(world, m, 2, seed=7, verify_shortlist=20, panorama_width_px=64)

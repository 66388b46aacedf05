"""Multi-place worlds and tours: places in every room of both worlds, a tour through all rooms by the doors, a
trajectory whose kidnappings the odometry does not see, its faults, and bad settings named."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.sim import world_by_name
from factorloc.sim.track import TrackConfig, generate_track, plan_path, room_of, room_places, rooms, tour_path


@pytest.fixture(scope="module")
def apartment_places():
    world = world_by_name("apartment")
    return world, room_places(world, 1.5, seed=0)


@pytest.mark.parametrize("name, n_rooms", [("apartment", 6), ("office", 9)])
def test_every_room_and_the_corridor_hold_a_place_in_free_space(name: str, n_rooms: int) -> None:
    world = world_by_name(name)
    names = [r for r, _ in rooms(world)]
    assert len(names) == n_rooms and "corridor" in names
    pm = room_places(world, 1.5, seed=0, clearance_m=0.3) if name == "apartment" else None
    if pm is None:  # the office: the same rule, checked on the points without rendering 150 scans
        from factorloc.sim.track import _room_points

        pts = {r: _room_points(world, box, 1.5, 0.3) for r, box in rooms(world)}
        assert all(len(p) >= 1 for p in pts.values())
        assert len(pts["corridor"]) >= 15  # the 30 m corridor: a place every 1.5–2 m along it
        all_pts = np.vstack(list(pts.values()))
    else:
        by_room = {r: [p for p in pm if p.reference.name == r] for r in names}
        assert all(len(v) >= 1 for v in by_room.values()), {r: len(v) for r, v in by_room.items()}
        all_pts = pm.positions_m()
        assert [room_of(world, p.position_m)[0] for p in pm] == [p.reference.name for p in pm]
        assert all(p.reference.scan is not None and len(p.reference.scan) > 100 for p in pm)
    assert world.is_free(all_pts, 0.3 - 1e-9).all()


def test_the_office_is_a_larger_textured_world_whose_panoramas_render() -> None:
    from factorloc.sim import render_panorama

    world = world_by_name("office")
    x0, y0, x1, y1 = world.bounds_xy
    assert (x1 - x0, y1 - y0) == (30.0, 15.0)
    pano = render_panorama(world, Pose2(4.0, 7.5, 0.0), width_px=256)
    img = pano.image_bgr.astype(np.float64)
    assert img.shape[1] == 256
    assert img.std() > 20.0  # not a flat colour
    flat = render_panorama(world_by_name("apartment"), Pose2(2.0, 4.1, 0.0), width_px=256).image_bgr.astype(np.float64)

    def detail(im: np.ndarray) -> float:  # mean |horizontal gradient|: textures and decals
        return float(np.mean(np.abs(np.diff(im, axis=1))))

    assert detail(img) > 0.5 * detail(flat)  # textured like the apartment (its corridor as the peer)


def test_a_path_between_rooms_goes_through_the_door() -> None:
    world = world_by_name("apartment")
    wps = plan_path(world, (1.5, 1.5), (3.0, 6.0), clearance_m=0.35)  # living room -> bedroom: two walls between
    assert np.allclose(wps[0], (1.5, 1.5)) and np.allclose(wps[-1], (3.0, 6.0))
    dense = np.vstack([a + np.linspace(0, 1, 50)[:, None] * (b - a) for a, b in zip(wps[:-1], wps[1:], strict=True)])
    assert world.is_free(dense, 0.25).all()
    length = float(np.sum(np.hypot(*np.diff(wps, axis=0).T)))
    assert length > math.dist((1.5, 1.5), (3.0, 6.0)) + 0.1  # not the straight line through the walls
    for y, (lo, hi) in ((3.5, (1.5, 2.4)), (4.7, (2.8, 3.7))):  # the living-room door, then the bedroom door
        at_wall = dense[np.abs(dense[:, 1] - y) < 0.05]
        assert len(at_wall) and np.all((at_wall[:, 0] > lo) & (at_wall[:, 0] < hi))
    with pytest.raises(InputError, match="goal_xy"):
        plan_path(world, (1.5, 1.5), (1.5, 6.5))  # on the bed


@pytest.mark.parametrize("name, length_m", [("apartment", 45.0), ("office", 140.0)])
def test_a_tour_visits_every_room(name: str, length_m: float) -> None:
    world = world_by_name(name)
    path, visited = tour_path(world, Pose2(1.5, 2.5, 0.0), length_m, seed=3)
    names = {r for r, _ in rooms(world)}
    assert set(visited) == names
    assert set(room_of(world, path[:, :2])) == names  # it is really there, not just planned
    assert world.is_free(path[:, :2], 0.25).all()
    steps = np.hypot(*np.diff(path[:, :2], axis=0).T)
    assert steps.max() <= 0.05 + 1e-9


def test_a_trajectory_has_truth_in_free_space_and_kidnappings_the_odometry_does_not_see(apartment_places) -> None:
    world, pm = apartment_places
    sc = generate_track(world, pm, 20, seed=31, kidnaps=1, config=TrackConfig(fault_probability=0.3))
    assert len(sc.queries) == 20 and [r.id for r in sc.references] == list(pm.ids)
    truth = np.array([q.truth.as_array() for q in sc.queries])
    odo = np.array([q.query.odometry.T_world_robot.as_array() for q in sc.queries])
    assert world.is_free(truth[:, :2], 0.25).all()  # clearance_m − planner_resolution_m
    kid = [i for i, q in enumerate(sc.queries) if "kidnapped" in q.faults]
    assert len(kid) == 1 and 10 <= kid[0] <= 15
    k = kid[0]
    true_step = np.hypot(*np.diff(truth[:, :2], axis=0).T)
    odo_step = np.hypot(*np.diff(odo[:, :2], axis=0).T)
    assert true_step[k - 1] > 1.0  # carried to another room
    assert room_of(world, truth[k, :2]) != room_of(world, truth[k - 1, :2])
    assert odo_step[k - 1] <= 0.26  # the odometry goes on by one ordinary step
    others = np.delete(true_step, k - 1)
    assert others.max() <= 0.25 + 1e-9 and np.all(np.delete(odo_step, k - 1) <= 0.3)
    assert [q.timestamp_s for q in sc.queries] == sorted(q.timestamp_s for q in sc.queries)
    assert all(q.metadata["room"] == room_of(world, q.truth.translation)[0] for q in sc.queries)
    occluded = [q for q in sc.queries if "occlusion" in q.faults]
    assert occluded and all(q.metadata["occluders"] for q in occluded)
    again = generate_track(world, pm, 20, seed=31, kidnaps=1, config=TrackConfig(fault_probability=0.3))
    assert np.array_equal(truth, [q.truth.as_array() for q in again.queries])  # reproducible from the seed
    assert all(
        np.array_equal(a.query.scan.points_m, b.query.scan.points_m) for a, b in zip(sc.queries, again.queries, strict=True)
    )


def test_bad_track_settings_are_named(apartment_places) -> None:
    world, pm = apartment_places
    with pytest.raises(InputError, match="panorama_width_px"):
        TrackConfig(faults=("lighting",))
    with pytest.raises(InputError, match="unknown"):
        TrackConfig(faults=("glass",))
    with pytest.raises(InputError, match="kidnappings need"):
        generate_track(world, pm, 12, seed=1, kidnaps=1)
    no_rooms = world_by_name("apartment").__class__(name="bare", walls=world.walls)
    with pytest.raises(InputError, match="no rooms"):
        room_places(no_rooms)
    assert math.isfinite(TrackConfig().query_spacing_m)


def test_covering_points_bring_every_free_pose_within_reach_of_a_place() -> None:
    from factorloc.sim.track import COVER_LATTICE_M, covering_points, grid_places

    world = world_by_name("apartment")
    plain = grid_places(world, 1.0, seed=0)
    covered = grid_places(world, 1.0, seed=0, cover_m=0.9)
    n = len(plain)
    assert len(covered) > n  # the 1 m grid leaves free space along walls and in passages more than 0.9 m from it
    # the grid's places come first, unchanged (ids, poses, the very scans)
    for a, b in zip(plain, list(covered)[:n], strict=True):
        assert a.id == b.id and a.T_world_reference == b.T_world_reference
        assert np.array_equal(a.reference.scan.points_m, b.reference.scan.points_m)
    pos = covered.positions_m()
    assert world.is_free(pos, 0.3 - 1e-9).all()
    rng = np.random.default_rng(5)
    x0, y0, x1, y1 = world.bounds_xy
    probe = np.column_stack([rng.uniform(x0, x1, 20000), rng.uniform(y0, y1, 20000)])
    probe = probe[world.is_free(probe, 0.3)]

    def nearest(places: np.ndarray) -> np.ndarray:
        return np.min(np.hypot(probe[:, None, 0] - places[None, :, 0], probe[:, None, 1] - places[None, :, 1]), axis=1)

    assert nearest(pos).max() <= 0.9 + COVER_LATTICE_M / math.sqrt(2) + 1e-9
    assert nearest(plain.positions_m()).max() > 1.0  # what the covering places are for
    # already covered: nothing to add; bad input is named
    assert covering_points(world, pos, 50.0).shape == (0, 2)
    with pytest.raises(InputError, match="cover_m"):
        covering_points(world, pos, 0.0)
    with pytest.raises(InputError, match="placed_xy"):
        covering_points(world, np.array([[np.nan, 0.0]]), 1.0)

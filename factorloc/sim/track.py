"""Multi-place worlds and trajectories through them: places in every room, a robot touring the rooms, kidnappings.

A world names its rooms as regions ``room.<name>`` (axis-aligned boxes ``(x0, y0, x1, y1)``, metres, world frame;
the corridor is a room too, ``room.corridor``): :func:`rooms` lists them, :func:`room_of` says where a point is.

* :func:`room_places` — a :class:`~factorloc.places.PlaceMap` with places in every room: the nodes of a
  ``spacing_m`` grid centred in each room's box that are free (``clearance_m``), at least one per room (the free
  point nearest the room's centre when no node is free), each with a 360° laser scan
  (:func:`factorloc.sim.render_scan`, the real-lidar error model) taken at a random heading and, optionally, a
  rendered panorama. :func:`grid_places` is the same over one grid of the whole plan, rooms ignored; with
  ``cover_m`` it adds places until every free pose lies within ``cover_m`` of one (a grid leaves the free space
  along walls and in narrow passages farther than that from its free nodes).
* :func:`tour_path` — a robot touring the rooms: from its room to the nearest not yet visited one (of the two
  nearest, drawn at random), to a random free point in it, along the shortest collision-free path of an
  8-connected occupancy grid (A*, ``planner_resolution_m``) shortened by line of sight, driven by
  :func:`factorloc.sim.waypoint_trajectory` (turn in place, then straight). It passes through the doors because the
  walls leave no other way. When every room was visited, a new round starts.
* :func:`generate_track` — a :class:`~factorloc.datasets.Scenario` along such a tour: a query every
  ``query_spacing_m`` of travel (a turn counts ``turn_weight_m_per_rad`` metres per radian), each with a 360° scan
  (and a panorama with ``panorama_width_px``), one continuous drifting odometry run
  (:func:`factorloc.sim.simulate_odometry`), the true pose and the room; ``kidnaps`` times the robot is carried to a
  random free pose of another room between two queries (tag ``kidnapped`` on the first query after it; the
  odometry goes on from where it was: it does not see it); single queries get the faults of
  :mod:`factorloc.sim.faults` that apply to them with probability ``fault_probability``: ``occlusion`` (people and
  boxes the places do not have, seen by the scan and the panorama), ``lighting`` and ``blur`` (the panorama only).
  :func:`random_track` is the older drive of random legs (no tour) over any place map.

Everything is reproducible from the seed.
"""

from __future__ import annotations

import heapq
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING, Any

import numpy as np

from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.sim.determinism import deterministic
from factorloc.sim.faults import motion_blur, place_occluders, relight
from factorloc.sim.laser import SCAN_POSE_SIGMA_M, SCAN_POSE_SIGMA_RAD, render_scan
from factorloc.sim.motion import DriftModel, sample_free_pose, simulate_odometry, waypoint_trajectory
from factorloc.sim.render import render_panorama
from factorloc.sim.world import World
from factorloc.types import Odometry, Query, Reference

if TYPE_CHECKING:  # pragma: no cover
    from factorloc.datasets import Scenario
    from factorloc.places import PlaceMap

__all__ = [
    "ROOM_PREFIX",
    "TRACK_FAULTS",
    "TrackConfig",
    "generate_track",
    "covering_points",
    "grid_places",
    "plan_path",
    "random_track",
    "room_of",
    "room_places",
    "rooms",
    "tour_path",
]

#: The prefix of the world regions that are rooms (``room.kitchen``, ``room.corridor``).
ROOM_PREFIX = "room."
#: The per-query faults :func:`generate_track` can apply (besides ``kidnapped``).
TRACK_FAULTS = ("occlusion", "lighting", "blur")
_PANORAMA_FAULTS = ("lighting", "blur")


# --------------------------------------------------------------------------
# Rooms
# --------------------------------------------------------------------------
def rooms(world: World) -> tuple[tuple[str, tuple[float, float, float, float]], ...]:
    """The world's rooms: ``(name, (x0, y0, x1, y1))`` of every region named ``room.<name>``, in file order.

    Raises
    ------
    InputError
        When the world names no room.
    """
    out = tuple((n[len(ROOM_PREFIX) :], box) for n, box in world.regions if n.startswith(ROOM_PREFIX))
    if not out:
        raise InputError(f"world '{world.name}' has no rooms: name regions 'room.<name>: [x0, y0, x1, y1]' in its file")
    return out


def room_of(world: World, xy: np.ndarray) -> list[str | None]:
    """The room of each of N×2 points (the first room whose box holds it; None outside every room)."""
    pts = np.atleast_2d(np.asarray(xy, dtype=np.float64))
    out: list[str | None] = [None] * len(pts)
    for name, (x0, y0, x1, y1) in reversed(rooms(world)):
        inside = (pts[:, 0] >= x0) & (pts[:, 0] <= x1) & (pts[:, 1] >= y0) & (pts[:, 1] <= y1)
        for i in np.flatnonzero(inside):
            out[int(i)] = name
    return out


def _room_points(world: World, box: tuple[float, float, float, float], spacing_m: float, clearance_m: float) -> np.ndarray:
    """The free nodes of a ``spacing_m`` grid centred in ``box`` (at least one: the free point nearest its centre)."""
    x0, y0, x1, y1 = box
    nx, ny = max(1, round((x1 - x0) / spacing_m)), max(1, round((y1 - y0) / spacing_m))
    xs = x0 + (np.arange(nx) + 0.5) * (x1 - x0) / nx
    ys = y0 + (np.arange(ny) + 0.5) * (y1 - y0) / ny
    grid = np.array([(x, y) for y in ys for x in xs])
    free = grid[world.is_free(grid, clearance_m)]
    if len(free):
        return free
    fine = np.array([(x, y) for y in np.arange(y0, y1, 0.05) for x in np.arange(x0, x1, 0.05)])
    ok = fine[world.is_free(fine, clearance_m)]
    if not len(ok):
        raise InputError(f"room box {box} of world '{world.name}' has no point {clearance_m} m from every surface")
    c = np.array([(x0 + x1) / 2, (y0 + y1) / 2])
    return ok[[int(np.argmin(np.hypot(*(ok - c).T)))]]


def _place_covariance() -> np.ndarray:
    """A simulated place's covariance: the simulator's per-scan sensor pose error (the scan was taken that far from
    the pose the map states)."""
    return np.diag([SCAN_POSE_SIGMA_M**2, SCAN_POSE_SIGMA_M**2, SCAN_POSE_SIGMA_RAD**2])


def _render_place(world: World, T: Pose2, rng: np.random.Generator, panorama_width_px: int, name: str) -> Reference:
    scan = render_scan(world, T, rng=rng)
    pano = render_panorama(world, T, width_px=panorama_width_px) if panorama_width_px > 0 else None
    return Reference(panorama=pano, scan=scan, T_world_reference=T, name=name)


def _check_spacing(spacing_m: float) -> float:
    if isinstance(spacing_m, bool) or not (isinstance(spacing_m, (int, float)) and math.isfinite(spacing_m) and spacing_m > 0):
        raise InputError(f"spacing_m must be a finite number > 0, got {spacing_m!r}")
    return float(spacing_m)


@deterministic
def room_places(
    world: World, spacing_m: float = 1.5, seed: int = 0, clearance_m: float = 0.3, *, panorama_width_px: int = 0
) -> PlaceMap:
    """Places in every room of ``world`` (see the module): ids ``<room>-<k>``, the reference named after its room.

    Each place's covariance is the simulator's per-scan sensor pose error (``SCAN_POSE_SIGMA_M`` per axis,
    ``SCAN_POSE_SIGMA_RAD``). With ``panorama_width_px`` > 0 each place also holds a rendered 360° panorama of that
    width (camera at 1 m). Reproducible from ``seed``.
    """
    from factorloc.places import Place, PlaceMap

    spacing = _check_spacing(spacing_m)
    rng = np.random.default_rng(seed)
    cov = _place_covariance()
    places = []
    for name, box in rooms(world):
        for k, (x, y) in enumerate(_room_points(world, box, spacing, clearance_m)):
            T = Pose2(float(x), float(y), float(rng.uniform(-math.pi, math.pi)))
            places.append(Place(f"{name}-{k}", _render_place(world, T, rng, panorama_width_px, name), T, cov))
    return PlaceMap(places)


#: Lattice step (m) of the free points that :func:`grid_places` covers with ``cover_m``: a free pose is at most
#: half a diagonal of it (0.071 m) from the nearest lattice point.
COVER_LATTICE_M = 0.1
#: Tolerance (m) of the covering test and of the farthest point's choice: a lattice point exactly ``cover_m`` from
#: a place (lattice distances can be exactly that in theory) counts as covered, and points equally far in theory
#: are a tie, whatever the rounding of the distances.
COVER_TOLERANCE_M = 1e-9


def covering_points(world: World, placed_xy: np.ndarray, cover_m: float, clearance_m: float = 0.3) -> np.ndarray:
    """The points (K×2, world frame, m) to add to ``placed_xy`` (N×2) so that every free point of the plan (free
    at ``clearance_m``, on a :data:`COVER_LATTICE_M` lattice) lies within ``cover_m`` of a place: greedy
    farthest-point insertion (each new point is the free lattice point farthest from all places so far; ties,
    within :data:`COVER_TOLERANCE_M`: the first in row order), a 2-approximation of the fewest such points
    (Gonzalez 1985, k-centre)."""
    if isinstance(cover_m, bool) or not (isinstance(cover_m, (int, float)) and math.isfinite(cover_m) and cover_m > 0):
        raise InputError(f"cover_m must be a finite number > 0, got {cover_m!r}")
    r = float(cover_m)
    placed = np.asarray(placed_xy, dtype=np.float64)
    if placed.size and (placed.ndim != 2 or placed.shape[1] != 2 or not np.all(np.isfinite(placed))):
        raise InputError(f"placed_xy must be finite N×2 positions (m), got shape {placed.shape}")
    placed = placed.reshape(-1, 2)
    x0, y0, x1, y1 = world.bounds_xy
    h = COVER_LATTICE_M
    xs, ys = np.arange(x0 + h / 2, x1, h), np.arange(y0 + h / 2, y1, h)
    lattice = np.column_stack([np.tile(xs, len(ys)), np.repeat(ys, len(xs))])
    free = lattice[world.is_free(lattice, clearance_m)]
    if len(free) == 0:
        return np.zeros((0, 2))
    d = np.full(len(free), np.inf)
    for p in placed:
        d = np.minimum(d, np.hypot(*(free - p).T))
    added = []
    while (far := float(d.max())) > r + COVER_TOLERANCE_M:
        # the first lattice point (row order) within the tolerance of the farthest: ties in theory are ties here
        p = free[int(np.flatnonzero(d >= far - COVER_TOLERANCE_M)[0])]
        added.append(p)
        d = np.minimum(d, np.hypot(*(free - p).T))
    return np.array(added).reshape(-1, 2)


def grid_places(
    world: World,
    spacing_m: float = 1.0,
    seed: int = 0,
    clearance_m: float = 0.3,
    *,
    panorama_width_px: int = 0,
    cover_m: float | None = None,
) -> PlaceMap:
    """A place on every free node of one ``spacing_m`` grid over the plan's bounds (ids ``g000``, …), each with a
    360° laser scan taken at a random heading (and a panorama with ``panorama_width_px`` > 0); covariance as in
    :func:`room_places`. With ``cover_m``, places at the :func:`covering_points` follow the grid's (the grid's
    places, their scans and headings unchanged): every free pose then lies within ``cover_m`` (+ 0.071 m, half the
    lattice's diagonal) of a place. Reproducible from ``seed``."""
    from factorloc.places import Place, PlaceMap

    spacing = _check_spacing(spacing_m)
    cov = _place_covariance()
    rng = np.random.default_rng(seed)
    x0, y0, x1, y1 = world.bounds_xy
    xs = np.arange(x0 + spacing / 2, x1, spacing)
    ys = np.arange(y0 + spacing / 2, y1, spacing)
    grid = np.array([(x, y) for y in ys for x in xs])
    free = grid[world.is_free(grid, clearance_m)]
    if cover_m is not None:
        free = np.concatenate([free, covering_points(world, free, cover_m, clearance_m)])
    places = []
    for n, (x, y) in enumerate(free):
        T = Pose2(float(x), float(y), float(rng.uniform(-math.pi, math.pi)))
        scan = render_scan(world, T, rng=rng)
        pano = render_panorama(world, T, width_px=panorama_width_px) if panorama_width_px > 0 else None
        places.append(Place(f"g{n:03d}", Reference(panorama=pano, scan=scan, T_world_reference=T), T, cov))
    return PlaceMap(places)


# --------------------------------------------------------------------------
# Paths
# --------------------------------------------------------------------------
def _free_segment(world: World, a: np.ndarray, b: np.ndarray, clearance_m: float) -> bool:
    n = max(2, int(math.ceil(np.linalg.norm(b - a) / 0.05)) + 1)
    pts = a[None] + np.linspace(0.0, 1.0, n)[:, None] * (b - a)[None]
    return bool(np.all(world.is_free(pts, clearance_m)))


@dataclass(frozen=True, eq=False)
class _Grid:
    origin: np.ndarray
    resolution_m: float
    free: np.ndarray  # ny × nx

    @classmethod
    def of(cls, world: World, clearance_m: float, resolution_m: float) -> _Grid:
        x0, y0, x1, y1 = world.bounds_xy
        xs = np.arange(x0 + resolution_m / 2, x1, resolution_m)
        ys = np.arange(y0 + resolution_m / 2, y1, resolution_m)
        pts = np.array([(x, y) for y in ys for x in xs])
        free = np.concatenate([world.is_free(pts[i : i + 2000], clearance_m) for i in range(0, len(pts), 2000)])
        return cls(np.array([xs[0], ys[0]]), resolution_m, free.reshape(len(ys), len(xs)))

    def xy(self, cell: tuple[int, int]) -> np.ndarray:
        return self.origin + self.resolution_m * np.array([cell[1], cell[0]], dtype=np.float64)

    def nearest_free(self, xy: np.ndarray) -> tuple[int, int]:
        rows, cols = np.nonzero(self.free)
        if not len(rows):
            raise InputError("the world has no free cell at this clearance")
        centres = self.origin + self.resolution_m * np.column_stack([cols, rows])
        k = int(np.argmin(np.hypot(*(centres - xy).T)))
        return int(rows[k]), int(cols[k])


_MOVES = tuple((dr, dc, math.hypot(dr, dc)) for dr in (-1, 0, 1) for dc in (-1, 0, 1) if dr or dc)


def _astar(grid: _Grid, start: tuple[int, int], goal: tuple[int, int]) -> list[tuple[int, int]] | None:
    ny, nx = grid.free.shape
    g = {start: 0.0}
    parent: dict[tuple[int, int], tuple[int, int]] = {}
    heap = [(math.dist(start, goal), start)]
    done: set[tuple[int, int]] = set()
    while heap:
        _, cell = heapq.heappop(heap)
        if cell == goal:
            path = [cell]
            while path[-1] in parent:
                path.append(parent[path[-1]])
            return path[::-1]
        if cell in done:
            continue
        done.add(cell)
        for dr, dc, cost in _MOVES:
            nb = (cell[0] + dr, cell[1] + dc)
            if not (0 <= nb[0] < ny and 0 <= nb[1] < nx) or not grid.free[nb] or nb in done:
                continue
            if dr and dc and not (grid.free[cell[0] + dr, cell[1]] and grid.free[cell[0], cell[1] + dc]):
                continue  # no corner cutting
            cand = g[cell] + cost
            if cand < g.get(nb, math.inf):
                g[nb], parent[nb] = cand, cell
                heapq.heappush(heap, (cand + math.dist(nb, goal), nb))
    return None


def _plan(world: World, grid: _Grid, a_xy: np.ndarray, b_xy: np.ndarray, clearance_m: float) -> np.ndarray:
    cells = _astar(grid, grid.nearest_free(a_xy), grid.nearest_free(b_xy))
    if cells is None:
        raise InputError(f"no collision-free path from {a_xy.tolist()} to {b_xy.tolist()} in world '{world.name}'")
    pts = [a_xy, *(grid.xy(c) for c in cells[1:-1]), b_xy]
    out, i = [pts[0]], 0
    while i < len(pts) - 1:  # line-of-sight shortcut: the farthest point in a free straight line
        j = i + 1
        while j + 1 < len(pts) and _free_segment(world, pts[i], pts[j + 1], clearance_m):
            j += 1
        out.append(pts[j])
        i = j
    return np.array(out)


def plan_path(
    world: World, start_xy: Sequence[float], goal_xy: Sequence[float], clearance_m: float = 0.35, resolution_m: float = 0.1
) -> np.ndarray:
    """The shortest collision-free path from ``start_xy`` to ``goal_xy`` as K×2 waypoints (metres, world frame):
    A* on an 8-connected grid of ``resolution_m`` cells free at ``clearance_m`` (no corner cutting), shortened by
    line of sight (each waypoint the farthest point of the grid path reachable in a straight free line, checked at
    ``clearance_m - resolution_m``)."""
    a, b = np.asarray(start_xy, dtype=np.float64), np.asarray(goal_xy, dtype=np.float64)
    if a.shape != (2,) or b.shape != (2,):
        raise InputError(f"start_xy and goal_xy must be (x, y) pairs, got {start_xy!r} and {goal_xy!r}")
    for name, p in (("start_xy", a), ("goal_xy", b)):
        if not bool(world.is_free(p[None], clearance_m)[0]):
            raise InputError(
                f"{name} = {p.tolist()} is closer than clearance_m = {clearance_m} m to a surface of world '{world.name}'"
            )
    grid = _Grid.of(world, clearance_m, resolution_m)
    return _plan(world, grid, a, b, clearance_m - resolution_m)


# --------------------------------------------------------------------------
# Tours
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class TrackConfig:
    """How :func:`generate_track` tours a world and what it senses (metres, radians, seconds).

    ``query_spacing_m``: travel between two queries (a turn counts ``turn_weight_m_per_rad`` m/rad).
    ``clearance_m``: the robot's distance to every surface. ``faults``: per-query faults among
    :data:`TRACK_FAULTS` applied with probability ``fault_probability`` (``lighting``/``blur`` need panoramas).
    ``panorama_width_px``: 0 for laser-only queries, else a rendered 360° panorama of that width per query.
    ``query_period_s``: time between two queries (the timestamps).
    """

    query_spacing_m: float = 0.25
    turn_weight_m_per_rad: float = 0.3
    clearance_m: float = 0.35
    planner_resolution_m: float = 0.1
    faults: tuple[str, ...] = ("occlusion",)
    fault_probability: float = 0.1
    panorama_width_px: int = 0
    drift: DriftModel = field(default_factory=DriftModel)
    query_period_s: float = 1.0

    def __post_init__(self) -> None:
        for name in ("query_spacing_m", "clearance_m", "planner_resolution_m", "query_period_s"):
            v = getattr(self, name)
            if isinstance(v, bool) or not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise InputError(f"TrackConfig.{name} must be a finite number > 0, got {v!r}")
        if not (isinstance(self.turn_weight_m_per_rad, (int, float)) and self.turn_weight_m_per_rad >= 0):
            raise InputError(f"TrackConfig.turn_weight_m_per_rad must be >= 0, got {self.turn_weight_m_per_rad!r}")
        if self.planner_resolution_m >= self.clearance_m:
            raise InputError(
                f"TrackConfig.planner_resolution_m ({self.planner_resolution_m}) must be below clearance_m ({self.clearance_m})"
            )
        faults = tuple(self.faults)
        bad = [f for f in faults if f not in TRACK_FAULTS]
        if bad:
            raise InputError(f"TrackConfig.faults: unknown {bad} (a track applies {list(TRACK_FAULTS)} and 'kidnapped')")
        if self.panorama_width_px <= 0 and any(f in _PANORAMA_FAULTS for f in faults):
            raise InputError(
                f"TrackConfig.faults {[f for f in faults if f in _PANORAMA_FAULTS]} act on panoramas: set panorama_width_px"
            )
        object.__setattr__(self, "faults", faults)
        if not 0.0 <= self.fault_probability <= 1.0:
            raise InputError(f"TrackConfig.fault_probability must be in [0, 1], got {self.fault_probability!r}")
        if isinstance(self.panorama_width_px, bool) or not isinstance(self.panorama_width_px, int) or self.panorama_width_px < 0:
            raise InputError(f"TrackConfig.panorama_width_px must be an integer >= 0, got {self.panorama_width_px!r}")
        if not isinstance(self.drift, DriftModel):
            raise InputError(f"TrackConfig.drift must be a DriftModel, got {type(self.drift).__name__}")


class _Tour:
    """The rooms still to visit (a round), the planner's grid, the random stream."""

    def __init__(self, world: World, rng: np.random.Generator, config: TrackConfig) -> None:
        self.world, self.rng, self.config = world, rng, config
        self.rooms = dict(rooms(world))
        self.grid = _Grid.of(world, config.clearance_m, config.planner_resolution_m)
        self.todo: list[str] = []
        self.visited: list[str] = []

    def random_point(self, room: str, clearance_m: float) -> np.ndarray:
        x0, y0, x1, y1 = self.rooms[room]
        for _ in range(200):
            xy = np.column_stack([self.rng.uniform(x0, x1, 32), self.rng.uniform(y0, y1, 32)])
            ok = np.flatnonzero(self.world.is_free(xy, clearance_m))
            if len(ok):
                return xy[ok[0]]
        raise InputError(f"room '{room}' of world '{self.world.name}' has no free point at clearance {clearance_m} m")

    def next_room(self, here: np.ndarray, current: str | None) -> str:
        if not self.todo:
            self.todo = [r for r in self.rooms if r != current] or list(self.rooms)
        centres = {r: np.array([(b[0] + b[2]) / 2, (b[1] + b[3]) / 2]) for r, b in self.rooms.items()}
        near = sorted(self.todo, key=lambda r: float(np.hypot(*(centres[r] - here))))
        room = near[int(self.rng.integers(min(2, len(near))))]
        self.todo.remove(room)
        return room

    def path(self, start: Pose2, length_m: float) -> np.ndarray:
        """A dense N×3 tour from ``start`` of at least ``length_m`` (plus the last leg's remainder)."""
        wps: list = [start]
        here = start.translation
        current = room_of(self.world, here)[0]
        total = 0.0
        self.visited.append(current or "")
        while total < length_m:
            room = self.next_room(here, current)
            goal = self.random_point(room, self.config.clearance_m + 0.15)
            leg = _plan(self.world, self.grid, here, goal, self.config.clearance_m - self.config.planner_resolution_m)
            wps.extend((float(p[0]), float(p[1])) for p in leg[1:])
            total += float(np.sum(np.hypot(*np.diff(leg, axis=0).T)))
            here, current = goal, room
            self.visited.append(room)
        return waypoint_trajectory(wps, step_m=0.05, step_rad=0.05)


def tour_path(
    world: World, start: Pose2, length_m: float, seed: int, config: TrackConfig = TrackConfig()
) -> tuple[np.ndarray, tuple[str, ...]]:
    """A tour of the rooms from ``start`` of at least ``length_m`` (see the module): the dense N×3 true poses
    (≤ 5 cm, ≤ 0.05 rad apart) and the rooms in the order visited (the start's room first)."""
    if not isinstance(start, Pose2):
        raise InputError(f"start must be a Pose2, got {type(start).__name__}")
    if not bool(world.is_free(start.translation[None], config.clearance_m)[0]):
        raise InputError(
            f"start {start} is closer than clearance_m = {config.clearance_m} m to a surface of world '{world.name}'"
        )
    tour = _Tour(world, np.random.default_rng(seed), config)
    path = tour.path(start, float(length_m))
    return path, tuple(tour.visited)


def _sample_indices(path: np.ndarray, n: int, spacing_m: float, turn_weight: float) -> np.ndarray:
    """Indices of ``n`` samples of ``path`` every ``spacing_m`` of travel (turns weighted)."""
    steps = np.hypot(np.diff(path[:, 0]), np.diff(path[:, 1])) + turn_weight * np.abs(np.diff(np.unwrap(path[:, 2])))
    arc = np.concatenate([[0.0], np.cumsum(steps)])
    return np.minimum(np.searchsorted(arc, spacing_m * np.arange(n)), len(path) - 1)


def _kidnap_cuts(rng: np.random.Generator, n_queries: int, kidnaps: int) -> list[int]:
    if isinstance(kidnaps, bool) or not isinstance(kidnaps, int) or kidnaps < 0:
        raise InputError(f"kidnaps must be an integer >= 0, got {kidnaps!r}")
    if kidnaps and n_queries - 15 < kidnaps:
        raise InputError(f"{kidnaps} kidnappings need at least {kidnaps + 15} queries, got {n_queries}")
    return sorted(rng.choice(np.arange(10, n_queries - 5), size=kidnaps, replace=False).tolist()) if kidnaps else []


def _faulted_query(
    world: World, truth: Pose2, rng: np.random.Generator, config: TrackConfig, odometry: Odometry, qid: str
) -> tuple[Query, tuple[str, ...], dict[str, Any]]:
    """One query at ``truth``: its scan (and panorama), with the faults drawn for it."""
    tags: tuple[str, ...] = ()
    meta: dict[str, Any] = {}
    if config.faults and rng.random() < config.fault_probability:
        tags = (config.faults[int(rng.integers(len(config.faults)))],)
    occluders: tuple = ()
    if "occlusion" in tags:
        yaw = float(rng.uniform(-math.pi, math.pi))
        occluders = place_occluders(world, truth, rng, n=int(rng.integers(1, 3)), view_yaw_rad=yaw)
        meta["occluders"] = [o.name for o in occluders]
    scan = render_scan(world, truth, rng=rng, occluders=occluders)
    pano = None
    if config.panorama_width_px > 0:
        pano = render_panorama(world, truth, width_px=config.panorama_width_px, occluders=occluders)
        img = pano.image_bgr
        if "lighting" in tags:
            gain, gamma, shadows = float(rng.uniform(0.45, 1.6)), float(rng.uniform(0.6, 1.6)), int(rng.integers(0, 3))
            img = relight(img, gain, gamma, shadows, rng)
            meta["lighting"] = {"gain": gain, "gamma": gamma, "shadows": shadows}
        if "blur" in tags:
            length = float(rng.uniform(6.0, 20.0))
            img = motion_blur(img, length, 0.0)
            meta["blur"] = {"length_px": length}
        if img is not pano.image_bgr:
            pano = replace(pano, image_bgr=img)
    return Query(panorama=pano, scan=scan, odometry=odometry, id=qid), tags, meta


def _visits(rooms_of_queries: Sequence[str | None]) -> list[str]:
    """The rooms the queries were in, in order, a run of queries in one room counted once."""
    out: list[str] = []
    for r in rooms_of_queries:
        if r is not None and (not out or out[-1] != r):
            out.append(r)
    return out


def _kidnap_pose(tour: _Tour, current: str | None) -> Pose2:
    others = [r for r in tour.rooms if r != current] or list(tour.rooms)
    room = others[int(tour.rng.integers(len(others)))]
    xy = tour.random_point(room, tour.config.clearance_m + 0.15)
    return Pose2(float(xy[0]), float(xy[1]), float(tour.rng.uniform(-math.pi, math.pi)))


@deterministic
def generate_track(
    world: World | str,
    place_map: PlaceMap,
    n_queries: int,
    seed: int,
    *,
    kidnaps: int = 0,
    config: TrackConfig = TrackConfig(),
    name: str | None = None,
    progress: Callable[[int, int], None] | None = None,
) -> Scenario:
    """A robot touring the rooms of ``world`` (see the module): a :class:`~factorloc.datasets.Scenario` whose
    references are ``place_map``'s places and whose ``n_queries`` queries, in time order, carry one continuous
    odometry run, the truth, the room (``metadata["room"]``) and each its nearest place as ``reference_id``; the
    scenario's ``metadata["rooms_visited"]`` lists the rooms the queries were in, in order.

    The tour starts at a random free pose; ``kidnaps`` times (between queries 10 and ``n_queries`` − 5) the robot
    is carried to a random free pose of another room (tag ``kidnapped`` on the first query after it). Reproducible
    from ``seed``. ``progress(done, total)`` is called after each query (the CLI's progress bar).
    """
    from factorloc.datasets import Scenario, ScenarioQuery, ScenarioReference
    from factorloc.sim.world import world_by_name

    w = world_by_name(world) if isinstance(world, str) else world
    if not isinstance(w, World):
        raise InputError(f"world must be a factorloc.sim.World or a world name/file, got {type(world).__name__}")
    if isinstance(n_queries, bool) or not isinstance(n_queries, int) or n_queries < 2:
        raise InputError(f"n_queries must be an integer >= 2, got {n_queries!r}")
    from factorloc.places import PlaceMap

    if not isinstance(place_map, PlaceMap):
        raise InputError(f"place_map must be a factorloc.PlaceMap, got {type(place_map).__name__}")
    if not len(place_map):
        raise InputError("place_map has no places")
    rng = np.random.default_rng(seed)
    cuts = _kidnap_cuts(rng, n_queries, kidnaps)
    tour = _Tour(w, rng, config)
    bounds = [0, *cuts, n_queries]
    pos, ids = place_map.positions_m(), place_map.ids
    start = _kidnap_pose(tour, None)
    queries: list = []
    odo_end: Pose2 | None = None
    for s, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        n = b - a
        path = tour.path(start, config.query_spacing_m * n + 0.5)
        idx = _sample_indices(path, n, config.query_spacing_m, config.turn_weight_m_per_rad)
        run = simulate_odometry(path[: idx[-1] + 1], rng, config.drift)
        T0 = Pose2.from_array(run.poses[0])
        for j, i in enumerate(idx):
            truth = Pose2.from_array(path[i])
            rel = T0.between(Pose2.from_array(run.poses[i]))
            o = run.odometry(int(i), model=config.drift)
            odo = Odometry(rel if odo_end is None else odo_end.compose(rel), o.sigma_x_m, o.sigma_y_m, o.sigma_theta_rad)
            k = a + j
            q, tags, meta = _faulted_query(w, truth, rng, config, odo, f"q{k:04d}")
            if s > 0 and j == 0:
                tags = ("kidnapped", *tags)
            meta["room"] = room_of(w, truth.translation)[0]
            nearest = ids[int(np.argmin(np.hypot(*(pos - truth.translation).T)))]
            queries.append(ScenarioQuery(q, config.query_period_s * k, truth, tags, nearest, metadata=meta))
            if progress is not None:
                progress(k + 1, n_queries)
        odo_end = queries[-1].query.odometry.T_world_robot
        start = _kidnap_pose(tour, room_of(w, path[idx[-1], :2])[0])
    from factorloc.places.placemap import PLACE_COVARIANCE_KEY

    refs = tuple(
        ScenarioReference(p.id, p.reference, {} if p.covariance is None else {PLACE_COVARIANCE_KEY: p.covariance.tolist()})
        for p in place_map
    )
    meta = {
        "generator": "factorloc.sim.generate_track",
        "n_queries": n_queries,
        "kidnaps": kidnaps,
        "query_spacing_m": config.query_spacing_m,
        "faults": list(config.faults),
        "fault_probability": config.fault_probability,
        "panorama_width_px": config.panorama_width_px,
        "rooms_visited": _visits([q.metadata["room"] for q in queries]),
    }
    return Scenario(
        name or f"{w.name}-track-seed{seed}",
        refs,
        tuple(queries),
        world=w,
        seed=seed,
        description=f"a tour of world '{w.name}' by factorloc.sim.generate_track"
        f"(n_queries={n_queries}, seed={seed}, kidnaps={kidnaps})",
        metadata=meta,
    )


# --------------------------------------------------------------------------
# Random legs (the first simulated drive)
# --------------------------------------------------------------------------
def _leg(world: World, start: Pose2, length_m: float, rng: np.random.Generator, clearance_m: float) -> np.ndarray:
    """A collision-free waypoint path of at least ``length_m`` from ``start`` (N×3, ≤ 5 cm apart)."""
    wps: list = [start]
    here, total = start.translation, 0.0
    while total < length_m:
        for _ in range(4000):
            r, a = rng.uniform(0.5, 4.0), rng.uniform(-math.pi, math.pi)
            p = here + r * np.array([math.cos(a), math.sin(a)])
            if bool(world.is_free(p[None], clearance_m)[0]) and _free_segment(world, here, p, clearance_m):
                break
        else:
            raise InputError(f"no reachable waypoint within 4 m of {here.tolist()} after 4000 draws")
        total += float(np.linalg.norm(p - here))
        wps.append((float(p[0]), float(p[1])))
        here = p
    return waypoint_trajectory(wps, step_m=0.05, step_rad=0.05)


def random_track(
    world: World,
    place_map: PlaceMap,
    n_queries: int,
    seed: int,
    *,
    kidnaps: int = 0,
    spacing_m: float = 0.25,
    clearance_m: float = 0.35,
) -> Scenario:
    """A robot driving random legs through a simulated world (no tour: :func:`generate_track` visits the rooms), a
    360° laser scan every ``spacing_m`` of travel (turns count 0.3 m/rad): a :class:`~factorloc.datasets.Scenario`
    whose references are ``place_map``'s places and whose queries, in time order, carry one continuous odometry run
    (restarted from the odometry's last pose after a kidnapping so that the odometry does not see it) and the truth.

    ``kidnaps`` times the robot is carried to a random free pose between two queries (tag ``kidnapped`` on the
    first query after it). Each query names its nearest place as ``reference_id``. Reproducible from ``seed``.
    """
    from factorloc.datasets import Scenario, ScenarioQuery, ScenarioReference

    rng = np.random.default_rng(seed)
    if n_queries < 2:
        raise InputError(f"n_queries must be >= 2, got {n_queries!r}")
    cuts = sorted(rng.choice(np.arange(10, n_queries - 5), size=kidnaps, replace=False).tolist()) if kidnaps else []
    bounds = [0, *cuts, n_queries]
    pos = place_map.positions_m()
    queries = []
    odo_end: Pose2 | None = None
    start = sample_free_pose(world, rng, clearance_m)
    for s, (a, b) in enumerate(zip(bounds[:-1], bounds[1:], strict=True)):
        n = b - a
        path = _leg(world, start, spacing_m * n + 1.0, rng, clearance_m)
        idx = _sample_indices(path, n, spacing_m, 0.3)
        run = simulate_odometry(path[: idx[-1] + 1], rng)
        T0 = Pose2.from_array(run.poses[0])
        for j, i in enumerate(idx):
            truth = Pose2.from_array(path[i])
            rel = T0.between(Pose2.from_array(run.poses[i]))
            T_odo = rel if odo_end is None else odo_end.compose(rel)
            o = run.odometry(int(i))
            k = a + j
            q = Query(
                scan=render_scan(world, truth, rng=rng),
                odometry=Odometry(T_odo, o.sigma_x_m, o.sigma_y_m, o.sigma_theta_rad),
                id=f"q{k:04d}",
            )
            nearest = place_map.ids[int(np.argmin(np.hypot(*(pos - truth.translation).T)))]
            faults = ("kidnapped",) if (s > 0 and j == 0) else ()
            queries.append(ScenarioQuery(q, float(k), truth, faults, nearest))
        odo_end = queries[-1].query.odometry.T_world_robot
        start = sample_free_pose(world, rng, clearance_m)
    refs = tuple(ScenarioReference(p.id, p.reference) for p in place_map)
    return Scenario(f"track-{seed}", refs, tuple(queries), seed=seed, metadata={"kidnaps": kidnaps, "spacing_m": spacing_m})

"""Scenarios along one continuous trajectory, for the sequential strategies.

:func:`factorloc.sim.generate_scenario` draws *independent* queries: each is
reached from its own exact odometry reset, so the odometry of one query says
nothing about the next. Smoothers and filters need the opposite: one robot
driving, queried every ``spacing_m`` metres, with one odometry run whose
drift keeps growing. :func:`generate_trajectory_scenario` renders that with
the simulator's public pieces (same reference, cameras, depth camera, scan and
fault models as :func:`~factorloc.sim.generate_scenario`):

* the path visits random free waypoints within ``max_distance_m`` of the
  reference, in line of sight of it (so the visual and ICP steps can work);
* the odometry is one run (:func:`factorloc.sim.motion.simulate_odometry`), σ growing all along;
* ``kidnaps`` times the robot is carried 0.7–2 m to another free pose between
  two queries (tag ``kidnapped`` on the first query after it): the odometry
  does not know and carries on from where it thought it was;
* other faults (``occlusion``, ``lighting``, ``blur``, ``depth_dropout``,
  ``glass``) hit single queries with probability ``fault_probability``;
* ``no_depth_stretches`` are index ranges of queries without cloud and scan
  (tag ``no_depth``): only heading steps and odometry are available there.

Reproducible from ``seed``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import replace
from typing import Any

import numpy as np

from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.sim.faults import depth_dropout, most_seen_face, motion_blur, place_occluders, relight
from factorloc.sim.generate import GeneratorConfig, render_reference
from factorloc.sim.laser import render_scan
from factorloc.sim.motion import simulate_odometry, waypoint_trajectory
from factorloc.sim.render import render_camera, render_cloud
from factorloc.sim.world import World
from factorloc.types import Odometry, PointCloud, Query

#: Per-query faults :func:`generate_trajectory_scenario` can apply (besides ``kidnapped`` and ``no_depth``).
QUERY_FAULTS = ("occlusion", "lighting", "blur", "depth_dropout", "glass")


def _free_segment(world: World, a: np.ndarray, b: np.ndarray, clearance_m: float) -> bool:
    n = max(2, int(math.ceil(np.linalg.norm(b - a) / 0.05)) + 1)
    pts = a[None] + np.linspace(0.0, 1.0, n)[:, None] * (b - a)[None]
    return bool(np.all(world.is_free(pts, clearance_m)))


def _waypoint(world: World, ref: Pose2, here: np.ndarray, rng: np.random.Generator, max_d: float, cl: float) -> np.ndarray:
    for _ in range(2000):
        r = math.sqrt(rng.uniform(0.3**2, max_d**2))
        a = rng.uniform(-math.pi, math.pi)
        p = np.array([ref.x + r * math.cos(a), ref.y + r * math.sin(a)])
        if np.linalg.norm(p - here) < 0.8 or not bool(world.is_free(p[None], cl)[0]):
            continue
        if not bool(world.line_of_sight(ref.translation[None], p[None])[0]):
            continue
        if _free_segment(world, here, p, cl * 0.8):
            return p
    raise InputError(f"no reachable free waypoint within {max_d} m of the reference from {here.tolist()} in world '{world.name}'")


def _leg(
    world: World, ref: Pose2, start: Pose2, length_m: float, rng: np.random.Generator, max_d: float, cl: float
) -> np.ndarray:
    """A waypoint path of at least ``length_m`` from ``start`` (N×3, a few cm apart)."""
    wps: list = [start]
    here = start.translation
    total = 0.0
    while total < length_m:
        p = _waypoint(world, ref, here, rng, max_d, cl)
        total += float(np.linalg.norm(p - here))
        wps.append((float(p[0]), float(p[1])))
        here = p
    return waypoint_trajectory(wps, step_m=0.05, step_rad=0.05)


def _arc_samples(path: np.ndarray, spacing_m: float, n: int) -> np.ndarray:
    """Indices of ``n`` samples of ``path`` every ``spacing_m`` of travel (also counting turns as 0.3 m/rad)."""
    steps = np.hypot(np.diff(path[:, 0]), np.diff(path[:, 1])) + 0.3 * np.abs(np.diff(np.unwrap(path[:, 2])))
    s = np.concatenate([[0.0], np.cumsum(steps)])
    targets = spacing_m * np.arange(n)
    idx = np.searchsorted(s, targets, side="left")
    return np.minimum(idx, len(path) - 1)


def generate_trajectory_scenario(
    world: World | str,
    n_queries: int,
    seed: int,
    *,
    spacing_m: float = 0.5,
    max_distance_m: float = 3.0,
    kidnaps: int = 0,
    faults: Sequence[str] = (),
    fault_probability: float = 0.2,
    no_depth_stretches: Sequence[tuple[int, int]] = (),
    config: GeneratorConfig = GeneratorConfig(),
    name: str | None = None,
):  # -> factorloc.datasets.Scenario
    """A scenario of ``n_queries`` consecutive queries along one continuous trajectory (see the module docstring).

    Parameters
    ----------
    world
        A :class:`~factorloc.sim.World` or a built-in world name.
    n_queries, seed
        Number of queries; seed of every random draw.
    spacing_m
        Travel between consecutive queries (m; turning in place counts 0.3 m per rad).
    max_distance_m
        Waypoints stay within this distance of the reference (m).
    kidnaps
        How many times the robot is carried away without the odometry knowing.
    faults
        Per-query faults (a subset of :data:`QUERY_FAULTS`).
    fault_probability
        The probability of a fault per query.
    no_depth_stretches
        ``(first, last)`` query index ranges (inclusive) without depth cloud and scan.
    config
        Rendering settings (reference, cameras, drift) as for :func:`~factorloc.sim.generate_scenario`.
    """
    from factorloc.datasets.scenario import Scenario, ScenarioReference

    world = _checked_world(world)
    _check_arguments(n_queries, kidnaps, faults, spacing_m)
    rng = np.random.default_rng([seed, 7])
    reference = render_reference(world, config, seed)
    truths, odos, kidnapped = _trajectory(
        world, reference.T_world_reference, n_queries, kidnaps, spacing_m, max_distance_m, config, rng
    )
    no_depth = {i for lo, hi in no_depth_stretches for i in range(int(lo), int(hi) + 1)}
    faulting = (tuple(faults), fault_probability)
    queries = [
        _query(world, reference.T_world_reference, i, truth, odo, seed, config, faulting, i in kidnapped, i in no_depth)
        for i, (truth, odo) in enumerate(zip(truths, odos, strict=True))
    ]
    return Scenario(
        name=name or f"{world.name}-trajectory-seed{seed}",
        references=(ScenarioReference("ref0", reference, {"height_m": config.panorama_height_m}),),
        queries=tuple(queries),
        world=world,
        seed=seed,
        description=(
            f"one continuous trajectory in world '{world.name}' by factorloc.baselines.trajectory."
            f"generate_trajectory_scenario(n_queries={n_queries}, seed={seed}, kidnaps={kidnaps})"
        ),
        metadata={
            "generator": "factorloc.baselines.generate_trajectory_scenario",
            "continuous_odometry": True,
            "spacing_m": spacing_m,
        },
    )


def _checked_world(world: World | str) -> World:
    if isinstance(world, str):
        from factorloc.sim.world import world_by_name

        world = world_by_name(world)
    if not isinstance(world, World):
        raise InputError(f"world must be a factorloc.sim.World or a world name, got {type(world).__name__}")
    return world


def _check_arguments(n_queries: int, kidnaps: int, faults: Sequence[str], spacing_m: float) -> None:
    if isinstance(n_queries, bool) or not isinstance(n_queries, int) or n_queries < 1:
        raise InputError(f"n_queries must be a positive integer, got {n_queries!r}")
    if isinstance(kidnaps, bool) or not isinstance(kidnaps, int) or not 0 <= kidnaps < n_queries:
        raise InputError(f"kidnaps must be an integer in [0, n_queries), got {kidnaps!r}")
    unknown = [f for f in faults if f not in QUERY_FAULTS]
    if unknown:
        raise InputError(f"unknown fault(s) {unknown}; known: {QUERY_FAULTS} (plus kidnaps= and no_depth_stretches=)")
    if not spacing_m > 0:
        raise InputError(f"spacing_m must be > 0, got {spacing_m!r}")


def _kidnap_start(world: World, ref: Pose2, last: Pose2, rng: np.random.Generator, clearance_m: float) -> Pose2:
    """Where a kidnapped robot is carried: 0.7–2 m from where the last leg ended, free and seen from the reference."""
    for _ in range(500):
        d, a = rng.uniform(0.7, 2.0), rng.uniform(-math.pi, math.pi)
        p = np.array([last.x + d * math.cos(a), last.y + d * math.sin(a)])
        if bool(world.is_free(p[None], clearance_m)[0]) and bool(world.line_of_sight(ref.translation[None], p[None])[0]):
            return Pose2(float(p[0]), float(p[1]), last.theta + rng.uniform(-1.0, 1.0))
    raise InputError(f"no free pose to carry the kidnapped robot to near {last}")


def _trajectory(
    world: World,
    ref: Pose2,
    n_queries: int,
    kidnaps: int,
    spacing_m: float,
    max_distance_m: float,
    config: GeneratorConfig,
    rng: np.random.Generator,
) -> tuple[list[Pose2], list[Odometry], set[int]]:
    """The true poses, the odometry and the kidnapped query indices along the legs of one run.

    Kidnap points split the run into legs; each leg is a continuous path, and the odometry carries on from
    where it believed the robot was.
    """
    cuts = (
        sorted(rng.choice(np.arange(max(1, n_queries // 4), n_queries), size=kidnaps, replace=False).tolist()) if kidnaps else []
    )
    bounds = [0, *cuts, n_queries]
    truths: list[Pose2] = []
    odos: list[Odometry] = []
    kidnapped: set[int] = set()
    T_odo_end: Pose2 | None = None
    var_end = np.zeros(3)
    start = Pose2(ref.x + 0.3, ref.y, float(rng.uniform(-math.pi, math.pi)))
    for leg_i in range(len(bounds) - 1):
        n_leg = bounds[leg_i + 1] - bounds[leg_i]
        if leg_i > 0:
            start = _kidnap_start(world, ref, truths[-1], rng, config.clearance_m)
            kidnapped.add(bounds[leg_i])
        path = _leg(world, ref, start, spacing_m * (n_leg + 1) + 1.0, rng, max_distance_m, config.clearance_m)
        run = simulate_odometry(path, rng, config.drift)
        idx = _arc_samples(path, spacing_m, n_leg)
        start0 = Pose2.from_array(path[0])
        for i in idx:
            truths.append(Pose2.from_array(path[i]))
            o = run.odometry(int(i), model=config.drift)
            if T_odo_end is None:
                odos.append(o)
            else:
                rel = start0.between(o.T_world_robot)
                var = var_end + np.array([o.sigma_x_m, o.sigma_y_m, o.sigma_theta_rad]) ** 2
                odos.append(Odometry(T_odo_end.compose(rel), *np.sqrt(var)))
        T_odo_end = odos[-1].T_world_robot
        var_end = np.array([odos[-1].sigma_x_m, odos[-1].sigma_y_m, odos[-1].sigma_theta_rad]) ** 2
        start = Pose2.from_array(path[idx[-1]])
    return truths, odos, kidnapped


def _images(
    world: World, truth: Pose2, config: GeneratorConfig, tags: list[str], occluders: Any, qrng: np.random.Generator
) -> list:
    images = []
    for yaw in config.image_yaws_rad:
        im = render_camera(world, truth, replace(config.camera, yaw_in_robot_rad=float(yaw)), occluders=occluders)
        img = im.image_bgr
        if "lighting" in tags:
            img = relight(img, float(qrng.uniform(0.45, 1.6)), float(qrng.uniform(0.6, 1.6)), int(qrng.integers(0, 3)), qrng)
        if "blur" in tags:
            img = motion_blur(img, float(qrng.uniform(6.0, 20.0)), float(qrng.uniform(-0.3, 0.3)))
        if img is not im.image_bgr:
            im = type(im)(img, im.hfov_rad, im.yaw_in_robot_rad, im.pitch_rad, im.cx_px)
        images.append(im)
    return images


def _depth(
    world: World,
    truth: Pose2,
    config: GeneratorConfig,
    tags: list[str],
    occluders: Any,
    glass: tuple[int, ...],
    qrng: np.random.Generator,
) -> tuple[PointCloud | None, Any]:
    try:
        cloud = render_cloud(world, truth, config.depth_camera, qrng, occluders=occluders, glass_faces=glass)
    except InputError:
        cloud = None
    if "depth_dropout" in tags and cloud is not None:
        cloud = PointCloud(depth_dropout(cloud.points_m, qrng, float(qrng.uniform(0.1, 0.3)), int(qrng.integers(2, 6))))
    scan = (
        render_scan(world, truth, config.scan_beams, config.scan_height_m, rng=qrng, occluders=occluders) if config.scan else None
    )
    return cloud, scan


def _query(
    world: World,
    ref: Pose2,
    i: int,
    truth: Pose2,
    odo: Odometry,
    seed: int,
    config: GeneratorConfig,
    faulting: tuple[tuple[str, ...], float],
    kidnapped: bool,
    no_depth: bool,
) -> Any:
    """Query ``i`` of the run (id ``t<i>``), rendered at ``truth`` with its faults drawn from its own generator."""
    from factorloc.datasets.scenario import ScenarioQuery

    faults, fault_probability = faulting
    qrng = np.random.default_rng([seed, 1000 + i])
    tags: list[str] = ["kidnapped"] if kidnapped else []
    if faults and qrng.random() < fault_probability:
        tags.append(faults[int(qrng.integers(len(faults)))])
    occluders = ()
    if "occlusion" in tags:
        occluders = place_occluders(world, truth, qrng, n=int(qrng.integers(1, 3)), view_yaw_rad=float(config.image_yaws_rad[0]))
    glass: tuple[int, ...] = ()
    if "glass" in tags:
        f = most_seen_face(world, truth, config.depth_camera.yaw_in_robot_rad)
        glass = () if f is None else (f,)
    images = _images(world, truth, config, tags, occluders, qrng)
    cloud = scan = None
    if no_depth:
        tags.append("no_depth")
    else:
        cloud, scan = _depth(world, truth, config, tags, occluders, glass, qrng)
    return ScenarioQuery(
        query=Query(tuple(images), None, cloud, scan, odo, f"t{i:04d}"),
        timestamp_s=float(i),
        truth=truth,
        faults=tuple(tags),
        reference_id="ref0",
        distance_from_reference_m=math.dist((truth.x, truth.y), (ref.x, ref.y)),
        metadata={},
    )


__all__ = ["QUERY_FAULTS", "generate_trajectory_scenario"]

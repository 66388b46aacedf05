"""Generate a localization scenario in a simulated world, reproducibly from a seed.

:func:`generate_scenario` renders one reference (a 360° panorama, a 360° depth
cloud, a laser scan) at the world's ``"reference"`` region and ``n_queries``
queries around it. Every query draws from its own random stream,
``numpy.random.default_rng([seed, i])``, so the same seed gives bit-for-bit
the same scenario and any query can be regenerated alone
(``only_queries=[i]``).

Per query: the true pose is a free pose at a distance from the reference
drawn from ``distance_bands_m`` (varied difficulty); the robot reached it by
a random walk of ``path_length_range_m`` from an exact odometry reset, so the
odometry has drifted (:func:`factorloc.sim.motion.simulate_odometry`, honest
σ); it takes ``len(config.image_yaws_rad)`` camera images, a depth cloud and
a scan. With probability ``fault_probability`` one fault (sometimes two) of
``faults`` is applied (see :mod:`factorloc.sim.faults`):

``kidnapped``      pushed 0.7–2 m after its last odometry step: the odometry does not know
``occlusion``      1–2 people/boxes in view that the reference does not have
``lighting``       gain 0.45–1.6, gamma 0.6–1.6, 0–2 shadows on the camera images
``blur``           motion blur 6–20 px on the camera images
``depth_dropout``  10–30 % of the depth returns missing, plus 2–5 holes
``glass``          the wall face most in view is glass: no depth return from it
``corridor``       the pose is in the world's ``"corridor"`` region, facing a side wall
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from factorloc.errors import InputError
from factorloc.geometry import Pose2, wrap_angle
from factorloc.sim.determinism import deterministic
from factorloc.sim.faults import depth_dropout, most_seen_face, motion_blur, place_occluders, relight
from factorloc.sim.laser import render_scan
from factorloc.sim.motion import DriftModel, random_walk, simulate_odometry
from factorloc.sim.render import (
    DepthCamera,
    PinholeCamera,
    render_camera,
    render_cloud,
    render_cloud_360,
    render_panorama,
)
from factorloc.sim.world import World
from factorloc.types import Odometry, PointCloud, Query, Reference

#: The fault names :func:`generate_scenario` understands.
FAULTS = ("kidnapped", "occlusion", "lighting", "blur", "depth_dropout", "glass", "corridor")


@dataclass(frozen=True)
class GeneratorConfig:
    """What :func:`generate_scenario` renders and how it draws the queries.

    Distances in metres, angles in radians. ``reference_pose`` None: the centre
    of the world's ``"reference"`` region, heading 0 (else the centre of the
    bounds). ``distance_bands_m``: (min, max) bands of distance from the
    reference, drawn in turn so the difficulty varies evenly.
    """

    reference_pose: Pose2 | None = None
    panorama_width_px: int = 2048
    panorama_height_px: int = 256
    panorama_fov_v_rad: float = math.radians(60.0)
    panorama_height_m: float = 1.0
    camera: PinholeCamera = field(default_factory=PinholeCamera)
    image_yaws_rad: tuple[float, ...] = (0.0,)
    depth_camera: DepthCamera = field(default_factory=lambda: DepthCamera(stride_px=4))
    reference_depth_camera: DepthCamera = field(default_factory=lambda: DepthCamera(stride_px=5))
    scan: bool = True
    scan_beams: int = 360
    scan_height_m: float = 0.3
    distance_bands_m: tuple[tuple[float, float], ...] = ((0.2, 1.0), (1.0, 2.0), (2.0, 3.5))
    path_length_range_m: tuple[float, float] = (0.5, 6.0)
    clearance_m: float = 0.4
    require_line_of_sight: bool = True
    fault_probability: float = 0.3
    drift: DriftModel = field(default_factory=DriftModel)
    query_period_s: float = 5.0

    def __post_init__(self) -> None:
        if self.reference_pose is not None and not isinstance(self.reference_pose, Pose2):
            raise InputError(f"GeneratorConfig.reference_pose must be a Pose2 or None, got {type(self.reference_pose).__name__}")
        if not 0.0 <= self.fault_probability <= 1.0:
            raise InputError(f"GeneratorConfig.fault_probability must be in [0, 1], got {self.fault_probability}")
        if not self.distance_bands_m or any(not (0 <= lo < hi) for lo, hi in self.distance_bands_m):
            raise InputError(f"GeneratorConfig.distance_bands_m must be non-empty (min, max) pairs, got {self.distance_bands_m}")
        lo, hi = self.path_length_range_m
        if not 0 <= lo <= hi:
            raise InputError(
                f"GeneratorConfig.path_length_range_m must be (min, max) with 0 <= min <= max, got {self.path_length_range_m}"
            )
        if not self.image_yaws_rad:
            raise InputError("GeneratorConfig.image_yaws_rad must hold at least one camera yaw")


def reference_pose_of(world: World, config: GeneratorConfig = GeneratorConfig()) -> Pose2:
    """Where the reference is taken (see :class:`GeneratorConfig`)."""
    if config.reference_pose is not None:
        return config.reference_pose
    box = world.region("reference")
    if box is None:
        x0, y0, x1, y1 = world.bounds_xy
    else:
        x0, y0, x1, y1 = box
    return Pose2(0.5 * (x0 + x1), 0.5 * (y0 + y1), 0.0)


def render_reference(world: World, config: GeneratorConfig, seed: int) -> Reference:
    """The reference: panorama, 360° cloud and scan at :func:`reference_pose_of` (noise from ``[seed, -1]``)."""
    T = reference_pose_of(world, config)
    rng = np.random.default_rng([seed, 2**31])
    pano = render_panorama(
        world, T, config.panorama_height_m, config.panorama_width_px, config.panorama_fov_v_rad, config.panorama_height_px
    )
    cloud = render_cloud_360(world, T, config.reference_depth_camera, rng)
    scan = render_scan(world, T, config.scan_beams, config.scan_height_m, rng=rng) if config.scan else None
    return Reference(pano, cloud, scan, T, "reference")


def _pick_faults(rng: np.random.Generator, faults: Sequence[str], p: float) -> tuple[str, ...]:
    if not faults or rng.random() >= p:
        return ()
    chosen = [faults[int(rng.integers(len(faults)))]]
    if len(faults) > 1 and rng.random() < 0.25:
        other = [f for f in faults if f not in chosen]
        chosen.append(other[int(rng.integers(len(other)))])
    return tuple(sorted(chosen, key=FAULTS.index))


def _query_pose(
    world: World, ref: Pose2, rng: np.random.Generator, band: tuple[float, float], cfg: GeneratorConfig, corridor: bool
) -> Pose2:
    if corridor:
        box = world.region("corridor")
        if box is None:
            raise InputError(f"the 'corridor' fault needs a 'corridor' region in world '{world.name}'")
        for _ in range(200):
            x, y = rng.uniform(box[0], box[2]), rng.uniform(box[1], box[3])
            if bool(world.is_free(np.array([[x, y]]), cfg.clearance_m)[0]):
                side = math.pi / 2 if rng.random() < 0.5 else -math.pi / 2
                return Pose2(x, y, side + rng.normal(0.0, 0.05))
        raise InputError(f"no free pose in the 'corridor' region of world '{world.name}'")
    lo, hi = band
    for _ in range(400):
        r = math.sqrt(rng.uniform(lo * lo, hi * hi))
        a = rng.uniform(-math.pi, math.pi)
        xy = np.array([[ref.x + r * math.cos(a), ref.y + r * math.sin(a)]])
        if not bool(world.is_free(xy, cfg.clearance_m)[0]):
            continue
        if cfg.require_line_of_sight and not bool(world.line_of_sight(ref.translation[None], xy)[0]):
            continue
        return Pose2(float(xy[0, 0]), float(xy[0, 1]), float(rng.uniform(-math.pi, math.pi)))
    raise InputError(f"no free pose {lo}–{hi} m from the reference {ref} in world '{world.name}'")


def _path_to(world: World, goal: Pose2, length_m: float, rng: np.random.Generator, cfg: GeneratorConfig) -> np.ndarray:
    """A trajectory of ``length_m`` that ends at ``goal`` (a random walk away from it, reversed)."""
    away = random_walk(world, Pose2(goal.x, goal.y, goal.theta + math.pi), length_m, rng, clearance_m=0.3)
    path = away[::-1].copy()
    path[:, 2] = wrap_angle(path[:, 2] + math.pi)
    return path


def generate_query(
    world: World, reference: Reference, config: GeneratorConfig, seed: int, index: int, faults: Sequence[str]
) -> dict:
    """Query ``index`` of the scenario of ``seed`` (its own random stream ``[seed, index]``).

    Returns the keyword arguments of a :class:`factorloc.datasets.ScenarioQuery`
    (``query``, ``timestamp_s``, ``truth``, ``faults``, ``reference_id``,
    ``distance_from_reference_m``, ``metadata``).
    """
    rng = np.random.default_rng([seed, index])
    cfg = config
    T_ref = reference.T_world_reference
    tags = _pick_faults(rng, faults, cfg.fault_probability)
    band = cfg.distance_bands_m[index % len(cfg.distance_bands_m)]
    truth = _query_pose(world, T_ref, rng, band, cfg, "corridor" in tags)
    meta: dict = {"distance_band_m": list(band)}
    odometry = _odometry(world, truth, tags, rng, cfg, meta, index)
    occluders = ()
    if "occlusion" in tags:
        occluders = place_occluders(world, truth, rng, n=int(rng.integers(1, 3)), view_yaw_rad=float(cfg.image_yaws_rad[0]))
        meta["occluders"] = [o.name for o in occluders]
    glass_faces: tuple[int, ...] = ()
    if "glass" in tags:
        f = most_seen_face(world, truth, cfg.depth_camera.yaw_in_robot_rad)
        glass_faces = () if f is None else (f,)
        meta["glass_faces"] = list(glass_faces)
    images = _images(world, truth, tags, occluders, rng, cfg, meta)
    cloud = _cloud(world, truth, tags, occluders, glass_faces, rng, cfg, meta)
    scan = render_scan(world, truth, cfg.scan_beams, cfg.scan_height_m, rng=rng, occluders=occluders) if cfg.scan else None
    qid = f"q{index:04d}"
    return {
        "query": Query(tuple(images), None, cloud, scan, odometry, qid),
        "timestamp_s": cfg.query_period_s * (index + 1),
        "truth": truth,
        "faults": tags,
        "reference_id": "ref0",
        "distance_from_reference_m": math.dist((truth.x, truth.y), (T_ref.x, T_ref.y)),
        "metadata": meta,
    }


def _odometry(
    world: World, truth: Pose2, tags: Sequence[str], rng: np.random.Generator, cfg: GeneratorConfig, meta: dict, index: int
) -> Odometry:
    """The odometry of a query reached along a random path from its reset (a kidnapped robot: to a pose nearby)."""
    length = float(rng.uniform(*cfg.path_length_range_m))
    if "kidnapped" in tags:
        # the robot drove to a pose 0.7–2 m away, then was pushed/carried to the true pose
        for _ in range(100):
            d, a = rng.uniform(0.7, 2.0), rng.uniform(-math.pi, math.pi)
            before = Pose2(truth.x + d * math.cos(a), truth.y + d * math.sin(a), truth.theta + rng.uniform(-1.2, 1.2))
            if bool(world.is_free(before.translation[None], cfg.clearance_m)[0]):
                break
        else:
            raise InputError(f"query {index}: no free pose to be kidnapped from near {truth}")
        path = _path_to(world, before, length, rng, cfg)
        meta["kidnap_from"] = [before.x, before.y, before.theta]
        meta["kidnap_offset_m"] = math.dist((before.x, before.y), (truth.x, truth.y))
    else:
        path = _path_to(world, truth, length, rng, cfg)
    run = simulate_odometry(path, rng, cfg.drift)
    meta["odometry_reset"] = [float(v) for v in path[0]]
    meta["path_length_m"] = float(run.distance_m[-1])
    meta["path_rotation_rad"] = float(run.rotation_rad[-1])
    return run.odometry(-1, model=cfg.drift)


def _images(
    world: World, truth: Pose2, tags: Sequence[str], occluders: Any, rng: np.random.Generator, cfg: GeneratorConfig, meta: dict
) -> list:
    """The query's camera images, relit and blurred by its faults."""
    light = None
    if "lighting" in tags:
        light = (float(rng.uniform(0.45, 1.6)), float(rng.uniform(0.6, 1.6)), int(rng.integers(0, 3)))
        meta["lighting"] = {"gain": light[0], "gamma": light[1], "shadows": light[2]}
    blur = None
    if "blur" in tags:
        blur = (float(rng.uniform(6.0, 20.0)), float(rng.uniform(-0.3, 0.3)))
        meta["blur"] = {"length_px": blur[0], "angle_rad": blur[1]}
    images = []
    for yaw in cfg.image_yaws_rad:
        cam = replace(cfg.camera, yaw_in_robot_rad=float(yaw))
        im = render_camera(world, truth, cam, occluders=occluders)
        img = im.image_bgr
        if light is not None:
            img = relight(img, light[0], light[1], light[2], rng)
        if blur is not None:
            img = motion_blur(img, blur[0], blur[1])
        if img is not im.image_bgr:
            im = type(im)(img, im.hfov_rad, im.yaw_in_robot_rad, im.pitch_rad, im.cx_px)
        images.append(im)
    return images


def _cloud(
    world: World,
    truth: Pose2,
    tags: Sequence[str],
    occluders: Any,
    glass_faces: tuple[int, ...],
    rng: np.random.Generator,
    cfg: GeneratorConfig,
    meta: dict,
) -> PointCloud | None:
    """The query's depth cloud (None when nothing is in range), with its depth dropout."""
    try:
        cloud = render_cloud(world, truth, cfg.depth_camera, rng, occluders=occluders, glass_faces=glass_faces)
    except InputError:  # nothing in range (e.g. only glass in view): the query has no cloud
        cloud = None
        meta["cloud"] = "no depth return"
    if "depth_dropout" in tags and cloud is not None:
        frac, holes = float(rng.uniform(0.1, 0.3)), int(rng.integers(2, 6))
        cloud = PointCloud(depth_dropout(cloud.points_m, rng, frac, holes))
        meta["depth_dropout"] = {"random_fraction": frac, "holes": holes}
    return cloud


@deterministic
def generate_scenario(
    world: World | str,
    n_queries: int,
    seed: int,
    faults: Sequence[str] = FAULTS,
    config: GeneratorConfig = GeneratorConfig(),
    *,
    name: str | None = None,
    only_queries: Sequence[int] | None = None,
    progress: Callable[[int, int], None] | None = None,
):  # -> factorloc.datasets.Scenario (imported lazily: datasets imports sim)
    """Generate a scenario: one reference and ``n_queries`` queries with ground truth, drift and faults.

    ``world`` is a :class:`World`, a built-in world name (``"apartment"``) or a world file.

    Bit-for-bit reproducible from ``seed`` (same library versions). ``faults``
    lists the faults that may be applied (a subset of :data:`FAULTS`; empty for
    a clean scenario). ``only_queries`` regenerates just those query indices
    (same content as in the full scenario). ``progress(done, total)`` is called
    after each query (the CLI's progress bar).
    """
    from factorloc.datasets.scenario import Scenario, ScenarioQuery, ScenarioReference

    if isinstance(world, str):
        from factorloc.sim.world import world_by_name

        world = world_by_name(world)
    if not isinstance(world, World):
        raise InputError(f"world must be a factorloc.sim.World or a world name/file, got {type(world).__name__}")
    if isinstance(n_queries, bool) or not isinstance(n_queries, int) or n_queries < 0:
        raise InputError(f"n_queries must be a non-negative integer, got {n_queries!r}")
    if isinstance(seed, bool) or not isinstance(seed, int) or seed < 0:
        raise InputError(f"seed must be a non-negative integer, got {seed!r}")
    faults = tuple(faults)
    unknown = [f for f in faults if f not in FAULTS]
    if unknown:
        raise InputError(f"unknown fault(s) {unknown}; known: {FAULTS}")
    indices = list(range(n_queries)) if only_queries is None else sorted(set(only_queries))
    if any(not (0 <= i < n_queries) for i in indices):
        raise InputError(f"only_queries must be indices in [0, {n_queries}), got {list(only_queries or [])}")
    reference = render_reference(world, config, seed)
    queries = []
    for k, i in enumerate(indices):
        queries.append(ScenarioQuery(**generate_query(world, reference, config, seed, i, faults)))
        if progress is not None:
            progress(k + 1, len(indices))
    meta = {
        "generator": "factorloc.sim.generate_scenario",
        "n_queries": n_queries,
        "faults": list(faults),
        "fault_probability": config.fault_probability,
        "camera": {
            "width_px": config.camera.width_px,
            "height_px": config.camera.height_px,
            "hfov_rad": config.camera.hfov_rad,
            "height_m": config.camera.height_m,
        },
        "image_yaws_rad": list(config.image_yaws_rad),
        "depth_camera": {"stride_px": config.depth_camera.stride_px, "height_m": config.depth_camera.height_m},
        "panorama_height_m": config.panorama_height_m,
        "drift": {
            "translation_ratio": config.drift.translation_ratio,
            "rotation_ratio": config.drift.rotation_ratio,
            "heading_rad_per_m": config.drift.heading_rad_per_m,
        },
    }
    ref_meta = {"height_m": config.panorama_height_m, "depth_stride_px": config.reference_depth_camera.stride_px}
    return Scenario(
        name=name or f"{world.name}-seed{seed}",
        references=(ScenarioReference("ref0", reference, ref_meta),),
        queries=tuple(queries),
        world=world,
        seed=seed,
        description=f"simulated in world '{world.name}' by factorloc.sim.generate_scenario(n_queries={n_queries}, seed={seed})",
        metadata=meta,
    )

"""A simulated indoor world: floor plans, textured walls, rendered panoramas, camera images and depth clouds.

Usage
-----
>>> import math, numpy as np
>>> from factorloc import Pose2
>>> from factorloc.sim import apartment, render_panorama, render_camera, render_cloud, render_cloud_360
>>> from factorloc.sim import PinholeCamera, DepthCamera
>>> world = apartment()                      # ~10 × 8 m, 6 rooms, a corridor, doors; x ∈ [0, 10], y ∈ [0, 8]
>>> T = Pose2(3.0, 2.2, 0.3)                 # T_world_robot (living room)
>>> pano = render_panorama(world, T, height_m=1.0, width_px=2048, fov_v_rad=math.radians(60))
>>> pano.image_bgr.shape                     # factorloc.Panorama, azimuth(u) = π − 2π·u/W, centre column forward
(256, 2048, 3)
>>> img = render_camera(world, T, PinholeCamera(yaw_in_robot_rad=0.5))   # factorloc.CameraImage 640×480, 57°
>>> cloud = render_cloud(world, T, DepthCamera(), np.random.default_rng(0))  # factorloc.PointCloud, robot frame
>>> ref_cloud = render_cloud_360(world, T, DepthCamera(stride_px=4), np.random.default_rng(1))

Conventions: poses are ``T_world_robot`` (:class:`factorloc.Pose2`, metres and
radians, x forward, y left). Panoramas follow :class:`factorloc.Panorama`
exactly (cylindrical rows, horizon at row H/2). Camera images follow
:class:`factorloc.CameraImage` (``azimuth_of_column``; square pixels; optical
axis horizontal; ``yaw_in_robot_rad`` pans the camera). Clouds are N×3 in the
robot frame, z measured from the floor; ``rng=None`` renders noise-free.
Every sensor sits on the robot's vertical axis at its ``height_m``.
A world is a :class:`World` (load your own with :func:`load_world`, YAML/JSON).

Motion and faults: :func:`random_walk` / :func:`waypoint_trajectory` give N×3
true trajectories; :func:`simulate_odometry` dead-reckons along one with a
:class:`DriftModel` (~5 % drift, honest σ growing with distance since the
reset); faults are :func:`place_occluders` (pass ``occluders=`` to any
renderer), :func:`relight`, :func:`motion_blur`, :func:`depth_dropout`,
``glass_faces=`` of :func:`render_cloud`. A whole scenario:

>>> from factorloc.sim import generate_scenario               # doctest: +SKIP
>>> scenario = generate_scenario("apartment", n_queries=30, seed=103)  # doctest: +SKIP

Multi-place worlds (:mod:`factorloc.sim.track`): places in every room of a world
(:func:`~factorloc.sim.track.room_places`; rooms are the regions ``room.<name>``) and a robot touring the rooms
through the doors with kidnappings (:func:`~factorloc.sim.track.generate_track`). Built-in worlds: ``apartment``
and ``office`` (30 × 15 m, a corridor and eight rooms; :func:`world_by_name`).
"""

from factorloc.sim.faults import depth_dropout, most_seen_face, motion_blur, place_occluders, relight
from factorloc.sim.generate import FAULTS, GeneratorConfig, generate_scenario
from factorloc.sim.laser import render_scan
from factorloc.sim.motion import (
    DriftModel,
    OdometryRun,
    path_length_m,
    path_rotation_rad,
    random_walk,
    sample_free_pose,
    simulate_odometry,
    waypoint_trajectory,
)
from factorloc.sim.raycast import Hits, cast_rays
from factorloc.sim.render import (
    DepthCamera,
    PinholeCamera,
    panorama_rays,
    render_camera,
    render_cloud,
    render_cloud_360,
    render_panorama,
)
from factorloc.sim.textures import BASE_TEXTURES, DECAL_IMAGES
from factorloc.sim.world import (
    Decal,
    Face,
    Material,
    Obstacle,
    Wall,
    World,
    apartment,
    builtin_worlds,
    load_world,
    save_world,
    world_by_name,
)

__all__ = [
    "FAULTS",
    "DriftModel",
    "GeneratorConfig",
    "OdometryRun",
    "depth_dropout",
    "generate_scenario",
    "most_seen_face",
    "motion_blur",
    "path_length_m",
    "path_rotation_rad",
    "place_occluders",
    "random_walk",
    "relight",
    "sample_free_pose",
    "simulate_odometry",
    "waypoint_trajectory",
    "BASE_TEXTURES",
    "DECAL_IMAGES",
    "Decal",
    "DepthCamera",
    "Face",
    "Hits",
    "Material",
    "Obstacle",
    "PinholeCamera",
    "Wall",
    "World",
    "apartment",
    "builtin_worlds",
    "cast_rays",
    "load_world",
    "panorama_rays",
    "render_camera",
    "render_cloud",
    "render_cloud_360",
    "render_panorama",
    "render_scan",
    "save_world",
    "world_by_name",
]

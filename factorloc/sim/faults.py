"""Faults a localizer must survive, each a small pure function switchable per query.

Geometric faults change what is in the world at query time and so reach
every sensor consistently:

* :func:`place_occluders` — people and boxes that were not there when the
  reference was recorded (pass them as ``occluders=`` to the renderers);
* glass — ``glass_faces=`` of :func:`factorloc.sim.render_cloud`: the depth
  sensor gets no return from those faces (:func:`most_seen_face` picks one).

Photometric faults act on camera images (BGR uint8):

* :func:`relight` — gain, gamma and soft shadows (lighting change);
* :func:`motion_blur` — a linear blur kernel (the robot or its head moving).

Depth faults act on clouds: :func:`depth_dropout` removes random returns
and whole patches. Odometry faults (the robot pushed: *kidnapped*) and the
degenerate corridor are poses, decided by the scenario generator
(:mod:`factorloc.sim.generate`).
"""

from __future__ import annotations

import math

import cv2
import numpy as np

from factorloc._validate import nonnegative_float, positive_float
from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.sim.determinism import deterministic
from factorloc.sim.world import Decal, Face, Material, Obstacle, World

_CLOTHES = ("carpet", "gravel", "grass", "wallpaper")
_FACES = ("astronaut", "chelsea", "cat", "coffee")


def _image(name: str, image_bgr: np.ndarray) -> np.ndarray:
    if not isinstance(image_bgr, np.ndarray) or image_bgr.dtype != np.uint8 or image_bgr.ndim != 3 or image_bgr.shape[2] != 3:
        raise InputError(f"{name} must be an H×W×3 uint8 BGR image, got {getattr(image_bgr, 'shape', type(image_bgr).__name__)}")
    return image_bgr


@deterministic
def relight(
    image_bgr: np.ndarray,
    gain: float = 1.0,
    gamma: float = 1.0,
    shadows: int = 0,
    rng: np.random.Generator | None = None,
    shadow_strength: float = 0.5,
) -> np.ndarray:
    """A lighting change: ``out = 255·(gain·I/255)^gamma``, then ``shadows`` soft dark blobs.

    Each shadow is a random convex quadrilateral covering ~5–25 % of the image,
    blurred at its border, darkening by ``shadow_strength`` (0–1). Needs ``rng``
    when ``shadows > 0``. Returns a new BGR uint8 image.
    """
    img = _image("image_bgr", image_bgr)
    g = positive_float("gain", gain)
    ga = positive_float("gamma", gamma)
    if isinstance(shadows, bool) or not isinstance(shadows, int) or shadows < 0:
        raise InputError(f"shadows must be a non-negative integer, got {shadows!r}")
    strength = nonnegative_float("shadow_strength", shadow_strength)
    if strength > 1.0:
        raise InputError(f"shadow_strength must be in [0, 1], got {strength}")
    lut = np.clip(255.0 * np.clip(g * np.arange(256) / 255.0, 0.0, 1.0) ** ga, 0, 255).round().astype(np.uint8)
    out = cv2.LUT(img, lut)
    if shadows:
        if rng is None:
            raise InputError("relight needs an rng to place shadows")
        h, w = out.shape[:2]
        mask = np.zeros((h, w), np.float32)
        for _ in range(shadows):
            cx, cy = rng.uniform(0, w), rng.uniform(0, h)
            r = rng.uniform(0.15, 0.35) * min(h, w) * 1.5
            ang = np.sort(rng.uniform(0, 2 * math.pi, 4))
            pts = np.column_stack([cx + r * np.cos(ang), cy + r * np.sin(ang)]).astype(np.int32)
            cv2.fillConvexPoly(mask, pts, 1.0)
        k = max(3, int(0.03 * min(h, w)) | 1)
        mask = cv2.GaussianBlur(mask, (k, k), 0)
        out = np.clip(out.astype(np.float32) * (1.0 - strength * mask[:, :, None]), 0, 255).astype(np.uint8)
    return out


@deterministic
def motion_blur(image_bgr: np.ndarray, length_px: float, angle_rad: float = 0.0) -> np.ndarray:
    """Linear motion blur: the image averaged along a ``length_px`` segment at ``angle_rad`` (0 = horizontal)."""
    img = _image("image_bgr", image_bgr)
    length = nonnegative_float("length_px", length_px)
    if length < 1.0:
        return img.copy()
    n = int(math.ceil(length)) | 1
    kernel = np.zeros((n, n), np.float32)
    c = n // 2
    for t in np.linspace(-length / 2, length / 2, 4 * n):
        kernel[int(round(c - t * math.sin(angle_rad))), int(round(c + t * math.cos(angle_rad)))] += 1.0
    kernel /= kernel.sum()
    return cv2.filter2D(img, -1, kernel, borderType=cv2.BORDER_REFLECT)


def depth_dropout(
    points_m: np.ndarray,
    rng: np.random.Generator,
    random_fraction: float = 0.1,
    n_holes: int = 3,
    hole_radius_rad: float = 0.12,
) -> np.ndarray:
    """Missing depth returns: drop a random ``random_fraction`` of the points and
    every point within ``hole_radius_rad`` (angular) of ``n_holes`` random directions
    (dark or specular patches). Points are N×3 in the sensor's robot frame; the
    sensor is assumed on the z axis at the points' median height. Returns M×3, M ≤ N.
    """
    pts = np.asarray(points_m, np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise InputError(f"points_m must be N×3, got {pts.shape}")
    frac = nonnegative_float("random_fraction", random_fraction)
    if frac >= 1.0:
        raise InputError(f"random_fraction must be < 1, got {frac}")
    keep = rng.random(len(pts)) >= frac
    if n_holes:
        z0 = float(np.median(pts[:, 2]))
        az = np.arctan2(pts[:, 1], pts[:, 0])
        el = np.arctan2(pts[:, 2] - z0, np.hypot(pts[:, 0], pts[:, 1]))
        idx = rng.integers(0, len(pts), n_holes)
        for i in idx:
            d_az = np.angle(np.exp(1j * (az - az[i])))
            keep &= np.hypot(d_az, el - el[i]) > hole_radius_rad
    return pts[keep]


def place_occluders(
    world: World,
    T_world_robot: Pose2,
    rng: np.random.Generator,
    n: int = 2,
    view_yaw_rad: float = 0.0,
    half_fov_rad: float = math.radians(28.0),
    distance_range_m: tuple[float, float] = (0.9, 2.5),
    clearance_m: float = 0.25,
) -> tuple[Obstacle, ...]:
    """People and boxes standing in front of the robot, inside its view, not in the reference.

    Each occluder is placed at a random bearing within ±``half_fov_rad`` of
    ``view_yaw_rad`` (robot frame) and a random distance in ``distance_range_m``,
    in free space (``clearance_m`` from walls and obstacles), in line of
    sight. A person is a 1.6–1.85 m octagonal prism wearing a textured
    jumper with a portrait on its front; a box is a 0.4–0.7 m cardboard cube.
    Returns up to ``n`` obstacles (fewer when the view has no room).
    """
    if not isinstance(T_world_robot, Pose2):
        raise InputError(f"T_world_robot must be a Pose2, got {type(T_world_robot).__name__}")
    lo, hi = (
        positive_float("distance_range_m[0]", distance_range_m[0]),
        positive_float("distance_range_m[1]", distance_range_m[1]),
    )
    out: list[Obstacle] = []
    placed: list[np.ndarray] = []
    for k in range(n):
        for _ in range(30):
            bearing = T_world_robot.theta + view_yaw_rad + rng.uniform(-half_fov_rad, half_fov_rad)
            d = rng.uniform(lo, hi)
            c = np.array([T_world_robot.x + d * math.cos(bearing), T_world_robot.y + d * math.sin(bearing)])
            person = rng.random() < 0.6
            r = 0.24 if person else rng.uniform(0.2, 0.35)
            if not bool(world.is_free(c[None], r + clearance_m)[0]):
                continue
            if not bool(world.line_of_sight(T_world_robot.translation[None], c[None])[0]):
                continue
            if any(np.linalg.norm(c - p) < 2 * r + 0.2 for p in placed):
                continue
            if person:
                ang = bearing + math.pi + np.arange(8) * (2 * math.pi / 8) + math.pi / 8  # an edge faces the robot
                verts = tuple((float(c[0] + r * math.cos(a)), float(c[1] + r * math.sin(a))) for a in ang)
                tint = tuple(float(v) for v in rng.uniform(0.3, 1.5, 3))
                clothes = Material(str(rng.choice(_CLOTHES)), tint, 0.3)
                front = Face(clothes, (Decal(str(rng.choice(_FACES)), 0.0, 2 * r * math.sin(math.pi / 8), 1.2, 1.55),))
                faces = (front,) + (Face(clothes),) * 7
                h = float(rng.uniform(1.6, 1.85))
                out.append(Obstacle(verts, h, faces, top=Material("carpet", (0.3, 0.3, 0.3), 0.3), name=f"person{k}"))
            else:
                yaw = rng.uniform(0, math.pi / 2)
                ang = yaw + np.arange(4) * (math.pi / 2) + math.pi / 4
                verts = tuple((float(c[0] + r * math.cos(a)), float(c[1] + r * math.sin(a))) for a in ang)
                cardboard = Material("wood", (0.75, 0.95, 1.15), 0.5)
                h = float(rng.uniform(0.4, 0.7))
                out.append(Obstacle(verts, h, (Face(cardboard),), top=cardboard, name=f"box{k}"))
            placed.append(c)
            break
    return tuple(out)


def most_seen_face(
    world: World, T_world_robot: Pose2, view_yaw_rad: float = 0.0, n_rays: int = 64, half_fov_rad: float = 0.5
) -> int | None:
    """Index (into ``world.segments.faces``) of the face most seen at mid-wall height within ±``half_fov_rad``
    of the view direction ``view_yaw_rad`` (robot frame); None if no face is in view."""
    from factorloc.sim.raycast import FACE, cast_rays

    az = view_yaw_rad + np.linspace(-half_fov_rad, half_fov_rad, n_rays)
    hits = cast_rays(
        world, T_world_robot, 0.5 * world.wall_height_m, az, np.zeros(1), np.ones(n_rays), np.full(n_rays, 0.01), texture=False
    )
    faces = hits.face[0][hits.kind[0] == FACE]
    if len(faces) == 0:
        return None
    vals, counts = np.unique(faces, return_counts=True)
    return int(vals[np.argmax(counts)])

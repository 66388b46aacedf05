"""Robot motion in a simulated world: trajectories and odometry with drift.

Trajectories are N×3 arrays of true poses ``[x_m, y_m, theta_rad]`` in the world
frame, densely sampled (a few cm / a few degrees apart). :func:`waypoint_trajectory`
follows scripted waypoints (turn in place, then drive straight);
:func:`random_walk` wanders through free space, keeping a clearance to every
wall and obstacle so it never passes through one.

Odometry (:func:`simulate_odometry`) integrates the true motion increments
with *systematic* errors drawn once per odometry reset, the dominant errors
of wheel odometry (wheel radius and track mismatch):

* translation scale ``ε_t ~ N(0, k_t²)`` and lateral slip ``ε_l ~ N(0, k_t²)``:
  a step ``(dx, dy)`` in the robot frame is measured as
  ``(dx(1+ε_t) − dy·ε_l, dy(1+ε_t) + dx·ε_l)``;
* rotation scale ``ε_r ~ N(0, k_r²)``: a turn ``dθ`` is measured as ``dθ + ε_r·|dθ|``;
* heading drift ``ω ~ N(0, k_d²)`` rad per metre: each step adds ``ω·|step|``.

Position error therefore grows linearly with the distance (σ ≈ k_t·d, the
patent's "5 % drift") plus the lever arm of the heading error. The reported
covariance is the second moment of the error these four parameters produce
along the actual path (Monte Carlo, deterministic), so it is honest: the
mean NEES of the true odometry error is 3.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from factorloc._validate import nonnegative_float, positive_float
from factorloc.errors import InputError
from factorloc.geometry import Pose2, wrap_angle
from factorloc.sim.world import World
from factorloc.types import Odometry


# --------------------------------------------------------------------------
# Trajectories
# --------------------------------------------------------------------------
def _as_poses(name: str, poses: np.ndarray) -> np.ndarray:
    arr = np.asarray(poses, dtype=np.float64)
    if arr.ndim != 2 or arr.shape[1] != 3 or arr.shape[0] < 1:
        raise InputError(f"{name} must be an N×3 array of [x_m, y_m, theta_rad], got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise InputError(f"{name} contains NaN or infinite values")
    return arr


def path_length_m(trajectory: np.ndarray) -> float:
    """Total distance driven along an N×3 trajectory (m)."""
    t = _as_poses("trajectory", trajectory)
    return float(np.sum(np.hypot(np.diff(t[:, 0]), np.diff(t[:, 1]))))


def path_rotation_rad(trajectory: np.ndarray) -> float:
    """Total absolute rotation along an N×3 trajectory (rad)."""
    t = _as_poses("trajectory", trajectory)
    return float(np.sum(np.abs(wrap_angle(np.diff(t[:, 2])))))


def waypoint_trajectory(waypoints: list[Pose2 | tuple[float, float]], step_m: float = 0.05, step_rad: float = 0.05) -> np.ndarray:
    """Drive through ``waypoints``: turn in place to face the next one, then straight to it.

    The first waypoint must be a :class:`Pose2` (the start pose). A later
    :class:`Pose2` waypoint also fixes the heading on arrival (the robot turns
    in place to it); an ``(x, y)`` tuple leaves the heading of travel.
    Returns the N×3 world-frame poses, ``step_m``/``step_rad`` apart at most.
    """
    if not waypoints or not isinstance(waypoints[0], Pose2):
        raise InputError("waypoint_trajectory needs a Pose2 as its first waypoint (the start pose)")
    ds = positive_float("step_m", step_m)
    dr = positive_float("step_rad", step_rad)
    out = [waypoints[0].as_array()]

    def turn_to(theta: float) -> None:
        x, y, th = out[-1]
        delta = wrap_angle(theta - th)
        n = max(1, math.ceil(abs(delta) / dr))
        for k in range(1, n + 1):
            out.append(np.array([x, y, th + delta * k / n]))

    for i, wp in enumerate(waypoints[1:], start=1):
        if isinstance(wp, Pose2):
            gx, gy, gth = wp.x, wp.y, wp.theta
        else:
            try:
                gx, gy = float(wp[0]), float(wp[1])
            except (TypeError, ValueError, IndexError) as exc:
                raise InputError(f"waypoints[{i}] must be a Pose2 or an (x, y) pair, got {wp!r}") from exc
            gth = None
        x, y, _ = out[-1]
        dist = math.hypot(gx - x, gy - y)
        if dist > 1e-9:
            turn_to(math.atan2(gy - y, gx - x))
            x, y, th = out[-1]
            n = max(1, math.ceil(dist / ds))
            for k in range(1, n + 1):
                out.append(np.array([x + (gx - x) * k / n, y + (gy - y) * k / n, th]))
        if gth is not None:
            turn_to(gth)
    traj = np.vstack(out)
    traj[:, 2] = wrap_angle(traj[:, 2])
    return traj


def sample_free_pose(world: World, rng: np.random.Generator, clearance_m: float = 0.4, max_tries: int = 10000) -> Pose2:
    """A pose uniformly drawn in the world's bounds, at least ``clearance_m`` from any surface, heading uniform."""
    x0, y0, x1, y1 = world.bounds_xy
    for _ in range(max(1, max_tries // 64)):
        xy = np.column_stack([rng.uniform(x0, x1, 64), rng.uniform(y0, y1, 64)])
        ok = np.nonzero(world.is_free(xy, clearance_m))[0]
        if len(ok):
            p = xy[ok[0]]
            return Pose2(float(p[0]), float(p[1]), float(rng.uniform(-math.pi, math.pi)))
    raise InputError(f"no free pose with clearance {clearance_m} m found in world '{world.name}' after {max_tries} tries")


def random_walk(
    world: World,
    start: Pose2,
    length_m: float,
    rng: np.random.Generator,
    *,
    step_m: float = 0.05,
    clearance_m: float = 0.35,
    turn_sigma_rad: float = 0.03,
) -> np.ndarray:
    """Wander ``length_m`` metres through free space from ``start``.

    Each step of ``step_m`` keeps the heading plus a random turn
    (σ = ``turn_sigma_rad``); when the next position would come closer than
    ``clearance_m`` to a surface, the robot turns in place (5° steps, recorded)
    to the free heading nearest to its current one. Steps shorter than the
    clearance cannot cross a wall. Returns the N×3 world-frame poses.
    """
    if not isinstance(start, Pose2):
        raise InputError(f"start must be a Pose2, got {type(start).__name__}")
    L = nonnegative_float("length_m", length_m)
    ds = positive_float("step_m", step_m)
    cl = positive_float("clearance_m", clearance_m)
    if ds >= cl:
        raise InputError(f"step_m ({ds}) must be smaller than clearance_m ({cl}) so that a step cannot cross a wall")
    if not bool(world.is_free(start.translation[None], cl * 0.999)[0]):
        raise InputError(f"start {start} is closer than clearance_m = {cl} m to a surface of world '{world.name}'")
    x, y, th = start.x, start.y, start.theta
    out = [[x, y, th]]
    travelled = 0.0
    candidates = np.deg2rad(np.concatenate([[0.0], np.repeat(np.arange(5.0, 185.0, 5.0), 2) * np.tile([1.0, -1.0], 36)]))
    while travelled < L - 1e-12:
        step = min(ds, L - travelled)
        th_try = th + rng.normal(0.0, turn_sigma_rad)
        heads = th_try + candidates
        nxt = np.column_stack([x + step * np.cos(heads), y + step * np.sin(heads)])
        free = np.nonzero(world.is_free(nxt, cl))[0]
        if len(free) == 0:
            raise InputError(f"random_walk is stuck at ({x:.2f}, {y:.2f}) in world '{world.name}': no free heading")
        k = int(free[0])
        new_th = float(heads[k])
        turn = wrap_angle(new_th - th)
        n_turn = int(abs(turn) // math.radians(5.0))
        for j in range(1, n_turn + 1):  # turn in place first when the way is blocked
            out.append([x, y, th + turn * j / (n_turn + 1)])
        x, y, th = float(nxt[k, 0]), float(nxt[k, 1]), new_th
        out.append([x, y, th])
        travelled += step
    traj = np.asarray(out, dtype=np.float64)
    traj[:, 2] = wrap_angle(traj[:, 2])
    return traj


# --------------------------------------------------------------------------
# Odometry
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class DriftModel:
    """Systematic odometry errors, drawn once per reset (see the module docstring).

    Defaults give the patent's ~5 % drift: σ of the translation scale and of the
    lateral slip 5 %, rotation scale 5 % of the angle turned, heading drift
    0.02 rad per metre (as :meth:`factorloc.Odometry.from_distance`).
    """

    translation_ratio: float = 0.05
    rotation_ratio: float = 0.05
    heading_rad_per_m: float = 0.02
    min_sigma_m: float = 1e-3
    min_sigma_rad: float = 1e-3

    def __post_init__(self) -> None:
        for name in ("translation_ratio", "rotation_ratio", "heading_rad_per_m"):
            object.__setattr__(self, name, nonnegative_float(f"DriftModel.{name}", getattr(self, name)))
        for name in ("min_sigma_m", "min_sigma_rad"):
            object.__setattr__(self, name, positive_float(f"DriftModel.{name}", getattr(self, name)))

    @property
    def sigmas(self) -> np.ndarray:
        """σ of the four error parameters (ε_t, ε_l, ε_r, ω)."""
        return np.array([self.translation_ratio, self.translation_ratio, self.rotation_ratio, self.heading_rad_per_m])


def _integrate(traj: np.ndarray, start: np.ndarray, params: np.ndarray) -> np.ndarray:
    """Integrate the motion increments of ``traj`` from ``start`` with error parameters.

    ``params`` is (4,) or M×4 rows (ε_t, ε_l, ε_r, ω); returns N×3 or M×N×3 poses (θ unwrapped).
    """
    p = np.atleast_2d(params)
    et, el, er, om = (p[:, k : k + 1] for k in range(4))
    th = traj[:, 2]
    dxw, dyw = np.diff(traj[:, 0]), np.diff(traj[:, 1])
    c, s = np.cos(th[:-1]), np.sin(th[:-1])
    dx = c * dxw + s * dyw  # robot-frame increments
    dy = -s * dxw + c * dyw
    dth = wrap_angle(np.diff(th))
    step = np.hypot(dx, dy)
    mdx = dx * (1.0 + et) - dy * el
    mdy = dy * (1.0 + et) + dx * el
    mdth = dth + er * np.abs(dth) + om * step
    zero = np.zeros((p.shape[0], 1))
    heads = start[2] + np.concatenate([zero, np.cumsum(mdth, axis=1)], axis=1)
    hc, hs = np.cos(heads[:, :-1]), np.sin(heads[:, :-1])
    wx = start[0] + np.concatenate([zero, np.cumsum(hc * mdx - hs * mdy, axis=1)], axis=1)
    wy = start[1] + np.concatenate([zero, np.cumsum(hs * mdx + hc * mdy, axis=1)], axis=1)
    out = np.stack([wx, wy, heads], axis=-1)
    return out[0] if np.ndim(params) == 1 else out


@dataclass(frozen=True)
class OdometryRun:
    """The odometry along a trajectory since its last reset.

    ``poses``: N×3 odometry poses (world frame, θ unwrapped). ``covariances``:
    N×3×3 first-order covariances (world frame). ``errors``: the drawn
    (ε_t, ε_l, ε_r, ω). ``distance_m`` and ``rotation_rad``: N cumulative
    distance and absolute rotation since the reset.
    """

    poses: np.ndarray
    covariances: np.ndarray
    errors: np.ndarray
    distance_m: np.ndarray
    rotation_rad: np.ndarray

    def odometry(self, i: int = -1, *, model: DriftModel | None = None) -> Odometry:
        """The :class:`factorloc.Odometry` at sample ``i``: pose and per-axis sigmas (diagonal of the covariance)."""
        m = model or DriftModel()
        x, y, th = self.poses[i]
        var = np.diag(self.covariances[i])
        return Odometry(
            Pose2(float(x), float(y), float(th)),
            max(m.min_sigma_m, float(math.sqrt(var[0]))),
            max(m.min_sigma_m, float(math.sqrt(var[1]))),
            max(m.min_sigma_rad, float(math.sqrt(var[2]))),
        )


def simulate_odometry(
    trajectory: np.ndarray,
    rng: np.random.Generator | None,
    model: DriftModel = DriftModel(),
    *,
    n_samples: int = 128,
) -> OdometryRun:
    """Dead-reckon along ``trajectory`` (N×3 true poses) from an exact reset at its first pose.

    ``rng=None`` gives the error-free odometry (still with its honest covariances).
    The covariance of sample i is the second moment of the odometry error about
    the true pose over ``n_samples`` draws of (ε_t, ε_l, ε_r, ω) from the model
    (Monte Carlo with a fixed internal seed, so it is deterministic and honest
    also where the heading error makes the error non-linear: the mean NEES of
    the true error is 3 by construction).
    """
    traj = _as_poses("trajectory", trajectory)
    if not isinstance(model, DriftModel):
        raise InputError(f"model must be a DriftModel, got {type(model).__name__}")
    if isinstance(n_samples, bool) or not isinstance(n_samples, int) or n_samples < 8:
        raise InputError(f"n_samples must be an integer >= 8, got {n_samples!r}")
    sig = model.sigmas
    errors = np.zeros(4) if rng is None else rng.standard_normal(4) * sig
    start = traj[0]
    poses = _integrate(traj, start, errors)
    draws = np.random.default_rng(20150415).standard_normal((n_samples, 4)) * sig
    draws = np.vstack([draws, -draws])  # antithetic: removes the first-order sampling bias
    err = _integrate(traj, start, draws) - traj[None]
    err[..., 2] = wrap_angle(err[..., 2])
    cov = np.einsum("mni,mnj->nij", err, err) / err.shape[0]
    steps = np.hypot(np.diff(traj[:, 0]), np.diff(traj[:, 1]))
    dist = np.concatenate([[0.0], np.cumsum(steps)])
    rot = np.concatenate([[0.0], np.cumsum(np.abs(wrap_angle(np.diff(traj[:, 2]))))])
    return OdometryRun(poses, cov, errors, dist, rot)

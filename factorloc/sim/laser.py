"""The simulated 2D laser scanner: :func:`render_scan` and its error model (a SICK LMS200-class lidar).

The scan is cast with the renderers' ray caster (:mod:`factorloc.sim.raycast`) at one height, then given the
statistical, per-surface systematic and mixed-pixel errors of a real time-of-flight scanner.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from factorloc._validate import nonnegative_float, positive_float, positive_int
from factorloc.datasets.rosbag import LaserLog
from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.sim.motion import DriftModel
from factorloc.sim.raycast import FACE, cast_all
from factorloc.sim.world import Obstacle, World
from factorloc.types import Scan

#: Defaults of :func:`render_scan`'s error model: a SICK LMS200-class 2D lidar, the scanner class of the
#: real logs (Intel, ACES, MIT CSAIL), set from those logs' ICP residuals rather than from the datasheet
#: (``benchmarks/bench_lidar_model.py``; ``docs/calibration/icp.md``). The datasheet's statistical error
#: (5 mm, 1σ) and ±15 mm systematic error per surface (SICK LMS200 technical description, mm mode, 1–8 m;
#: later SICK families alike) made simulated residuals too correlated along a wall (lag-1 autocorrelation
#: 0.41 against the logs' 0.11–0.25); 8 mm white and a 4 mm per-surface offset give the logs' residual RMSE
#: (14 mm; logs 11–21 mm) and their autocorrelation (0.27 / 0.15 / 0.07 at lags 1 / 2 / 5; Intel 0.25 /
#: 0.15 / 0.07). Beam divergence 4.6 mrad and 13 mm exit spot: the spot diameter ``d·0.0046 + 0.013`` m of
#: the LMS5xx (HR) operating instructions, §3.5.2.
SCAN_SIGMA_M = 0.008
SCAN_SYSTEMATIC_SIGMA_M = 0.004
SCAN_BEAM_DIVERGENCE_RAD = 0.0046
SCAN_SPOT_EXIT_M = 0.013
#: The sensor-pose error of :func:`render_scan` (1σ per axis and in heading): the pose a real scan was taken from
#: differs from the pose it is stamped with (motion during the sweep, timing, the mount), an error shared by all
#: its beams that no residual shows. Without it the simulated ICP errs half as much as the logs' at the same
#: residuals (median position error 0.82 cm against 0.91–2.57 cm); with it ICP's error on simulated pairs sits
#: among the logs' (median ~2 cm, MIT CSAIL's).
SCAN_POSE_SIGMA_M = 0.014
SCAN_POSE_SIGMA_RAD = math.radians(0.25)
#: Degrees of freedom of that error (Student's t, scaled to the σ above; ``inf``: Gaussian): real scans' errors
#: are heavy-tailed (on MIT CSAIL the mean ICP error is 1.4× the median, the NEES's 99 % quantile 2× χ²'s).
SCAN_POSE_DOF = math.inf


def render_scan(
    world: World,
    T_world_robot: Pose2,
    n_beams: int = 360,
    height_m: float = 0.3,
    max_range_m: float = 10.0,
    sigma_m: float = SCAN_SIGMA_M,
    rng: np.random.Generator | None = None,
    *,
    occluders: Sequence[Obstacle] = (),
    systematic_sigma_m: float = SCAN_SYSTEMATIC_SIGMA_M,
    beam_divergence_rad: float = SCAN_BEAM_DIVERGENCE_RAD,
    spot_exit_m: float = SCAN_SPOT_EXIT_M,
    mixed_min_jump_m: float = 0.05,
    pose_sigma_m: float = SCAN_POSE_SIGMA_M,
    pose_sigma_rad: float = SCAN_POSE_SIGMA_RAD,
    pose_dof: float = SCAN_POSE_DOF,
) -> Scan:
    """A planar laser scan at ``height_m`` above the floor: ``n_beams`` beams over 360°, beam i at azimuth 2π·i/n.

    Returns hits closer than ``max_range_m`` (N×2, robot frame). Glass is
    invisible to it as to the depth camera; obstacles lower than ``height_m``
    are not seen. Without ``rng`` the ranges are exact; with it they carry
    the error model of a real 2D lidar (defaults: SICK LMS200 class, see
    :data:`SCAN_SIGMA_M` and below), whose errors are *not* all white:

    * **statistical error** ``sigma_m`` (m, 1σ): independent Gaussian range
      noise per beam (8 mm: the datasheet's 5 mm and what else a real
      scan's residuals hold, see :data:`SCAN_SIGMA_M`);
    * **systematic error** ``systematic_sigma_m`` (m, 1σ): one Gaussian range
      offset per surface (wall/obstacle face, all occluders together) and
      per scan, shared by every beam that hits that surface in this scan
      (4 mm, see :data:`SCAN_SIGMA_M`).
      The datasheet's ±15 mm systematic error depends on the surface's
      reflectivity, the incidence angle and the range, so a surface seen
      from another pose is offset differently: each scan draws its own
      offsets. A shared offset moves a whole wall, which no amount of beams
      averages out: this is the correlated error the ICP covariance's
      ``bias_rmse_ratio`` term accounts for;
    * **mixed pixels** at depth edges: the spot (diameter
      ``spot_exit_m + beam_divergence_rad·r``) of a beam next to a range jump
      larger than ``mixed_min_jump_m`` straddles the edge with probability
      ``min(1, spot / beam spacing)``; its return is then a range drawn
      uniformly between the near and the far surface (a phantom point in
      free space), as real time-of-flight scanners report.

    * **sensor-pose error** ``pose_sigma_m`` (m, per axis) and ``pose_sigma_rad``: the scan is taken from
      ``T_world_robot · δ`` with one rigid motion δ per scan (Student's t with ``pose_dof`` degrees of
      freedom, scaled to those σ) and returned in the frame of
      ``T_world_robot``: the motion during the sweep, timing and the mount move the real scan as a whole, an
      error that no residual between two scans shows (the real logs' ICP errors are 1–2 cm larger than their
      residuals explain; see :data:`SCAN_POSE_SIGMA_M`).

    Angular errors (encoder jitter) are not modelled: for the scanners
    above they are far below the beam spacing.

    Random numbers: the statistical noise is drawn from ``rng`` exactly as
    before this model existed (``n_beams`` normals, only when
    ``sigma_m > 0``); the systematic offsets and mixed pixels come from a
    child generator (``rng.spawn(1)``), the sensor-pose error from a second one
    (only when its σ are not 0), so ``rng``'s own stream, and hence everything
    a simulator draws after the scan, does not depend on them.
    """
    if not isinstance(T_world_robot, Pose2):
        raise InputError(f"T_world_robot must be a Pose2, got {type(T_world_robot).__name__}")
    n = positive_int("n_beams", n_beams, 4)
    rmax = positive_float("max_range_m", max_range_m)
    sig = nonnegative_float("sigma_m", sigma_m)
    sig_sys = nonnegative_float("systematic_sigma_m", systematic_sigma_m)
    div = nonnegative_float("beam_divergence_rad", beam_divergence_rad)
    spot0 = nonnegative_float("spot_exit_m", spot_exit_m)
    jump = positive_float("mixed_min_jump_m", mixed_min_jump_m)
    pose_m = nonnegative_float("pose_sigma_m", pose_sigma_m)
    pose_rad = nonnegative_float("pose_sigma_rad", pose_sigma_rad)
    dof = float(pose_dof)
    if not dof > 2.0:
        raise InputError(f"pose_dof must be > 2 (a finite variance), got {pose_dof!r}")
    az = 2.0 * math.pi * np.arange(n) / n
    systematic = rng is not None and (sig_sys > 0 or div > 0 or spot0 > 0)
    moved = rng is not None and (pose_m > 0 or pose_rad > 0)
    # one spawn for both children: the systematic one is the child a single spawn gives (as before this error)
    children = rng.spawn(int(systematic) + int(moved)) if systematic or moved else []
    T_world_sensor = T_world_robot
    if moved:
        g = children[-1]
        # Student's t with pose_dof degrees of freedom, scaled to a standard deviation of 1 (Gaussian when inf)
        u = g.normal(0.0, 1.0, 3) if math.isinf(dof) else g.standard_t(dof, 3) / math.sqrt(dof / (dof - 2.0))
        d = u * np.array([pose_m, pose_m, pose_rad])
        T_world_sensor = T_world_robot * Pose2(float(d[0]), float(d[1]), float(d[2]))
    hits, _, _ = cast_all(
        world,
        occluders,
        T_world_sensor,
        positive_float("height_m", height_m),
        az,
        np.zeros(1),
        np.ones(n),
        np.full(n, 2 * math.pi / n),
        texture=False,
    )
    r = hits.distance_m[0].copy()
    keep = (hits.kind[0] >= FACE) & (r < rmax) & ~hits.glass[0]
    if rng is not None and sig > 0:
        r = r + rng.normal(0.0, sig, r.shape)
    if systematic:
        r = _lidar_systematic(r, keep, hits.face[0], children[0], sig_sys, div, spot0, jump, 2 * math.pi / n)
    pts = np.column_stack([r * np.cos(az), r * np.sin(az)])[keep]
    if len(pts) == 0:
        raise InputError(f"the scanner at {T_world_robot} sees nothing within {rmax} m")
    return Scan(pts.astype(np.float32).astype(np.float64))


def _lidar_systematic(
    r: np.ndarray,
    keep: np.ndarray,
    face: np.ndarray,
    rng: np.random.Generator,
    sigma_sys_m: float,
    divergence_rad: float,
    spot_exit_m: float,
    min_jump_m: float,
    spacing_rad: float,
) -> np.ndarray:
    """Per-surface range offsets and mixed pixels of :func:`render_scan` (ranges ``r`` of all n beams, metres)."""
    n = len(r)
    # per-(scan, surface) offset; face −1 (occluders, floor) shares one slot
    slot = face.astype(np.int64) + 1
    offsets = rng.normal(0.0, sigma_sys_m, int(slot.max()) + 1 if n else 1)
    out = r + np.where(keep, offsets[slot], 0.0)
    # mixed pixels: beam i whose neighbour (i±1, cyclic) is nearer by more than min_jump_m, and whose spot
    # reaches over the edge (probability spot/spacing at the edge's range), returns a range in between
    u_mix = rng.random(n)
    u_pos = rng.random(n)
    side = rng.random(n) < 0.5  # which neighbour's edge when both qualify
    nb = np.where(side, np.roll(np.arange(n), 1), np.roll(np.arange(n), -1))
    other = np.where(side, np.roll(np.arange(n), -1), np.roll(np.arange(n), 1))
    near_nb = keep[nb] & (r[nb] < r - min_jump_m)
    nb = np.where(near_nb, nb, other)
    near = keep[nb] & (r[nb] < r - min_jump_m)
    r_edge = r[nb]
    p = np.minimum(1.0, (spot_exit_m + divergence_rad * r_edge) / np.maximum(r_edge * spacing_rad, 1e-9))
    mixed = keep & near & (u_mix < p)
    return np.where(mixed, out[nb] + u_pos * (out - out[nb]), out)


def simulate_laser_log(
    world: World,
    trajectory: np.ndarray,
    rng: np.random.Generator,
    *,
    scan_every: int = 2,
    dt_s: float = 0.1,
    n_beams: int = 360,
    max_range_m: float = 10.0,
    drift: DriftModel | None = None,
    pose_sigma_m: float = SCAN_POSE_SIGMA_M,
    pose_sigma_rad: float = SCAN_POSE_SIGMA_RAD,
) -> tuple[LaserLog, np.ndarray]:
    """A simulated run along ``trajectory`` (N×3 true poses, world frame): drifting odometry at every pose and a
    :func:`render_scan` (with the real-scanner error model) at every ``scan_every``-th, ``dt_s`` apart.

    ``pose_sigma_m`` / ``pose_sigma_rad`` are :func:`render_scan`'s sensor-pose error (per scan, unobservable:
    with it no estimator can place a scan nearer its true pose than that error). Returns the
    :class:`~factorloc.datasets.rosbag.LaserLog` (odometry frame = the world at the first pose,
    where the odometry is reset) and the (M, 3) true poses of its scans.
    """
    from factorloc.datasets.rosbag import OdometryTrack, ScanTrack
    from factorloc.sim.motion import simulate_odometry  # noqa: PLC0415

    traj = np.asarray(trajectory, dtype=np.float64)
    if traj.ndim != 2 or traj.shape[1] != 3 or len(traj) < 2:
        raise InputError(f"trajectory must be N×3 with N >= 2, got shape {traj.shape}")
    every = positive_int("scan_every", scan_every)
    dt = positive_float("dt_s", dt_s)
    run = simulate_odometry(traj, rng, drift or DriftModel())
    stamps = np.arange(len(traj)) * dt
    picks = np.arange(0, len(traj), every)
    scans = tuple(
        render_scan(
            world,
            Pose2.from_array(traj[k]),
            n_beams,
            max_range_m=max_range_m,
            rng=rng,
            pose_sigma_m=pose_sigma_m,
            pose_sigma_rad=pose_sigma_rad,
        )
        for k in picks
    )
    log = LaserLog(OdometryTrack(stamps, run.poses), ScanTrack(stamps[picks], scans), f"sim:{world.name}")
    return log, traj[picks].copy()

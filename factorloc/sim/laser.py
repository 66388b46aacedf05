"""The simulated 2D laser scanner: :func:`render_scan` and its error model (a SICK LMS200-class lidar).

The scan is cast with the renderers' ray caster (:mod:`factorloc.sim.raycast`) at one height, then given the
statistical, per-surface systematic and mixed-pixel errors of a real time-of-flight scanner.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from factorloc._validate import nonnegative_float, positive_float, positive_int
from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.sim.raycast import FACE, cast_all
from factorloc.sim.world import Obstacle, World
from factorloc.types import Scan

#: Defaults of :func:`render_scan`'s error model (a SICK LMS200-class 2D lidar, the scanner class of the
#: Intel Research Lab and ACES logs): statistical (white) range error 5 mm (1σ) and systematic error
#: ±15 mm, "depending on surface reflectivity, incidence angle and range" (SICK LMS200 technical
#: description, mm mode, 1–8 m); later SICK families are specified alike (LMS1xx ±30 mm systematic /
#: 12 mm statistical, LMS5xx ±25 mm / 6–7 mm, SICK knowledge base "Measurement errors LMSxxx").
#: The ±15 mm bound is taken as 2σ of a per-surface offset. Beam divergence 4.6 mrad and 13 mm exit
#: spot: the spot diameter ``d·0.0046 + 0.013`` m of the LMS5xx (HR) operating instructions, §3.5.2.
SCAN_SIGMA_M = 0.005
SCAN_SYSTEMATIC_SIGMA_M = 0.0075
SCAN_BEAM_DIVERGENCE_RAD = 0.0046
SCAN_SPOT_EXIT_M = 0.013


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
) -> Scan:
    """A planar laser scan at ``height_m`` above the floor: ``n_beams`` beams over 360°, beam i at azimuth 2π·i/n.

    Returns hits closer than ``max_range_m`` (N×2, robot frame). Glass is
    invisible to it as to the depth camera; obstacles lower than ``height_m``
    are not seen. Without ``rng`` the ranges are exact; with it they carry
    the error model of a real 2D lidar (defaults: SICK LMS200 class, see
    :data:`SCAN_SIGMA_M` and below), whose errors are *not* all white:

    * **statistical error** ``sigma_m`` (m, 1σ): independent Gaussian range
      noise per beam (datasheet "statistical error": 5 mm);
    * **systematic error** ``systematic_sigma_m`` (m, 1σ): one Gaussian range
      offset per surface (wall/obstacle face, all occluders together) and
      per scan, shared by every beam that hits that surface in this scan.
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

    Angular errors (encoder jitter) are not modelled: for the scanners
    above they are far below the beam spacing.

    Random numbers: the statistical noise is drawn from ``rng`` exactly as
    before this model existed (``n_beams`` normals, only when
    ``sigma_m > 0``); the systematic offsets and mixed pixels come from a
    child generator (``rng.spawn(1)``), so ``rng``'s own stream, and hence
    everything a simulator draws after the scan, does not depend on them.
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
    az = 2.0 * math.pi * np.arange(n) / n
    hits, _, _ = cast_all(
        world,
        occluders,
        T_world_robot,
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
    if rng is not None and (sig_sys > 0 or div > 0 or spot0 > 0):
        r = _lidar_systematic(r, keep, hits.face[0], rng.spawn(1)[0], sig_sys, div, spot0, jump, 2 * math.pi / n)
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

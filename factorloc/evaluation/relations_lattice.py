"""Are a log's relations the odometry moved by whole grid steps? The translation lattice test.

A relation made by a correlative (grid) scan matcher seeded by the odometry (Olson 2009; the Freiburg relations of
Kümmerle et al. 2009 were scan-matched and checked by hand) keeps the matcher's grid: its translation is the
odometry's plus a whole number of grid steps ``s`` in x and y, so ``|t_relation − t_odometry| = s·√(a² + b²)`` for
integers a, b. The norm does not depend on the frame the grid was laid in, so the test needs neither.

For a relation on such a lattice the true motion lies anywhere in the grid cell around it: against the relation,
an estimate whose error does not depend on where the truth falls in the cell errs at least the mean distance from
a uniform point of a square of side ``s`` to its centre, ``(√2 + asinh 1)/6 · s ≈ 0.383 s`` on average (the
centre minimizes the mean distance to a centrally symmetric distribution, so the estimate's own error can only
add). :attr:`RelationsLattice.floor_mean_error_m` is that bound over all the relations (zero for the relations off
the lattice): no estimate of the true motion scores below it on the benchmark's mean translational error.

Chance: a norm lands within ``tolerance_m`` of some lattice norm by accident at a rate that depends on the norms;
:attr:`RelationsLattice.chance_rate` is the rate for the same norms each moved by a uniform offset in
``[−s/2, s/2]`` (seeded, deterministic), what a log without a grid shows.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from factorloc.datasets.rosbag import OdometryTrack
from factorloc.errors import InputError
from factorloc.evaluation.relations import Relations

__all__ = ["GRID_STEPS_M", "SQUARE_MEAN_DISTANCE", "RelationsLattice", "find_relations_grid", "relations_lattice"]

#: The grid steps :func:`find_relations_grid` tries (m).
GRID_STEPS_M = (0.005, 0.01, 0.02, 0.025, 0.05, 0.1)

#: Mean distance of a uniform point of the unit square from its centre, (√2 + asinh 1) / 6.
SQUARE_MEAN_DISTANCE = (math.sqrt(2.0) + math.asinh(1.0)) / 6.0


@dataclass(frozen=True, eq=False)
class RelationsLattice:
    """The lattice test of one log's relations against its odometry (see the module docstring).

    ``residual_norms_m`` (N,) is ``|t_relation − t_odometry|`` of each relation (m; the relative translations in
    the robot frame at t1), ``on_lattice`` (N,) whether it lies within ``tolerance_m`` of ``step_m·√(a² + b²)``.
    """

    step_m: float
    tolerance_m: float
    residual_norms_m: np.ndarray
    on_lattice: np.ndarray
    chance_rate: float

    @property
    def rate(self) -> float:
        """Share of the relations on the lattice."""
        return float(self.on_lattice.mean()) if len(self.on_lattice) else math.nan

    @property
    def grid_share(self) -> float:
        """The share of the relations made on the grid, the hits by chance removed: ``(rate − chance)/(1 − chance)``
        (a relation off the grid lands on it at the chance rate), clipped to [0, 1]."""
        if not len(self.on_lattice) or self.chance_rate >= 1.0:
            return math.nan
        return float(np.clip((self.rate - self.chance_rate) / (1.0 - self.chance_rate), 0.0, 1.0))

    @property
    def floor_mean_error_m(self) -> float:
        """The least mean translational error (m) over all relations of an estimate of the true motion whose error
        does not depend on where the truth lies in the grid cell: ``0.383 s`` times :attr:`grid_share`."""
        return SQUARE_MEAN_DISTANCE * self.step_m * self.grid_share

    def summary(self) -> str:
        """One line for a report (cm)."""
        n = len(self.on_lattice)
        return (
            f"{int(self.on_lattice.sum())} of {n} relations ({100 * self.rate:.1f} %) are the odometry moved by whole "
            f"{100 * self.step_m:g} cm grid steps (chance {100 * self.chance_rate:.1f} %); no estimate of the true "
            f"motion errs less than {100 * self.floor_mean_error_m:.2f} cm on average over all relations against them"
        )


def _lattice_norms(step_m: float, max_norm_m: float) -> np.ndarray:
    k = int(math.ceil(max_norm_m / step_m)) + 1
    a = np.arange(k + 1, dtype=np.float64)
    norms = step_m * np.hypot(a[:, None], a[None, :]).ravel()
    return np.unique(norms[norms <= max_norm_m + step_m])


def _near(norms: np.ndarray, lattice: np.ndarray, tolerance_m: float) -> np.ndarray:
    j = np.clip(np.searchsorted(lattice, norms), 1, len(lattice) - 1)
    return np.minimum(np.abs(norms - lattice[j - 1]), np.abs(norms - lattice[j])) <= tolerance_m


def relations_lattice(
    relations: Relations,
    odometry: OdometryTrack,
    *,
    step_m: float = 0.05,
    tolerance_m: float = 5e-4,
    max_norm_m: float = 0.5,
) -> RelationsLattice:
    """Test whether ``relations`` are ``odometry`` moved by whole grid steps of ``step_m`` (m).

    Parameters
    ----------
    relations
        The log's ground-truth relations (:func:`~factorloc.evaluation.relations.read_relations`).
    odometry
        Its odometry (:attr:`~factorloc.datasets.rosbag.LaserLog.odometry`); stamps outside its span are clamped.
    step_m
        The grid step tested (m).
    tolerance_m
        How near a lattice norm a residual must lie (m); the relations files give 5 decimals (10 µm).
    max_norm_m
        Residuals above this (m) are not on the lattice (a loop relation against the drifted odometry).

    Raises
    ------
    InputError
        On a non-positive or non-finite step, tolerance or bound, a tolerance of half a step or more, or no
        relation.
    """
    for name, v in (("step_m", step_m), ("tolerance_m", tolerance_m), ("max_norm_m", max_norm_m)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0.0):
            raise InputError(f"{name} must be a finite number > 0, got {v!r}")
    if tolerance_m >= 0.5 * step_m:
        raise InputError(f"tolerance_m ({tolerance_m}) must be below half the step ({step_m})")
    if not isinstance(relations, Relations) or len(relations) == 0:
        raise InputError("relations must be a non-empty Relations")
    if not isinstance(odometry, OdometryTrack):
        raise InputError(f"odometry must be an OdometryTrack, got {type(odometry).__name__}")
    lo, hi = float(odometry.stamps_s[0]), float(odometry.stamps_s[-1])
    norms = np.empty(len(relations))
    for k, (t1, t2, P) in enumerate(zip(relations.t1_s, relations.t2_s, relations.poses, strict=True)):
        D = odometry.between(float(np.clip(t1, lo, hi)), float(np.clip(t2, lo, hi)))
        norms[k] = math.hypot(float(P[0]) - D.x, float(P[1]) - D.y)
    lattice = _lattice_norms(step_m, max_norm_m)
    on = _near(norms, lattice, tolerance_m) & (norms <= max_norm_m)
    rng = np.random.default_rng(0)
    moved = np.abs(norms + rng.uniform(-0.5 * step_m, 0.5 * step_m, len(norms)))
    chance = float((_near(moved, lattice, tolerance_m) & (moved <= max_norm_m)).mean())
    return RelationsLattice(float(step_m), float(tolerance_m), norms, on, chance)


def find_relations_grid(
    relations: Relations,
    odometry: OdometryTrack,
    *,
    steps_m: tuple[float, ...] = GRID_STEPS_M,
    min_share: float = 0.5,
    tolerance_m: float = 5e-4,
) -> RelationsLattice | None:
    """The grid a log's relations were rounded to, if any: :func:`relations_lattice` at each of ``steps_m``.

    A grid of step s also puts its relations on every grid whose step divides s (5 cm steps are 1 cm steps), so
    the step is the *largest* whose :attr:`~RelationsLattice.grid_share` is within 95 % of the best share of all
    the steps tried; None when no step puts at least ``min_share`` of the relations on its grid beyond chance.
    (What it finds on the three laser logs: ``docs/mapping.md``, "How exact the ground truth itself is".)
    """
    if not steps_m:
        raise InputError("steps_m must name at least one grid step")
    tried = [relations_lattice(relations, odometry, step_m=s, tolerance_m=min(tolerance_m, 0.4 * s)) for s in steps_m]
    best = max(t.grid_share for t in tried)
    if not best >= min_share:
        return None
    return max((t for t in tried if t.grid_share >= 0.95 * best), key=lambda t: t.step_m)

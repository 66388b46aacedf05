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

The heading has its own test (:func:`heading_lattice`, :func:`find_heading_grid`): ``θ_relation − θ_odometry`` on
``offset + k·h`` for a heading step ``h`` (the matcher's angular step; the offset, one per log, is the circular
mean of the residuals modulo ``h``).

:func:`truth_rounding` turns what both tests find into a covariance per relation: a truth rounded to a grid cell
is off by a uniform error over the cell, variance ``s²/12`` per axis (``h²/12`` in heading). Judging an estimate
against such a relation with its own covariance alone counts the rounding as the estimator's error; the relations
benchmark adds this covariance (:func:`~factorloc.evaluation.relations.relations_benchmark`, ``truth_rounding``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from factorloc.datasets.rosbag import OdometryTrack
from factorloc.errors import InputError
from factorloc.evaluation.relations_data import Relations

__all__ = [
    "GRID_STEPS_M",
    "HEADING_GRID_STEPS_RAD",
    "MAX_NORM_M",
    "MIN_GRID_SHARE",
    "SQUARE_MEAN_DISTANCE",
    "TOLERANCE_M",
    "HeadingLattice",
    "RelationsLattice",
    "TruthRounding",
    "find_heading_grid",
    "find_relations_grid",
    "heading_lattice",
    "relations_lattice",
    "truth_rounding",
]

#: Residual norms above this (m) are never on a translation lattice (a loop relation against the drifted odometry).
MAX_NORM_M = 0.5

#: How near a lattice norm a translation residual must lie (m); the relations files give 5 decimals (10 µm).
TOLERANCE_M = 5e-4

#: The share of the relations a grid must hold beyond chance to be reported (:func:`find_relations_grid`,
#: :func:`find_heading_grid`).
MIN_GRID_SHARE = 0.5

#: The grid steps :func:`find_relations_grid` tries (m).
GRID_STEPS_M = (0.005, 0.01, 0.02, 0.025, 0.05, 0.1)

#: The heading steps :func:`find_heading_grid` tries (rad): 0.1°, 0.25°, 0.5°, 1°.
HEADING_GRID_STEPS_RAD = tuple(math.radians(d) for d in (0.1, 0.25, 0.5, 1.0))

#: How near ``offset + k·h`` a heading residual must lie (rad): 0.002°, 3.5e-5 rad; the relations files give
#: 5 decimals (1e-5 rad).
HEADING_TOLERANCE_RAD = math.radians(0.002)

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
    tolerance_m: float = TOLERANCE_M,
    max_norm_m: float = MAX_NORM_M,
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
    return _translation_lattice(relations, _relative_odometry(relations, odometry), step_m, tolerance_m, max_norm_m)


def _translation_lattice(
    relations: Relations, odo: np.ndarray, step_m: float, tolerance_m: float, max_norm_m: float
) -> RelationsLattice:
    """:func:`relations_lattice` on the relations' odometry ``odo`` (:func:`_relative_odometry`)."""
    for name, v in (("step_m", step_m), ("tolerance_m", tolerance_m), ("max_norm_m", max_norm_m)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0.0):
            raise InputError(f"{name} must be a finite number > 0, got {v!r}")
    if tolerance_m >= 0.5 * step_m:
        raise InputError(f"tolerance_m ({tolerance_m}) must be below half the step ({step_m})")
    norms = np.hypot(relations.poses[:, 0] - odo[:, 0], relations.poses[:, 1] - odo[:, 1])
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
    min_share: float = MIN_GRID_SHARE,
    tolerance_m: float = TOLERANCE_M,
) -> RelationsLattice | None:
    """The grid a log's relations were rounded to, if any: :func:`relations_lattice` at each of ``steps_m``.

    A grid of step s also puts its relations on every grid whose step divides s (5 cm steps are 1 cm steps), so
    the step is the *largest* whose :attr:`~RelationsLattice.grid_share` is within 95 % of the best share of all
    the steps tried; None when no step puts at least ``min_share`` of the relations on its grid beyond chance.
    (What it finds on the three laser logs: ``docs/mapping.md``, "How exact the ground truth itself is".)
    """
    return _find_relations_grid(relations, _relative_odometry(relations, odometry), steps_m, min_share, tolerance_m)


def _find_relations_grid(
    relations: Relations, odo: np.ndarray, steps_m: tuple[float, ...], min_share: float, tolerance_m: float
) -> RelationsLattice | None:
    if not steps_m:
        raise InputError("steps_m must name at least one grid step")
    tried = [_translation_lattice(relations, odo, s, min(tolerance_m, 0.4 * s), MAX_NORM_M) for s in steps_m]
    return _largest_near_best(tried, [t.step_m for t in tried], min_share)


def _largest_near_best(tried: list, steps: list[float], min_share: float):  # noqa: ANN202 - a lattice of ``tried``
    """Of the lattices ``tried`` (steps ``steps``), the one of the largest step whose grid share is within 95 % of
    the best; None when the best is below ``min_share``."""
    best = max(t.grid_share for t in tried)
    if not best >= min_share:
        return None
    return max((t for t in zip(steps, tried, strict=True) if t[1].grid_share >= 0.95 * best), key=lambda t: t[0])[1]


@dataclass(frozen=True, eq=False)
class HeadingLattice:
    """The heading lattice test of one log's relations (see the module docstring).

    ``residuals_rad`` (N,) is ``θ_relation − θ_odometry`` wrapped to (−π, π], ``on_lattice`` (N,) whether it lies
    within ``tolerance_rad`` of ``offset_rad + k·step_rad``; ``chance_rate`` is ``2·tolerance/step``, the rate of
    a residual uniform over a step.
    """

    step_rad: float
    offset_rad: float
    tolerance_rad: float
    residuals_rad: np.ndarray
    on_lattice: np.ndarray

    @property
    def chance_rate(self) -> float:
        return 2.0 * self.tolerance_rad / self.step_rad

    @property
    def rate(self) -> float:
        """Share of the relations on the lattice."""
        return float(self.on_lattice.mean()) if len(self.on_lattice) else math.nan

    @property
    def grid_share(self) -> float:
        """As :attr:`RelationsLattice.grid_share`: the share made on the grid, the chance hits removed."""
        if not len(self.on_lattice):
            return math.nan
        return float(np.clip((self.rate - self.chance_rate) / (1.0 - self.chance_rate), 0.0, 1.0))


def _relative_odometry(relations: Relations, odometry: OdometryTrack) -> np.ndarray:
    """(N, 3) the odometry's ``[x, y, θ]`` of each relation (robot frame at t1; stamps clamped to its span)."""
    if not isinstance(relations, Relations) or len(relations) == 0:
        raise InputError("relations must be a non-empty Relations")
    if not isinstance(odometry, OdometryTrack):
        raise InputError(f"odometry must be an OdometryTrack, got {type(odometry).__name__}")
    lo, hi = float(odometry.stamps_s[0]), float(odometry.stamps_s[-1])
    out = np.empty((len(relations), 3))
    for k, (t1, t2) in enumerate(zip(relations.t1_s, relations.t2_s, strict=True)):
        D = odometry.between(float(np.clip(t1, lo, hi)), float(np.clip(t2, lo, hi)))
        out[k] = (D.x, D.y, D.theta)
    return out


def heading_lattice(
    relations: Relations,
    odometry: OdometryTrack,
    *,
    step_rad: float,
    tolerance_rad: float = HEADING_TOLERANCE_RAD,
) -> HeadingLattice:
    """Test whether the headings of ``relations`` are the odometry's turned by whole steps of ``step_rad``.

    The offset is the circular mean of the residuals modulo the step (closed form, no search).

    Raises
    ------
    InputError
        On a non-positive or non-finite step or tolerance, a tolerance of half a step or more, or no relation.
    """
    return _heading_lattice(relations, _relative_odometry(relations, odometry), step_rad, tolerance_rad)


def _heading_lattice(relations: Relations, odo: np.ndarray, step_rad: float, tolerance_rad: float) -> HeadingLattice:
    """:func:`heading_lattice` on the relations' odometry ``odo`` (:func:`_relative_odometry`)."""
    for name, v in (("step_rad", step_rad), ("tolerance_rad", tolerance_rad)):
        if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0.0):
            raise InputError(f"{name} must be a finite number > 0, got {v!r}")
    if tolerance_rad >= 0.5 * step_rad:
        raise InputError(f"tolerance_rad ({tolerance_rad}) must be below half the step ({step_rad})")
    res = np.remainder(relations.poses[:, 2] - odo[:, 2] + math.pi, 2.0 * math.pi) - math.pi
    phase = np.exp(1j * (2.0 * math.pi / step_rad) * res)
    offset = float(np.angle(phase.mean())) * step_rad / (2.0 * math.pi)
    dev = np.remainder(res - offset + 0.5 * step_rad, step_rad) - 0.5 * step_rad
    return HeadingLattice(float(step_rad), offset, float(tolerance_rad), res, np.abs(dev) <= tolerance_rad)


def find_heading_grid(
    relations: Relations,
    odometry: OdometryTrack,
    *,
    steps_rad: tuple[float, ...] = HEADING_GRID_STEPS_RAD,
    min_share: float = MIN_GRID_SHARE,
) -> HeadingLattice | None:
    """The heading grid of a log's relations, if any: as :func:`find_relations_grid`, over ``steps_rad``."""
    return _find_heading_grid(relations, _relative_odometry(relations, odometry), steps_rad, min_share)


def _find_heading_grid(
    relations: Relations, odo: np.ndarray, steps_rad: tuple[float, ...], min_share: float
) -> HeadingLattice | None:
    if not steps_rad:
        raise InputError("steps_rad must name at least one heading step")
    tried = [_heading_lattice(relations, odo, h, min(HEADING_TOLERANCE_RAD, 0.4 * h)) for h in steps_rad]
    return _largest_near_best(tried, [t.step_rad for t in tried], min_share)


@dataclass(frozen=True, eq=False)
class TruthRounding:
    """The ground truth's own error per relation where it was rounded to a grid (see the module docstring).

    ``translation`` / ``heading`` are the grids found (None: not rounded); a relation on a grid is off by a uniform
    error over its cell: variance ``s²/12`` per position axis, ``h²/12`` in heading.
    """

    translation: RelationsLattice | None
    heading: HeadingLattice | None

    @classmethod
    def none(cls) -> TruthRounding:
        """Relations taken as exact."""
        return cls(None, None)

    def covariance(self, index: int) -> np.ndarray:
        """The 3×3 covariance (m², rad²; isotropic in position, so in any frame) of relation ``index``'s rounding."""
        vp = self.translation.step_m**2 / 12.0 if self.translation is not None and self.translation.on_lattice[index] else 0.0
        vh = self.heading.step_rad**2 / 12.0 if self.heading is not None and self.heading.on_lattice[index] else 0.0
        return np.diag([vp, vp, vh])

    def rounded(self) -> np.ndarray:
        """(N,) whether each relation is on either grid (empty when neither grid was found)."""
        grids = [g.on_lattice for g in (self.translation, self.heading) if g is not None]
        if not grids:
            return np.zeros(0, dtype=bool)
        return np.logical_or.reduce(grids)

    def summary(self) -> str:
        """One line for a report."""
        if self.translation is None and self.heading is None:
            return "ground truth taken as exact (no grid found in its relations)"
        parts = []
        if self.translation is not None:
            t = self.translation
            parts.append(f"translation on a {100 * t.step_m:g} cm grid ({int(t.on_lattice.sum())} of {len(t.on_lattice)})")
        if self.heading is not None:
            h = self.heading
            parts.append(f"heading on a {math.degrees(h.step_rad):g}° grid ({int(h.on_lattice.sum())} of {len(h.on_lattice)})")
        return "ground truth rounded: " + ", ".join(parts) + "; judged with the rounding's covariance added"


def truth_rounding(relations: Relations, odometry: OdometryTrack) -> TruthRounding:
    """The rounding of a log's relations to the grid of the matcher that made them (:func:`find_relations_grid`,
    :func:`find_heading_grid`; :meth:`TruthRounding.none` when neither finds one)."""
    odo = _relative_odometry(relations, odometry)  # once: the odometry between each relation's stamps
    return TruthRounding(
        _find_relations_grid(relations, odo, GRID_STEPS_M, MIN_GRID_SHARE, TOLERANCE_M),
        _find_heading_grid(relations, odo, HEADING_GRID_STEPS_RAD, MIN_GRID_SHARE),
    )

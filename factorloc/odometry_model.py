"""How the odometry's σ grows with the motion, and how to fit that growth to a robot's own log.

Wheel odometry integrates small errors, so its uncertainty grows with the path.
:class:`OdometryModel` is the model :meth:`factorloc.Odometry.from_distance` implements::

    σx = σy = max(min_sigma_m, drift_ratio · d)
    σθ      = max(min_sigma_rad, heading_drift_ratio · |r| + heading_drift_rad_per_m · d)

for a path of length ``d`` (m) and a summed absolute rotation ``r`` (rad) since the
last reset (the reference). The patent's example (WO 2015/158682: 5 % drift, 1 m →
σ 5 cm) is one instance of this form; a real robot's numbers depend on its wheels,
floor and calibration, and the drift of old wheel odometry is heavy-tailed.

:func:`fit_odometry_model` fits the five numbers to a log with ground truth
(relative poses between times, e.g. the relations of Kümmerle et al. 2009) for an
*honest tail*: what the gating and the confidently-wrong figure test is whether the
odometry lies beyond its 3σ region, which a Gaussian does 0.27 % of the time. Per
component (position, heading), among the models whose share of relations beyond 3σ
does not exceed that probability on *each* log given, it picks the sharpest (smallest
mean log σ). :func:`odometry_residuals` and :func:`assess_odometry_model` give the
figures (tail shares, NEES) of a model on held-out data. The leave-one-log-out folds
on the Intel, ACES and MIT CSAIL logs are in ``docs/calibration/odometry.md``.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import asdict, dataclass
from typing import Any, Protocol

import numpy as np

from factorloc._validate import nonnegative_float, positive_float
from factorloc.errors import InputError
from factorloc.geometry import Pose2, wrap_angle
from factorloc.types import Odometry
from factorloc.verdicts import ROUNDING_TOLERANCE

__all__ = [
    "CHI2_3SIGMA_2DOF",
    "GAUSSIAN_3SIGMA_TAIL",
    "OdometryAssessment",
    "OdometryModel",
    "OdometryResiduals",
    "RelativePoses",
    "assess_odometry_model",
    "fit_odometry_model",
    "odometry_residuals",
]

#: P(|z| > 3) for a standard normal: the share of a Gaussian beyond 3σ (1 dof).
GAUSSIAN_3SIGMA_TAIL = math.erfc(3.0 / math.sqrt(2.0))
#: The 2-dof χ² quantile of probability 1 − :data:`GAUSSIAN_3SIGMA_TAIL` (the 3σ ellipse, 11.83): for 2 dof the χ²
#: quantile has the closed form −2·ln(1 − p), equal to :func:`factorloc.stats.chi2_quantile` (no scipy import here).
CHI2_3SIGMA_2DOF = -2.0 * math.log(GAUSSIAN_3SIGMA_TAIL)


@dataclass(frozen=True)
class OdometryModel:
    """σ of a robot's odometry as a function of the motion since the reference.

    The defaults are the model of the relations benchmark
    (:mod:`factorloc.evaluation.relations`), fitted for an honest 3σ tail on the local
    relations (path < 5 m) of the Intel Research Lab and ACES logs — raw wheel odometry of
    two old indoor robots; cautious in the bulk, the price of an honest tail on heavy-tailed
    drift. They are a starting point, not your robot: fit yours with :func:`fit_odometry_model`
    (``docs/calibration/odometry.md`` has the leave-one-log-out folds, and how far the patent's 5 %
    example is from these logs).

    Parameters
    ----------
    drift_ratio
        Position σ per metre of path (dimensionless).
    min_sigma_m
        Position σ floor (m): ground truth and odometry disagree by a few cm even at rest.
    heading_drift_ratio
        Heading σ per radian of summed absolute rotation (dimensionless).
    heading_drift_rad_per_m
        Heading σ per metre of path (rad/m).
    min_sigma_rad
        Heading σ floor (rad).
    """

    drift_ratio: float = 0.2
    min_sigma_m: float = 0.05
    heading_drift_ratio: float = 0.15
    heading_drift_rad_per_m: float = 0.08
    min_sigma_rad: float = math.radians(0.3)

    def __post_init__(self) -> None:
        for name in ("drift_ratio", "heading_drift_ratio", "heading_drift_rad_per_m"):
            object.__setattr__(self, name, nonnegative_float(f"OdometryModel.{name}", getattr(self, name)))
        for name in ("min_sigma_m", "min_sigma_rad"):
            object.__setattr__(self, name, positive_float(f"OdometryModel.{name}", getattr(self, name)))

    def sigma_position_m(self, distance_m: np.ndarray | float) -> np.ndarray:
        """σx = σy (m) after a path of ``distance_m``."""
        return np.maximum(self.min_sigma_m, self.drift_ratio * np.asarray(distance_m, dtype=np.float64))

    def sigma_heading_rad(self, distance_m: np.ndarray | float, rotation_rad: np.ndarray | float) -> np.ndarray:
        """σθ (rad) after a path of ``distance_m`` with summed absolute rotation ``rotation_rad``."""
        d = np.asarray(distance_m, dtype=np.float64)
        r = np.abs(np.asarray(rotation_rad, dtype=np.float64))
        return np.maximum(self.min_sigma_rad, self.heading_drift_ratio * r + self.heading_drift_rad_per_m * d)

    def odometry(self, T_world_robot: Pose2, distance_m: float, rotation_rad: float) -> Odometry:
        """The :class:`~factorloc.Odometry` of a dead-reckoned pose with this model's σ."""
        return Odometry.from_distance(
            T_world_robot,
            distance_m,
            rotation_rad,
            drift_ratio=self.drift_ratio,
            heading_drift_ratio=self.heading_drift_ratio,
            heading_drift_rad_per_m=self.heading_drift_rad_per_m,
            min_sigma_m=self.min_sigma_m,
            min_sigma_rad=self.min_sigma_rad,
        )

    def to_dict(self) -> dict[str, float]:
        """The five numbers, as :meth:`from_dict` reads them (a YAML/JSON-ready mapping)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> OdometryModel:
        """Inverse of :meth:`to_dict`; unknown keys are rejected with their names."""
        if not isinstance(data, Mapping):
            raise InputError(f"an odometry model must be a mapping, got {type(data).__name__}")
        known = set(cls.__dataclass_fields__)
        unknown = sorted(set(data) - known)
        if unknown:
            raise InputError(f"unknown odometry model key(s) {unknown}; known: {sorted(known)}")
        return cls(**{k: data[k] for k in data})


# --------------------------------------------------------------------------
# Residuals of a log against its ground truth
# --------------------------------------------------------------------------
class RelativePoses(Protocol):
    """Ground-truth relative poses: (N,) times ``t1_s``, ``t2_s`` and (N, 3) ``poses``.

    ``poses[i] = [x_m, y_m, yaw_rad]`` of the robot at ``t2_s[i]`` in the robot frame at ``t1_s[i]``
    (e.g. :class:`factorloc.evaluation.relations.Relations`).
    """

    t1_s: np.ndarray
    t2_s: np.ndarray
    poses: np.ndarray


class _Track(Protocol):
    def between(self, t1_s: float, t2_s: float) -> Pose2: ...
    def distance_between(self, t1_s: float, t2_s: float) -> tuple[float, float]: ...


class _Log(Protocol):
    odometry: _Track


@dataclass(frozen=True, eq=False)
class OdometryResiduals:
    """The odometry's error on each ground-truth relation (N relations).

    ``distance_m``, ``rotation_rad``: path length and summed absolute rotation between the two
    times; ``error_xy_m`` (N, 2): odometry − truth position in the robot frame at ``t1``;
    ``error_theta_rad`` (N,): odometry − truth heading, wrapped.
    """

    distance_m: np.ndarray
    rotation_rad: np.ndarray
    error_xy_m: np.ndarray
    error_theta_rad: np.ndarray
    source: str = ""

    def __len__(self) -> int:
        return int(self.distance_m.shape[0])

    @property
    def error_position_m(self) -> np.ndarray:
        """(N,) position error norms (m)."""
        return np.hypot(self.error_xy_m[:, 0], self.error_xy_m[:, 1])


def odometry_residuals(log: _Log, relations: RelativePoses, *, max_path_m: float = 5.0, source: str = "") -> OdometryResiduals:
    """The odometry's error on every relation whose odometry path is shorter than ``max_path_m``.

    Parameters
    ----------
    log
        A log with an ``odometry`` track (:class:`factorloc.datasets.rosbag.LaserLog`).
    relations
        Its ground truth (:class:`RelativePoses`).
    max_path_m
        Relations with a longer odometry path are left out: beyond a few metres the odometry
        is no seed (the relations benchmark calls them loops).

    Raises
    ------
    InputError
        When no relation is shorter than ``max_path_m``.
    """
    limit = positive_float("max_path_m", max_path_m)
    t1 = np.asarray(relations.t1_s, dtype=np.float64)
    t2 = np.asarray(relations.t2_s, dtype=np.float64)
    poses = np.asarray(relations.poses, dtype=np.float64)
    d, r, exy, eth = [], [], [], []
    for a, b, p in zip(t1, t2, poses, strict=True):
        dist, rot = log.odometry.distance_between(float(a), float(b))
        if dist >= limit:
            continue
        seed = log.odometry.between(float(a), float(b))
        d.append(dist)
        r.append(rot)
        exy.append((seed.x - p[0], seed.y - p[1]))
        eth.append(float(wrap_angle(seed.theta - p[2])))
    if not d:
        raise InputError(f"no relation of {source or 'the log'} has an odometry path shorter than {limit} m")
    return OdometryResiduals(np.array(d), np.array(r), np.array(exy).reshape(-1, 2), np.array(eth), source)


@dataclass(frozen=True)
class OdometryAssessment:
    """How honest a model is on some residuals.

    ``tail_position`` / ``tail_heading``: shares of relations beyond the 3σ ellipse (2 dof) /
    beyond 3σθ — :data:`GAUSSIAN_3SIGMA_TAIL` (0.27 %) for an honest model; ``nees_position``
    (2 expected) and ``nees_heading`` (1 expected): mean normalized squared errors;
    ``median_sigma_m`` / ``median_sigma_rad``: how wide the model is on these relations.
    """

    source: str
    n: int
    tail_position: float
    tail_heading: float
    nees_position: float
    nees_heading: float
    median_sigma_m: float
    median_sigma_rad: float

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def assess_odometry_model(model: OdometryModel, residuals: OdometryResiduals) -> OdometryAssessment:
    """Tail shares, NEES and typical σ of ``model`` on ``residuals``."""
    s = model.sigma_position_m(residuals.distance_m)
    st = model.sigma_heading_rad(residuals.distance_m, residuals.rotation_rad)
    d2 = (residuals.error_position_m / s) ** 2
    h2 = (residuals.error_theta_rad / st) ** 2
    return OdometryAssessment(
        residuals.source,
        len(residuals),
        float(np.mean(d2 > CHI2_3SIGMA_2DOF)),
        float(np.mean(h2 > 9.0)),
        float(np.mean(d2)),
        float(np.mean(h2)),
        float(np.median(s)),
        float(np.median(st)),
    )


# --------------------------------------------------------------------------
# Fitting
# --------------------------------------------------------------------------
#: Candidate floors of the fit: position 0.5–20 cm, heading 0.05–2°.
POSITION_FLOORS_M = tuple(np.round(np.arange(0.005, 0.2001, 0.0025), 4))
HEADING_FLOORS_RAD = tuple(math.radians(v) for v in np.round(np.arange(0.05, 2.0001, 0.05), 3))
#: Candidate heading σ per metre (rad/m) of the fit.
HEADING_PER_M = tuple(np.round(np.arange(0.0, 0.2001, 0.0025), 4))


def _allowed(n: int, tail: float) -> int:
    """How many of ``n`` relations may lie beyond 3σ: ⌊tail·n⌋."""
    return int(math.floor(tail * n + 1e-9))


def _min_slope(excess: np.ndarray, per: np.ndarray, allowed: int) -> float | None:
    """Smallest k ≥ 0 with #{i: excess_i > k·per_i} ≤ allowed; None when impossible.

    ``excess_i > 0`` are the relations the floor alone leaves beyond 3σ; ``per_i ≥ 0`` the
    σ-per-unit-slope of each (a relation with ``per_i = 0`` cannot be brought in by the slope).
    """
    bad = excess > 0.0
    fixed = int(np.count_nonzero(bad & (per <= 0.0)))
    if fixed > allowed:
        return None
    need = np.sort(excess[bad & (per > 0.0)] / per[bad & (per > 0.0)])[::-1]
    room = allowed - fixed
    # the relation at the boundary lies exactly on 3σ: widen by the rounding tolerance so that its
    # verdict (inside) does not hang on the last bit of σ = k·d
    return float(need[room]) * (1.0 + ROUNDING_TOLERANCE) if room < need.size else 0.0


def _fit_position(res: Sequence[OdometryResiduals], tail: float) -> tuple[float, float]:
    c = math.sqrt(CHI2_3SIGMA_2DOF)
    best: tuple[float, float, float] | None = None
    for floor in POSITION_FLOORS_M:
        slopes = []
        for r in res:
            # beyond 3σ ⇔ |e| > c·max(floor, k·d) ⇔ |e| > c·floor and |e|/c > k·d
            e = r.error_position_m / c
            k = _min_slope(np.where(e > floor, e, 0.0), r.distance_m, _allowed(len(r), tail))
            slopes.append(k)
        if any(k is None for k in slopes):
            continue
        k = max(slopes)  # type: ignore[type-var]
        score = float(np.mean([np.mean(np.log(np.maximum(floor, k * r.distance_m))) for r in res]))
        if best is None or score < best[0] - 1e-12:
            best = (score, floor, k)
    if best is None:
        raise InputError("no position model of the candidate floors reaches the tail target")
    return best[1], best[2]


def _fit_heading(res: Sequence[OdometryResiduals], tail: float) -> tuple[float, float, float]:
    best: tuple[float, float, float, float] | None = None
    for floor in HEADING_FLOORS_RAD:
        for kd in HEADING_PER_M:
            slopes = []
            for r in res:
                # beyond 3σ ⇔ |e|/3 > floor and |e|/3 − kd·d > kh·|r|
                e = np.abs(r.error_theta_rad) / 3.0
                excess = np.where(e > floor, e - kd * r.distance_m, 0.0)
                slopes.append(_min_slope(excess, np.abs(r.rotation_rad), _allowed(len(r), tail)))
            if any(k is None for k in slopes):
                continue
            kh = max(slopes)  # type: ignore[type-var]
            score = float(
                np.mean([np.mean(np.log(np.maximum(floor, kh * np.abs(r.rotation_rad) + kd * r.distance_m))) for r in res])
            )
            if best is None or score < best[0] - 1e-12:
                best = (score, floor, kh, kd)
    if best is None:
        raise InputError("no heading model of the candidate floors and slopes reaches the tail target")
    return best[1], best[2], best[3]


def fit_odometry_model(
    log: _Log | Sequence[_Log],
    relations: RelativePoses | Sequence[RelativePoses],
    *,
    max_path_m: float = 5.0,
    tail_probability: float = GAUSSIAN_3SIGMA_TAIL,
) -> OdometryModel:
    """Fit an :class:`OdometryModel` to one or several logs with ground truth, for an honest 3σ tail.

    Per component: position (floor and drift ratio) and heading (floor, σ per radian turned,
    σ per metre). Among the candidates (floors on the grids :data:`POSITION_FLOORS_M`,
    :data:`HEADING_FLOORS_RAD`, :data:`HEADING_PER_M`; for each, the smallest slope that keeps
    the share of relations beyond 3σ at or below ``tail_probability`` on *every* log, computed
    exactly), the sharpest is kept: the smallest mean log σ, averaged over the logs. A log's
    share beyond 3σ is at most ⌊``tail_probability``·N⌋ of its N relations.

    Parameters
    ----------
    log
        A log with an ``odometry`` track (:class:`factorloc.datasets.rosbag.LaserLog`), or a
        sequence of them (each log must then meet the tail on its own).
    relations
        Its ground truth (:class:`RelativePoses`), or a sequence of the same length as ``log``.
    max_path_m
        Only relations with an odometry path shorter than this are used (see :func:`odometry_residuals`).
    tail_probability
        The target share beyond 3σ (default the Gaussian's 0.27 %).

    Returns
    -------
    OdometryModel
        Check it on held-out data with :func:`assess_odometry_model`.
    """
    logs = list(log) if isinstance(log, Sequence) else [log]
    rels = list(relations) if isinstance(relations, Sequence) else [relations]
    if len(logs) != len(rels) or not logs:
        raise InputError(f"fit_odometry_model needs as many relations as logs, got {len(logs)} logs, {len(rels)} relations")
    tail = positive_float("tail_probability", tail_probability)
    if tail >= 0.5:
        raise InputError(f"tail_probability must be < 0.5, got {tail!r}")
    res = [
        odometry_residuals(lg, rl, max_path_m=max_path_m, source=getattr(lg, "source", ""))
        for lg, rl in zip(logs, rels, strict=True)
    ]
    floor_m, k = _fit_position(res, tail)
    floor_rad, kh, kd = _fit_heading(res, tail)
    return OdometryModel(
        drift_ratio=k, min_sigma_m=floor_m, heading_drift_ratio=kh, heading_drift_rad_per_m=kd, min_sigma_rad=floor_rad
    )

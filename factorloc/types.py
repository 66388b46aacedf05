"""Frozen, validated value types: the inputs (panorama, camera image, point
cloud, scan, odometry, reference, query) and the outputs (estimate, step
report, localization).

Frames and conventions (REP-103): x forward, y left, z up, headings
counter-clockwise in radians. World-frame poses are ``T_world_robot``.
Images are OpenCV BGR ``uint8`` arrays. Every constructor validates its
fields and raises :class:`~factorloc.errors.InputError` naming the bad field.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from enum import StrEnum
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np

from factorloc._validate import bgr_image, finite_float, float_array, nonnegative_float, positive_float
from factorloc.errors import InputError
from factorloc.geometry import Pose2, wrap_angle
from factorloc.verdicts import Check, SeedEvidence, failed, render_checks

if TYPE_CHECKING:  # pragma: no cover
    from factorloc.config import Config


# --------------------------------------------------------------------------
# Components
# --------------------------------------------------------------------------
class Component(StrEnum):
    """A pose component an estimate can measure."""

    X = "x"
    Y = "y"
    THETA = "theta"


#: The component sets an :class:`Estimate` may measure, in canonical order.
HEADING: tuple[Component, ...] = (Component.THETA,)
POSITION: tuple[Component, ...] = (Component.X, Component.Y)
FULL: tuple[Component, ...] = (Component.X, Component.Y, Component.THETA)
_ALLOWED_COMPONENTS = {HEADING: "heading", POSITION: "position", FULL: "full"}
_INDEX = {Component.X: 0, Component.Y: 1, Component.THETA: 2}


def _components(value: Any) -> tuple[Component, ...]:
    try:
        comps = tuple(sorted({Component(c) for c in value}, key=_INDEX.__getitem__))
    except (TypeError, ValueError) as exc:
        raise InputError(f"Estimate.components must be drawn from 'x', 'y', 'theta', got {value!r}") from exc
    if comps not in _ALLOWED_COMPONENTS:
        raise InputError(
            "Estimate.components must be ('theta',) heading-only, ('x', 'y') position-only "
            f"or ('x', 'y', 'theta') full pose, got {tuple(c.value for c in comps)}"
        )
    return comps


def _cholesky_pivots(c: list[list[float]]) -> list[float]:
    """The pivots ``d_i`` of the LDLᵀ factorization of a small symmetric matrix (all > 0 ⇔ positive definite).

    Plain Python for k ≤ 3: a numpy call costs more than the arithmetic. The
    factorization stops at the first pivot ≤ 0 (it is returned last).
    """
    k = len(c)
    L = [[0.0] * k for _ in range(k)]
    d: list[float] = []
    for j in range(k):
        dj = c[j][j] - sum(L[j][m] * L[j][m] * d[m] for m in range(j))
        d.append(dj)
        if not dj > 0.0:
            break
        for i in range(j + 1, k):
            L[i][j] = (c[i][j] - sum(L[i][m] * L[j][m] * d[m] for m in range(j))) / dj
    return d


def _covariance(name: str, value: Any, k: int) -> np.ndarray:
    cov = float_array(name, value, (k, k))
    if (np.abs(cov - cov.T) > 1e-15 + 1e-9 * np.abs(cov.T)).any():  # np.allclose(rtol=1e-9, atol=1e-15), cheaper
        raise InputError(f"{name} must be symmetric, got {cov.tolist()}")
    cov = 0.5 * (cov + cov.T)
    if not all(p > 0.0 for p in _cholesky_pivots(cov.tolist())):
        eig = np.linalg.eigvalsh(cov)
        raise InputError(f"{name} must be positive definite (all sigmas > 0), got eigenvalues {eig.tolist()}")
    cov.setflags(write=False)
    return cov


# --------------------------------------------------------------------------
# Estimate
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class Estimate:
    """One estimator's measurement of some pose components, in the world frame.

    Parameters
    ----------
    step
        Name of the step that made it (``"odometry"``, ``"compass"``, ``"correlation"``, ``"icp"``, …).
    components
        What it measures: ``("theta",)``, ``("x", "y")`` or ``("x", "y", "theta")``.
    values
        The measured values in the order of ``components`` (metres, radians; θ wrapped to [-π, π)).
    covariance
        k×k covariance of ``values`` (m², rad²), world frame. Per-axis estimates
        (the patent's case) have a diagonal one; use :meth:`heading`,
        :meth:`position` or :meth:`pose` to build from sigmas.
    reliable
        The estimator's own verdict.
    reason
        A human-readable reason for it. Without a ``reason``, an estimate with ``checks`` gets the
        one rendered from its failed checks (:func:`factorloc.verdicts.render_checks`).
    diagnostics
        Free-form figures for people and plots: match count, peak correlation, residual, scale… Nothing in
        the library decides on them: decisions travel as ``checks`` and ``seed``.
    checks
        The step's reliability rules as typed :class:`~factorloc.verdicts.Check` records, in the order they
        apply. An estimate with a failed check cannot be ``reliable``.
    seed
        What seeded the step and what its data say about that seed (:class:`~factorloc.verdicts.SeedEvidence`;
        None: the step used no seed and tested none). The gate's seed audit reads only this.
    """

    step: str
    components: tuple[Component, ...]
    values: np.ndarray
    covariance: np.ndarray
    reliable: bool = True
    reason: str = ""
    diagnostics: Mapping[str, Any] = field(default_factory=dict)
    checks: tuple[Check, ...] = ()
    seed: SeedEvidence | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.step, str) or not self.step:
            raise InputError(f"Estimate.step must be a non-empty string, got {self.step!r}")
        comps = _components(self.components)
        object.__setattr__(self, "components", comps)
        k = len(comps)
        values = np.array(float_array(f"Estimate({self.step}).values", self.values, (k,)))
        if comps[-1] is Component.THETA:
            values[-1] = wrap_angle(values[-1])
        values.setflags(write=False)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "covariance", _covariance(f"Estimate({self.step}).covariance", self.covariance, k))
        object.__setattr__(self, "reliable", bool(self.reliable))
        checks = tuple(self.checks)
        for c in checks:
            if not isinstance(c, Check):
                raise InputError(f"Estimate({self.step}).checks must hold factorloc.verdicts.Check, got {type(c).__name__}")
        if self.reliable and failed(checks):
            raise InputError(f"Estimate({self.step}) cannot be reliable with failed checks: {render_checks(checks)}")
        object.__setattr__(self, "checks", checks)
        if self.seed is not None and not isinstance(self.seed, SeedEvidence):
            raise InputError(f"Estimate({self.step}).seed must be a SeedEvidence or None, got {type(self.seed).__name__}")
        reason = str(self.reason)
        if not reason and not self.reliable and checks:
            reason = render_checks(checks)
        object.__setattr__(self, "reason", reason)
        object.__setattr__(self, "diagnostics", MappingProxyType(dict(self.diagnostics)))

    # --- builders -----------------------------------------------------------
    @classmethod
    def heading(cls, step: str, theta_rad: float, sigma_rad: float, **kwargs: Any) -> Estimate:
        """A heading-only estimate θ ± σ (radians)."""
        s = positive_float(f"Estimate({step}).sigma_theta_rad", sigma_rad)
        return cls(step, HEADING, [theta_rad], [[s * s]], **kwargs)

    @classmethod
    def position(
        cls,
        step: str,
        x_m: float,
        y_m: float,
        sigma_x_m: float | None = None,
        sigma_y_m: float | None = None,
        *,
        covariance: np.ndarray | None = None,
        **kwargs: Any,
    ) -> Estimate:
        """A position-only estimate (world-frame x, y) from sigmas or a 2×2 covariance."""
        if covariance is None:
            sx = positive_float(f"Estimate({step}).sigma_x_m", sigma_x_m)
            sy = positive_float(f"Estimate({step}).sigma_y_m", sigma_y_m)
            covariance = np.diag([sx * sx, sy * sy])
        return cls(step, POSITION, [x_m, y_m], covariance, **kwargs)

    @classmethod
    def pose(
        cls,
        step: str,
        pose: Pose2,
        sigma_x_m: float | None = None,
        sigma_y_m: float | None = None,
        sigma_theta_rad: float | None = None,
        *,
        covariance: np.ndarray | None = None,
        **kwargs: Any,
    ) -> Estimate:
        """A full-pose estimate from per-axis sigmas or a 3×3 world-frame covariance."""
        if covariance is None:
            sx = positive_float(f"Estimate({step}).sigma_x_m", sigma_x_m)
            sy = positive_float(f"Estimate({step}).sigma_y_m", sigma_y_m)
            st = positive_float(f"Estimate({step}).sigma_theta_rad", sigma_theta_rad)
            covariance = np.diag([sx * sx, sy * sy, st * st])
        return cls(step, FULL, pose.as_array(), covariance, **kwargs)

    # --- accessors ------------------------------------------------------------
    @property
    def kind(self) -> str:
        """``"heading"``, ``"position"`` or ``"full"``."""
        return _ALLOWED_COMPONENTS[self.components]

    @property
    def sigmas(self) -> np.ndarray:
        """Standard deviations of ``values`` (square roots of the covariance diagonal)."""
        return np.sqrt(np.diag(self.covariance))

    def measures(self, component: Component | str) -> bool:
        """Whether this estimate measures ``component``."""
        return Component(component) in self.components

    def value(self, component: Component | str) -> float:
        """The measured value of ``component`` (m or rad)."""
        return float(self.values[self.components.index(Component(component))])

    def sigma(self, component: Component | str) -> float:
        """The standard deviation of ``component`` (m or rad)."""
        i = self.components.index(Component(component))
        return float(math.sqrt(self.covariance[i, i]))

    @property
    def has_cross_covariance(self) -> bool:
        """True when a full estimate couples position and heading (non-zero x–θ or y–θ terms)."""
        return self.kind == "full" and bool(np.any(self.covariance[:2, 2] != 0.0))

    def marginal(self, components: Sequence[Component | str]) -> Estimate:
        """The estimate restricted to ``components`` (values and covariance block)."""
        comps = _components(components)
        missing = [c.value for c in comps if c not in self.components]
        if missing:
            raise InputError(f"Estimate({self.step}) does not measure {missing}")
        idx = [self.components.index(c) for c in comps]
        return Estimate(
            self.step,
            comps,
            self.values[idx],
            self.covariance[np.ix_(idx, idx)],
            self.reliable,
            self.reason,
            self.diagnostics,
            self.checks,
            self.seed,
        )

    def with_verdict(self, reliable: bool, reason: str, checks: Sequence[Check] | None = None) -> Estimate:
        """A copy with another reliability verdict (and, when given, other checks)."""
        kept = self.checks if checks is None else tuple(checks)
        return Estimate(
            self.step, self.components, self.values, self.covariance, reliable, reason, self.diagnostics, kept, self.seed
        )

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (the format ``factorloc fuse`` reads)."""
        return {
            "step": self.step,
            "components": [c.value for c in self.components],
            "values": self.values.tolist(),
            "covariance": self.covariance.tolist(),
            "reliable": self.reliable,
            "reason": self.reason,
            "diagnostics": {k: _jsonable(v) for k, v in self.diagnostics.items()},
            "checks": [c.to_dict() for c in self.checks],
            "seed": None if self.seed is None else self.seed.to_dict(),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Estimate:
        """Inverse of :meth:`to_dict`; ``sigmas`` may replace ``covariance``."""
        if not isinstance(data, Mapping):
            raise InputError(f"an estimate must be a JSON object, got {type(data).__name__}")
        for key in ("step", "components", "values"):
            if key not in data:
                raise InputError(f"estimate is missing the field '{key}': {dict(data)!r}")
        if "covariance" in data:
            cov = data["covariance"]
        elif "sigmas" in data:
            sig = float_array(f"Estimate({data['step']}).sigmas", data["sigmas"], (len(data["values"]),))
            if np.any(sig <= 0):
                raise InputError(f"Estimate({data['step']}).sigmas must be > 0, got {sig.tolist()}")
            cov = np.diag(sig**2)
        else:
            raise InputError(f"estimate '{data['step']}' needs 'covariance' or 'sigmas'")
        return cls(
            step=data["step"],
            components=tuple(data["components"]),
            values=data["values"],
            covariance=cov,
            reliable=data.get("reliable", True),
            reason=data.get("reason", ""),
            diagnostics=data.get("diagnostics", {}),
            checks=tuple(Check.from_dict(c) for c in data.get("checks") or ()),
            seed=None if data.get("seed") is None else SeedEvidence.from_dict(data["seed"]),
        )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Estimate):
            return NotImplemented
        return (
            self.step == other.step
            and self.components == other.components
            and np.array_equal(self.values, other.values)
            and np.array_equal(self.covariance, other.covariance)
            and self.reliable == other.reliable
            and self.reason == other.reason
            and dict(self.diagnostics) == dict(other.diagnostics)
            and self.checks == other.checks
            and self.seed == other.seed
        )

    __hash__ = None  # type: ignore[assignment]


def _jsonable(v: Any) -> Any:
    if isinstance(v, np.generic):
        return v.item()
    if isinstance(v, np.ndarray):
        return v.tolist()
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, Mapping):
        return {str(k): _jsonable(x) for k, x in v.items()}
    return v


# --------------------------------------------------------------------------
# Sensor inputs
# --------------------------------------------------------------------------
class _ImageSize:
    """``width_px`` and ``height_px`` of an ``image_bgr`` (H×W×3)."""

    image_bgr: np.ndarray

    @property
    def width_px(self) -> int:
        return int(self.image_bgr.shape[1])

    @property
    def height_px(self) -> int:
        return int(self.image_bgr.shape[0])


@dataclass(frozen=True, eq=False)
class Panorama(_ImageSize):
    """A 360° cylindrical panorama (BGR uint8, H×W×3).

    Columns map linearly to azimuth in the frame of the robot that took it
    (x forward, y left, azimuth counter-clockwise, REP-103). Like an
    equirectangular photo viewed from inside, azimuth *decreases* to the right:

    ``azimuth(u) = azimuth_col0_rad - 2π·u / W``  (u = column index, pixel centre)

    With the default ``azimuth_col0_rad = π`` the centre column ``u = W/2``
    looks forward (azimuth 0). Rows are cylindrical: row ``v`` looks at
    elevation ``atan((H/2 - v) / f)`` with ``f = (H/2) / tan(fov_v_rad/2)``,
    the horizon at row H/2.

    ``seen_columns`` (bool, shape (W,)) marks the columns that hold imagery;
    None means all of them. A panorama stitched from a turning pinhole camera
    leaves columns it never saw: the camera steps ignore them (no keypoint,
    no correlation there) instead of matching blank pixels.
    """

    image_bgr: np.ndarray
    fov_v_rad: float = math.radians(60.0)
    azimuth_col0_rad: float = math.pi
    seen_columns: np.ndarray | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "image_bgr", bgr_image("Panorama.image_bgr", self.image_bgr))
        if self.seen_columns is not None:
            seen = np.asarray(self.seen_columns)
            if seen.dtype != np.bool_ or seen.shape != (self.image_bgr.shape[1],):
                raise InputError(
                    f"Panorama.seen_columns must be a bool array of shape ({self.image_bgr.shape[1]},) (one per column), "
                    f"got dtype {seen.dtype} shape {seen.shape}"
                )
            if not seen.any():
                raise InputError("Panorama.seen_columns marks no column as seen: the panorama holds no imagery")
            seen = seen.copy()
            seen.setflags(write=False)
            object.__setattr__(self, "seen_columns", seen)
        fov = positive_float("Panorama.fov_v_rad", self.fov_v_rad)
        if fov >= math.pi:
            raise InputError(f"Panorama.fov_v_rad must be < π (cylindrical), got {fov!r}")
        object.__setattr__(self, "fov_v_rad", fov)
        object.__setattr__(self, "azimuth_col0_rad", finite_float("Panorama.azimuth_col0_rad", self.azimuth_col0_rad))

    @classmethod
    def from_images(cls, images: Sequence[CameraImage], yaws_rad: Sequence[float], **kwargs: Any) -> Panorama:
        """Stitch pinhole views taken at known yaws: :func:`factorloc.vision.panoramas.panorama_from_images`."""
        from factorloc.vision.panoramas import panorama_from_images

        return panorama_from_images(images, yaws_rad, **kwargs)

    @property
    def rad_per_px(self) -> float:
        """Angular width of one column."""
        return 2.0 * math.pi / self.width_px

    def azimuth_of_column(self, u: float | np.ndarray) -> float | np.ndarray:
        """Azimuth (rad, wrapped) of column ``u`` (may be fractional)."""
        return wrap_angle(self.azimuth_col0_rad - np.asarray(u, dtype=np.float64) * self.rad_per_px)

    def column_of_azimuth(self, azimuth_rad: float | np.ndarray) -> float | np.ndarray:
        """Column in [0, W) that looks at ``azimuth_rad``."""
        u = np.mod((self.azimuth_col0_rad - np.asarray(azimuth_rad, dtype=np.float64)) / self.rad_per_px, self.width_px)
        return float(u) if np.ndim(u) == 0 else u


@dataclass(frozen=True, eq=False)
class CameraImage(_ImageSize):
    """A pinhole camera image (BGR uint8, H×W×3) taken by the robot.

    ``hfov_rad`` is the horizontal field of view; pixels are square and the
    principal point is the image centre unless ``cx_px`` is given. The camera
    looks along ``yaw_in_robot_rad`` in the robot frame (0 = forward, CCW
    positive); ``pitch_rad`` tilts it up (positive) or down.
    """

    image_bgr: np.ndarray
    hfov_rad: float = math.radians(57.0)
    yaw_in_robot_rad: float = 0.0
    pitch_rad: float = 0.0
    cx_px: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "image_bgr", bgr_image("CameraImage.image_bgr", self.image_bgr))
        fov = positive_float("CameraImage.hfov_rad", self.hfov_rad)
        if fov >= math.pi:
            raise InputError(f"CameraImage.hfov_rad must be < π for a pinhole camera, got {fov!r}")
        object.__setattr__(self, "hfov_rad", fov)
        object.__setattr__(
            self, "yaw_in_robot_rad", wrap_angle(finite_float("CameraImage.yaw_in_robot_rad", self.yaw_in_robot_rad))
        )
        object.__setattr__(self, "pitch_rad", finite_float("CameraImage.pitch_rad", self.pitch_rad))
        if self.cx_px is not None:
            object.__setattr__(self, "cx_px", finite_float("CameraImage.cx_px", self.cx_px))

    @property
    def focal_px(self) -> float:
        """Focal length in pixels: ``(W/2) / tan(hfov/2)``."""
        return 0.5 * self.width_px / math.tan(0.5 * self.hfov_rad)

    @property
    def principal_x_px(self) -> float:
        return (self.width_px - 1) / 2.0 if self.cx_px is None else self.cx_px

    @property
    def vfov_rad(self) -> float:
        """Vertical field of view implied by square pixels."""
        return 2.0 * math.atan(0.5 * self.height_px / self.focal_px)

    def azimuth_of_column(self, u: float | np.ndarray) -> float | np.ndarray:
        """Azimuth in the robot frame (rad) of image column ``u``: yaw + atan((cx - u)/f)."""
        return wrap_angle(
            self.yaw_in_robot_rad + np.arctan((self.principal_x_px - np.asarray(u, dtype=np.float64)) / self.focal_px)
        )


@dataclass(frozen=True, eq=False)
class PointCloud:
    """A 3D point cloud, N×3 metres, robot frame (x forward, y left, z up from the floor)."""

    points_m: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "points_m", float_array("PointCloud.points_m", self.points_m, (None, 3)))

    def __len__(self) -> int:
        return int(self.points_m.shape[0])


@dataclass(frozen=True, eq=False)
class Scan:
    """A 2D scan, N×2 metres, robot frame (x forward, y left): a horizontal cut or a laser scan."""

    points_m: np.ndarray

    def __post_init__(self) -> None:
        object.__setattr__(self, "points_m", float_array("Scan.points_m", self.points_m, (None, 2)))

    def __len__(self) -> int:
        return int(self.points_m.shape[0])


@dataclass(frozen=True)
class Odometry:
    """The odometry's pose of the robot in the world frame, with per-axis sigmas.

    Build it from the distance travelled with :meth:`from_distance` (the
    patent's example: 5 % drift, 1 m walked → σx = σy = 5 cm).
    """

    T_world_robot: Pose2
    sigma_x_m: float
    sigma_y_m: float
    sigma_theta_rad: float

    def __post_init__(self) -> None:
        if not isinstance(self.T_world_robot, Pose2):
            raise InputError(f"Odometry.T_world_robot must be a Pose2, got {type(self.T_world_robot).__name__}")
        object.__setattr__(self, "sigma_x_m", positive_float("Odometry.sigma_x_m", self.sigma_x_m))
        object.__setattr__(self, "sigma_y_m", positive_float("Odometry.sigma_y_m", self.sigma_y_m))
        object.__setattr__(self, "sigma_theta_rad", positive_float("Odometry.sigma_theta_rad", self.sigma_theta_rad))

    @classmethod
    def from_distance(
        cls,
        T_world_robot: Pose2,
        distance_m: float,
        rotation_rad: float = 0.0,
        *,
        drift_ratio: float = 0.05,
        heading_drift_ratio: float = 0.05,
        heading_drift_rad_per_m: float = 0.02,
        min_sigma_m: float = 1e-3,
        min_sigma_rad: float = 1e-3,
    ) -> Odometry:
        """Sigmas that grow with the motion since the last reset.

        σx = σy = max(min_sigma_m, drift_ratio · distance_m);
        σθ = max(min_sigma_rad, heading_drift_ratio · |rotation_rad| + heading_drift_rad_per_m · distance_m).
        """
        d = nonnegative_float("Odometry.distance_m", distance_m)
        r = abs(finite_float("Odometry.rotation_rad", rotation_rad))
        k = nonnegative_float("Odometry.drift_ratio", drift_ratio)
        kh = nonnegative_float("Odometry.heading_drift_ratio", heading_drift_ratio)
        kd = nonnegative_float("Odometry.heading_drift_rad_per_m", heading_drift_rad_per_m)
        s_xy = max(positive_float("Odometry.min_sigma_m", min_sigma_m), k * d)
        s_th = max(positive_float("Odometry.min_sigma_rad", min_sigma_rad), kh * r + kd * d)
        return cls(T_world_robot, s_xy, s_xy, s_th)


@dataclass(frozen=True, eq=False)
class Reference:
    """What the robot knows of one place: a panorama and/or a scan or 360° cloud, and where it was taken.

    ``T_world_reference`` is the pose of the robot that captured the reference
    (default: the world origin). The cloud/scan are in that robot's frame.
    """

    panorama: Panorama | None = None
    cloud: PointCloud | None = None
    scan: Scan | None = None
    T_world_reference: Pose2 = field(default_factory=Pose2)
    name: str = "reference"

    def __post_init__(self) -> None:
        _check_type("Reference.panorama", self.panorama, Panorama)
        _check_type("Reference.cloud", self.cloud, PointCloud)
        _check_type("Reference.scan", self.scan, Scan)
        if not isinstance(self.T_world_reference, Pose2):
            raise InputError(f"Reference.T_world_reference must be a Pose2, got {type(self.T_world_reference).__name__}")
        if self.panorama is None and self.cloud is None and self.scan is None:
            raise InputError("Reference needs at least one of panorama, cloud or scan")


@dataclass(frozen=True, eq=False)
class Query:
    """What the robot senses now; every modality is optional.

    ``images`` are pinhole views (several at different head yaws form a
    partial panorama); ``panorama`` a full 360° query; ``cloud``/``scan`` in the
    robot frame; ``odometry`` the dead-reckoned pose in the world frame.
    """

    images: tuple[CameraImage, ...] = ()
    panorama: Panorama | None = None
    cloud: PointCloud | None = None
    scan: Scan | None = None
    odometry: Odometry | None = None
    id: str = ""

    def __post_init__(self) -> None:
        images = self.images
        if isinstance(images, CameraImage):
            images = (images,)
        if not isinstance(images, Sequence) or isinstance(images, (str, bytes)):
            raise InputError(f"Query.images must be a sequence of CameraImage, got {type(images).__name__}")
        images = tuple(images)
        for i, im in enumerate(images):
            _check_type(f"Query.images[{i}]", im, CameraImage)
        object.__setattr__(self, "images", images)
        _check_type("Query.panorama", self.panorama, Panorama)
        _check_type("Query.cloud", self.cloud, PointCloud)
        _check_type("Query.scan", self.scan, Scan)
        _check_type("Query.odometry", self.odometry, Odometry)


def _check_type(name: str, value: Any, cls: type) -> None:
    if value is not None and not isinstance(value, cls):
        raise InputError(f"{name} must be a {cls.__name__} or None, got {type(value).__name__}")


# --------------------------------------------------------------------------
# Results
# --------------------------------------------------------------------------
class StepStatus(StrEnum):
    """What became of one step's estimate."""

    FUSED = "fused"
    UNRELIABLE = "unreliable"  # failed the estimator's own test or a reliability gate
    INCONSISTENT = "inconsistent"  # reliable, but rejected by the consistency gate
    SKIPPED = "skipped"  # its inputs were absent
    FAILED = "failed"  # it raised on this input (the error is the reason)


@dataclass(frozen=True)
class StepReport:
    """One step of one localization: its estimate, its fate, and its run time (s)."""

    name: str
    status: StepStatus
    estimate: Estimate | None = None
    reason: str = ""
    seconds: float = 0.0

    @property
    def fused(self) -> bool:
        return self.status is StepStatus.FUSED

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "status": self.status.value,
            "fused": self.fused,
            "reason": self.reason,
            "seconds": self.seconds,
            "estimate": None if self.estimate is None else self.estimate.to_dict(),
        }


@dataclass(frozen=True, eq=False)
class Localization:
    """The result of :func:`factorloc.localize` or :func:`factorloc.fuse`.

    ``covariance`` is 3×3 in the world frame, order (x, y, θ), m² and rad².
    A component that no fused estimate constrains is *under-determined*: it
    is listed in ``undetermined``, its variance is ``inf`` and its value in
    ``pose`` is a placeholder (the seed, or 0) that must not be used.
    """

    pose: Pose2
    covariance: np.ndarray
    steps: tuple[StepReport, ...]
    fused_with: str
    undetermined: tuple[Component, ...] = ()
    config: Config | None = None

    @property
    def sigmas(self) -> np.ndarray:
        """σx (m), σy (m), σθ (rad); ``inf`` where under-determined."""
        return np.sqrt(np.diag(self.covariance))

    @property
    def determined(self) -> bool:
        """True when every component is constrained by at least one fused estimate."""
        return not self.undetermined

    def step(self, name: str) -> StepReport:
        """The report of the step called ``name``."""
        for report in self.steps:
            if report.name == name:
                return report
        raise KeyError(f"no step named {name!r}; steps are {[r.name for r in self.steps]}")

    def certainty(self, radius_m: float, angle_rad: float) -> float:
        """The patent's degree of certainty: the probability mass of the fused
        Gaussian within ``radius_m`` of the position and ``angle_rad`` of the heading.

        Computed from the cumulative distribution: the position part integrates
        the 2D Gaussian over a disc of radius ``radius_m`` (Gauss–Legendre
        quadrature, exact to ~1e-10), the heading part is ``erf(a / (σθ√2))``;
        the two are multiplied (position and heading are independent in the
        per-axis product). Under-determined components give 0.
        """
        r = nonnegative_float("certainty.radius_m", radius_m)
        a = nonnegative_float("certainty.angle_rad", angle_rad)
        return _disc_probability(self.covariance[:2, :2], r) * _interval_probability(self.covariance[2, 2], a)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: pose, covariance (``null`` where infinite), sigmas, steps."""
        cov = [[None if not math.isfinite(v) else v for v in row] for row in self.covariance.tolist()]
        return {
            "pose": {
                "x_m": self.pose.x,
                "y_m": self.pose.y,
                "theta_rad": self.pose.theta,
                "theta_deg": math.degrees(self.pose.theta),
            },
            "covariance": cov,
            "sigmas": {
                "x_m": _finite_or_none(self.sigmas[0]),
                "y_m": _finite_or_none(self.sigmas[1]),
                "theta_rad": _finite_or_none(self.sigmas[2]),
            },
            "undetermined": [c.value for c in self.undetermined],
            "fused_with": self.fused_with,
            "steps": [s.to_dict() for s in self.steps],
        }


def _finite_or_none(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(96)


def _interval_probability(variance: float, half_width: float) -> float:
    if not math.isfinite(variance):
        return 0.0
    if variance <= 0.0:
        return 1.0
    return math.erf(half_width / math.sqrt(2.0 * variance))


def _disc_probability(cov2: np.ndarray, radius: float) -> float:
    """P(|e| ≤ radius) for e ~ N(0, cov2) in 2D, by Gauss–Legendre quadrature.

    Along the principal axes (σ1 ≤ σ2): P = ∫ φ(u; σ2) · erf(√(r²−u²) / (σ1√2)) du over
    |u| ≤ r. With u = r·sin φ the integrand is smooth; when r > 12σ2 the range is cut
    to |u| ≤ 12σ2 (the rest weighs < 1e-31), where √(r²−u²) is smooth already.
    """
    if not np.all(np.isfinite(cov2)):
        return 0.0
    if radius == 0.0:
        return 0.0
    l1, l2 = np.linalg.eigvalsh(cov2)  # l1 <= l2
    s1, s2 = math.sqrt(max(l1, 0.0)), math.sqrt(max(l2, 0.0))
    if s2 == 0.0:
        return 1.0
    if radius <= 12.0 * s2:
        phi = 0.5 * math.pi * _GL_NODES
        u = radius * np.sin(phi)
        jac = radius * np.cos(phi) * 0.5 * math.pi
    else:
        u = 12.0 * s2 * _GL_NODES
        jac = np.full_like(u, 12.0 * s2)
    half = np.sqrt(np.maximum(radius * radius - u * u, 0.0))
    inner = np.ones_like(u) if s1 == 0.0 else np.array([math.erf(h / (s1 * math.sqrt(2.0))) for h in half])
    density = np.exp(-0.5 * (u / s2) ** 2) / (s2 * math.sqrt(2.0 * math.pi))
    return float(np.clip(np.sum(_GL_WEIGHTS * jac * density * inner), 0.0, 1.0))

"""SE(2) helpers: angle wrapping, the :class:`Pose2` value type, rotations.

Conventions (REP-103): x forward, y left, z up; headings counter-clockwise in
radians. A pose named ``T_a_b`` maps coordinates in frame ``b`` to frame ``a``
(``p_a = T_a_b * p_b``); ``T_world_robot`` is the robot's pose in the world.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from factorloc._validate import finite_float

_TWO_PI = 2.0 * math.pi


def wrap_angle(angle_rad: float | np.ndarray) -> float | np.ndarray:
    """Wrap an angle (or array of angles) to [-π, π).

    The one helper every module uses, so that wrapping is done the same way
    everywhere.
    """
    if isinstance(angle_rad, float):
        # the common scalar case in plain floats: Python's float ``%`` is numpy's (C ``fmod``, then the divisor's
        # sign), so the same bits without a numpy scalar (``tests/test_geometry.py`` compares them)
        out = (angle_rad + math.pi) % _TWO_PI - math.pi
        return -math.pi if out >= math.pi else out  # just below -π, the mod rounds up to 2π: map π to -π
    wrapped = np.asarray(angle_rad, dtype=np.float64) + math.pi  # a new array: the input is never written
    if wrapped.ndim == 0:
        out = float(np.mod(wrapped, 2.0 * math.pi) - math.pi)
        return -math.pi if out >= math.pi else out
    np.mod(wrapped, 2.0 * math.pi, out=wrapped)  # in place: the same arithmetic as mod(x + π, 2π) − π, fewer copies
    wrapped -= math.pi
    wrapped[wrapped >= math.pi] = -math.pi
    return wrapped


def rot2(theta_rad: float) -> np.ndarray:
    """The 2×2 rotation matrix of ``theta_rad``."""
    c, s = math.cos(theta_rad), math.sin(theta_rad)
    return np.array([[c, -s], [s, c]])


def rotate_covariance(covariance: np.ndarray, theta_rad: float) -> np.ndarray:
    """Rotate a 3×3 (x, y, θ) covariance by ``theta_rad``: ``R Σ Rᵀ`` with R = diag(rot2(θ), 1), symmetrized.

    Used to turn a body-frame pose covariance (GTSAM's ``Marginals``) into
    the world frame (``theta_rad`` = the pose's heading) and back (``-theta``).

    In plain floats, the products by R's zeros and ones left out: the same operations on every CPU (a numpy
    matrix product goes through BLAS, whose kernel, and so its rounding, follows the instruction set) and a
    fraction of the numpy calls' cost.
    """
    c, s = math.cos(theta_rad), math.sin(theta_rad)
    (s00, s01, s02), (s10, s11, s12), (s20, s21, s22) = np.asarray(covariance, dtype=np.float64).tolist()
    # M = R Σ: the first two rows turned, the third kept
    m00, m01, m02 = c * s00 - s * s10, c * s01 - s * s11, c * s02 - s * s12
    m10, m11, m12 = s * s00 + c * s10, s * s01 + c * s11, s * s02 + c * s12
    # O = M Rᵀ: the first two columns turned, the third kept
    o00, o01 = m00 * c - m01 * s, m00 * s + m01 * c
    o10, o11 = m10 * c - m11 * s, m10 * s + m11 * c
    o20, o21 = s20 * c - s21 * s, s20 * s + s21 * c
    a01, a02, a12 = 0.5 * (o01 + o10), 0.5 * (m02 + o20), 0.5 * (m12 + o21)
    return np.array([[o00, a01, a02], [a01, o11, a12], [a02, a12, s22]])


@dataclass(frozen=True)
class Pose2:
    """A planar pose: position ``x``, ``y`` in metres and heading ``theta`` in radians.

    ``theta`` is wrapped to [-π, π) at construction. Read ``Pose2(x, y, theta)``
    as ``T_parent_child``; composition follows SE(2).
    """

    x: float = 0.0
    y: float = 0.0
    theta: float = 0.0

    def __post_init__(self) -> None:
        x, y, theta = self.x, self.y, self.theta
        if type(x) is float and type(y) is float and type(theta) is float and math.isfinite(x + y + theta):
            # the common case (finite floats, as every pose the library computes): only θ changes (wrapped)
            object.__setattr__(self, "theta", wrap_angle(theta))
            return
        object.__setattr__(self, "x", finite_float("Pose2.x", self.x))
        object.__setattr__(self, "y", finite_float("Pose2.y", self.y))
        object.__setattr__(self, "theta", wrap_angle(finite_float("Pose2.theta", self.theta)))

    # --- group operations -------------------------------------------------
    def compose(self, other: Pose2) -> Pose2:
        """``self * other``: ``T_a_c = T_a_b.compose(T_b_c)``."""
        c, s = math.cos(self.theta), math.sin(self.theta)
        return Pose2(
            self.x + c * other.x - s * other.y,
            self.y + s * other.x + c * other.y,
            self.theta + other.theta,
        )

    def __mul__(self, other: Pose2) -> Pose2:
        return self.compose(other)

    def inverse(self) -> Pose2:
        """``T_b_a`` from ``T_a_b``."""
        c, s = math.cos(self.theta), math.sin(self.theta)
        return Pose2(-c * self.x - s * self.y, s * self.x - c * self.y, -self.theta)

    def between(self, other: Pose2) -> Pose2:
        """``self⁻¹ * other``: the pose of ``other`` seen from ``self``."""
        return self.inverse().compose(other)

    def transform_points(self, points: np.ndarray) -> np.ndarray:
        """Map N×2 points from the child frame to the parent frame."""
        pts = np.asarray(points, dtype=np.float64)
        return pts @ rot2(self.theta).T + np.array([self.x, self.y])

    # --- conversions ------------------------------------------------------
    @property
    def translation(self) -> np.ndarray:
        """``[x, y]`` in metres."""
        return np.array([self.x, self.y])

    def as_array(self) -> np.ndarray:
        """``[x, y, theta]``."""
        return np.array([self.x, self.y, self.theta])

    @classmethod
    def from_array(cls, values: np.ndarray | list[float] | tuple[float, ...]) -> Pose2:
        """Build from ``[x, y, theta]``."""
        from factorloc.errors import InputError

        try:
            arr = np.asarray(values)
        except (TypeError, ValueError) as exc:
            raise InputError(f"Pose2.from_array needs 3 numbers [x, y, theta]: {exc}") from exc
        if arr.dtype.kind not in "iuf":  # like Pose2("1.0"): strings, objects and booleans are not numbers
            raise InputError(f"Pose2.from_array needs 3 numbers [x, y, theta], got dtype {arr.dtype} {values!r}")
        v = list(arr.astype(np.float64).ravel())
        if len(v) != 3:
            raise InputError(f"Pose2.from_array needs 3 values [x, y, theta], got {len(v)}")
        return cls(v[0], v[1], v[2])

    def to_gtsam(self):  # noqa: ANN201 - gtsam has no stubs
        """Return the equivalent ``gtsam.Pose2``."""
        import gtsam

        return gtsam.Pose2(self.x, self.y, self.theta)

    @classmethod
    def from_gtsam(cls, pose) -> Pose2:  # noqa: ANN001
        """Build from a ``gtsam.Pose2``."""
        return cls(float(pose.x()), float(pose.y()), float(pose.theta()))

    def __repr__(self) -> str:
        return f"Pose2(x={self.x:.4f} m, y={self.y:.4f} m, theta={math.degrees(self.theta):.3f}°)"

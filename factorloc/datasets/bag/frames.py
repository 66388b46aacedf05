"""Rigid 3D transforms and the TF tree of a bag (``/tf_static`` and ``/tf``).

A :class:`Rigid3` ``T_a_b`` maps coordinates of frame *b* into frame *a*
(``p_a = R·p_b + t``), as ROS's ``geometry_msgs/TransformStamped`` with
``header.frame_id = a`` and ``child_frame_id = b``. :class:`TransformTree`
holds the transforms of a bag: static ones (``/tf_static``, or edges of ``/tf``
that never move) and time-varying ones (a pan head, a turning mast), interpolated
at a query time (linear translation, spherical-linear rotation). It answers
:meth:`TransformTree.lookup` ``T_target_source`` along the chain of frames between the two.
The odometry edge (``odom → base_link``) is dynamic too; sensor extrinsics never pass
through it because the sensors hang below the robot frame.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field

import numpy as np

from factorloc.errors import DatasetError, InputError
from factorloc.geometry import Pose2

__all__ = ["Rigid3", "TransformTree", "quaternion_to_matrix", "matrix_to_quaternion"]

#: An edge of ``/tf`` whose translation varies less than this (m) and rotation less than
#: :data:`STATIC_ROTATION_RAD` over the bag is treated as static (its median is used).
STATIC_TRANSLATION_M = 1e-3
STATIC_ROTATION_RAD = math.radians(0.05)


def quaternion_to_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    """The 3×3 rotation matrix of a quaternion (normalized first; raises on a zero quaternion)."""
    n = math.sqrt(x * x + y * y + z * z + w * w)
    if not (math.isfinite(n) and n > 1e-9):
        raise InputError(f"quaternion ({x}, {y}, {z}, {w}) has no direction (norm {n})")
    x, y, z, w = x / n, y / n, z / n, w / n
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """``[x, y, z, w]`` of a rotation matrix (Shepperd's method), ``w ≥ 0``."""
    m = np.asarray(R, dtype=np.float64)
    tr = m[0, 0] + m[1, 1] + m[2, 2]
    if tr > 0:
        s = 2.0 * math.sqrt(1.0 + tr)
        q = [(m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s, 0.25 * s]
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = [0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s, (m[2, 1] - m[1, 2]) / s]
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * math.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = [(m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s, (m[0, 2] - m[2, 0]) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = [(m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s, (m[1, 0] - m[0, 1]) / s]
    out = np.array(q)
    return -out if out[3] < 0 else out


def _slerp(q0: np.ndarray, q1: np.ndarray, a: float) -> np.ndarray:
    d = float(np.dot(q0, q1))
    if d < 0.0:
        q1, d = -q1, -d
    if d > 0.9995:
        q = q0 + a * (q1 - q0)
        return q / np.linalg.norm(q)
    th = math.acos(min(1.0, d))
    return (math.sin((1 - a) * th) * q0 + math.sin(a * th) * q1) / math.sin(th)


@dataclass(frozen=True, eq=False)
class Rigid3:
    """A rigid 3D transform ``T_a_b``: rotation ``R`` (3×3) and translation ``t`` (3,, metres)."""

    R: np.ndarray = field(default_factory=lambda: np.eye(3))
    t: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        R = np.array(self.R, dtype=np.float64)
        t = np.array(self.t, dtype=np.float64).reshape(-1)
        if R.shape != (3, 3) or t.shape != (3,) or not (np.all(np.isfinite(R)) and np.all(np.isfinite(t))):
            raise InputError(f"Rigid3 needs a finite 3×3 R and 3-vector t, got shapes {R.shape}, {t.shape}")
        if np.abs(R @ R.T - np.eye(3)).max() > 1e-6 or np.linalg.det(R) < 0:
            raise InputError(f"Rigid3.R is not a rotation matrix: {R.tolist()}")
        R.setflags(write=False)
        t.setflags(write=False)
        object.__setattr__(self, "R", R)
        object.__setattr__(self, "t", t)

    @classmethod
    def from_quaternion(cls, translation: Iterable[float], quaternion_xyzw: Iterable[float]) -> Rigid3:
        return cls(quaternion_to_matrix(*quaternion_xyzw), np.asarray(list(translation), dtype=np.float64))

    @classmethod
    def from_xyz_rpy(cls, x: float, y: float, z: float, roll: float, pitch: float, yaw: float) -> Rigid3:
        """From a translation (m) and roll, pitch, yaw (rad; ``R = Rz(yaw)·Ry(pitch)·Rx(roll)``, as ROS's URDF)."""
        cr, sr, cp, sp, cy, sy = math.cos(roll), math.sin(roll), math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
        R = np.array(
            [
                [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
                [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
                [-sp, cp * sr, cp * cr],
            ]
        )
        return cls(R, np.array([x, y, z], dtype=np.float64))

    @classmethod
    def from_pose2(cls, pose: Pose2, z_m: float = 0.0) -> Rigid3:
        """A planar pose as a 3D transform (rotation about z)."""
        return cls.from_xyz_rpy(pose.x, pose.y, z_m, 0.0, 0.0, pose.theta)

    def __mul__(self, other: Rigid3) -> Rigid3:
        return Rigid3(self.R @ other.R, self.R @ other.t + self.t)

    def inverse(self) -> Rigid3:
        return Rigid3(self.R.T, -(self.R.T @ self.t))

    def apply(self, points: np.ndarray) -> np.ndarray:
        """Map N×3 points of frame *b* into frame *a*."""
        p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        return p @ self.R.T + self.t

    @property
    def quaternion(self) -> np.ndarray:
        """``[x, y, z, w]``."""
        return matrix_to_quaternion(self.R)

    @property
    def rpy(self) -> tuple[float, float, float]:
        """Roll, pitch, yaw (rad) of ``R = Rz·Ry·Rx``."""
        R = self.R
        pitch = math.asin(max(-1.0, min(1.0, -R[2, 0])))
        return math.atan2(R[2, 1], R[2, 2]), pitch, math.atan2(R[1, 0], R[0, 0])

    def to_pose2(self) -> Pose2:
        """The planar part: (x, y) and the yaw of the x axis projected on the plane."""
        return Pose2(float(self.t[0]), float(self.t[1]), math.atan2(self.R[1, 0], self.R[0, 0]))

    def interpolate(self, other: Rigid3, a: float) -> Rigid3:
        """``(1 − a)·self + a·other``: linear translation, spherical-linear rotation."""
        q = _slerp(self.quaternion, other.quaternion, a)
        return Rigid3(quaternion_to_matrix(*q), (1 - a) * self.t + a * other.t)


@dataclass(frozen=True, eq=False)
class _Series:
    stamps_s: np.ndarray
    transforms: tuple[Rigid3, ...]

    def at(self, t_s: float, tolerance_s: float) -> Rigid3:
        ts = self.stamps_s
        i = int(np.searchsorted(ts, t_s))
        if i <= 0 or i >= len(ts):
            j = 0 if i <= 0 else len(ts) - 1
            if abs(ts[j] - t_s) > tolerance_s:
                raise DatasetError(
                    f"no transform within {tolerance_s} s of t = {t_s!r} s (series spans [{ts[0]!r}, {ts[-1]!r}] s)"
                )
            return self.transforms[j]
        t0, t1 = ts[i - 1], ts[i]
        a = 0.0 if t1 == t0 else (t_s - t0) / (t1 - t0)
        return self.transforms[i - 1].interpolate(self.transforms[i], float(a))


def _is_static(transforms: list[Rigid3]) -> bool:
    t = np.array([T.t for T in transforms])
    if np.ptp(t, axis=0).max() > STATIC_TRANSLATION_M:
        return False
    R0 = transforms[0].R
    for T in transforms[1:]:
        c = (np.trace(R0.T @ T.R) - 1.0) / 2.0
        if math.acos(max(-1.0, min(1.0, c))) > STATIC_ROTATION_RAD:
            return False
    return True


class TransformTree:
    """The frames of a bag: static and time-varying edges ``parent → child`` (``T_parent_child``).

    Build it with :meth:`add` (one ``TransformStamped``-like edge at a time, as read from
    ``/tf`` and ``/tf_static``), then call :meth:`freeze`; or give ``static`` edges directly.
    ``overrides`` (``{frame: T_robot_frame}``) are extrinsics given by the user; they win over the bag.
    """

    def __init__(self, static: Mapping[tuple[str, str], Rigid3] | None = None) -> None:
        self._static: dict[tuple[str, str], Rigid3] = dict(static or {})
        self._samples: dict[tuple[str, str], list[tuple[float, Rigid3]]] = {}
        self._dynamic: dict[tuple[str, str], _Series] = {}
        self._frozen = static is not None

    @staticmethod
    def _frame(name: str) -> str:
        return str(name).lstrip("/")

    def add(self, parent: str, child: str, transform: Rigid3, stamp_s: float | None = None) -> None:
        """Record one edge; ``stamp_s`` None means static (``/tf_static``)."""
        key = (self._frame(parent), self._frame(child))
        if stamp_s is None:
            self._static[key] = transform
        else:
            self._samples.setdefault(key, []).append((float(stamp_s), transform))

    def freeze(self) -> TransformTree:
        """Sort the time-varying edges; an edge of ``/tf`` that never moves becomes static."""
        for key, samples in self._samples.items():
            if key in self._static:
                continue
            samples.sort(key=lambda s: s[0])
            transforms = [T for _, T in samples]
            if _is_static(transforms):
                self._static[key] = transforms[len(transforms) // 2]
            else:
                self._dynamic[key] = _Series(np.array([s for s, _ in samples]), tuple(transforms))
        self._samples = {}
        self._frozen = True
        return self

    @property
    def frames(self) -> list[str]:
        names = {f for key in (*self._static, *self._dynamic) for f in key}
        return sorted(names)

    def is_static(self, parent: str, child: str) -> bool:
        return (self._frame(parent), self._frame(child)) in self._static

    def _path(self, target: str, source: str) -> list[tuple[str, str, bool]]:
        """Edges from ``target`` to ``source``: (parent, child, forward) with forward = walking parent → child."""
        adj: dict[str, list[tuple[str, str, str, bool]]] = {}
        for p, c in (*self._static, *self._dynamic):
            adj.setdefault(p, []).append((c, p, c, True))
            adj.setdefault(c, []).append((p, p, c, False))
        prev: dict[str, tuple[str, tuple[str, str, bool]] | None] = {target: None}
        todo = deque([target])
        while todo:
            f = todo.popleft()
            if f == source:
                break
            for nxt, p, c, fwd in adj.get(f, []):
                if nxt not in prev:
                    prev[nxt] = (f, (p, c, fwd))
                    todo.append(nxt)
        if source not in prev:
            raise DatasetError(
                f"no chain of transforms from frame {target!r} to frame {source!r} in the bag's TF "
                f"(frames: {self.frames}); give the extrinsics on the command line (--extrinsic {source}=x,y,z,roll,pitch,yaw)"
            )
        edges = []
        f = source
        while prev[f] is not None:
            before, edge = prev[f]  # type: ignore[misc]
            edges.append(edge)
            f = before
        return edges[::-1]

    def lookup(self, target: str, source: str, t_s: float | None = None, *, tolerance_s: float = 0.1) -> Rigid3:
        """``T_target_source`` at time ``t_s`` (None: only static edges may be on the way).

        Raises
        ------
        DatasetError
            When the frames are not connected, or a time-varying edge is on the way and
            ``t_s`` is None or farther than ``tolerance_s`` from its samples.
        """
        target, source = self._frame(target), self._frame(source)
        T = Rigid3()
        if target == source:
            return T
        for p, c, fwd in self._path(target, source):
            key = (p, c)
            if key in self._static:
                edge = self._static[key]
            else:
                if t_s is None:
                    raise DatasetError(f"the transform {p!r} → {c!r} moves during the bag: a time is needed to look it up")
                edge = self._dynamic[key].at(t_s, tolerance_s)
            T = T * (edge if fwd else edge.inverse())
        return T

    def depends_on_time(self, target: str, source: str) -> bool:
        """True when a time-varying edge lies between the two frames (e.g. a pan head)."""
        target, source = self._frame(target), self._frame(source)
        if target == source:
            return False
        return any((p, c) not in self._static for p, c, _ in self._path(target, source))

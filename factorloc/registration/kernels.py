"""Robust kernels (M-estimators) for iteratively reweighted least squares.

A kernel maps residuals ``r`` (metres) to IRLS weights ``w(r) = ρ'(r)/r``
(Zhang, "Parameter estimation techniques: a tutorial with application to
conic fitting", 1997, table 1). Kernels are strategy objects passed to
:func:`factorloc.registration.icp2d.align`, like Open3D's
``TransformationEstimationPointToPlane(loss)``.

Each weight function is written once, in :func:`weight_scalar` (a kernel
is a code, :data:`KERNEL_CODES`, and a scale): the compiled ICP core calls
it per residual and the classes' numpy ``weight`` apply it elementwise
(a numba ufunc of the same function), so both give bit-identical weights.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar, Protocol, runtime_checkable

import numpy as np
from numba import njit, vectorize

from factorloc.errors import InputError

__all__ = ["KERNEL_CODES", "Cauchy", "Huber", "L2", "RobustKernel", "Tukey", "kernel_from_name", "weight_scalar"]

KERNEL_CODES = {"l2": 0, "huber": 1, "cauchy": 2, "tukey": 3}
"""The integer code of each kernel in :func:`weight_scalar` (and the compiled ICP core)."""


def _weight(code: int, scale_m: float, r: float) -> float:
    if code == 2:  # Cauchy: 1 / (1 + (r/k)²)
        u = r / scale_m
        return 1.0 / (1.0 + u * u)
    if code == 1:  # Huber: 1 for |r| <= k else k/|r|
        a = abs(r)
        return 1.0 if a <= scale_m else scale_m / max(a, 1e-300)
    if code == 3:  # Tukey: (1 − (r/k)²)² for |r| < k else 0
        u = r / scale_m
        if abs(u) < 1.0:
            v = 1.0 - u * u
            return v * v
        return 0.0
    return 1.0  # L2


weight_scalar = njit(cache=True, inline="always")(_weight)
"""``w(r)`` (scalar residual, m) of the kernel ``code`` (:data:`KERNEL_CODES`) with scale ``scale_m``, compiled;
for use inside other numba functions. (Numba's cache does not track this dependency: after editing
:func:`_weight`, delete ``factorloc/registration/__pycache__/*.nb*`` — ``tests/registration`` fails otherwise.)"""

_UFUNC = []


def _weight_ufunc(code: int, scale_m: float, r: np.ndarray) -> np.ndarray:
    """:func:`_weight` applied elementwise to ``r`` (a numba ufunc, built at first use: loading it costs ~0.15 s)."""
    if not _UFUNC:
        _UFUNC.append(vectorize(["float64(int64, float64, float64)"], cache=True)(_weight))
    return _UFUNC[0](code, scale_m, r)


@runtime_checkable
class RobustKernel(Protocol):
    """IRLS weight function of residuals (metres)."""

    def weight(self, residuals_m: np.ndarray) -> np.ndarray:
        """Per-residual weights in [0, 1], same shape as ``residuals_m``."""
        ...


@dataclass(frozen=True)
class L2:
    """Plain least squares: ``w(r) = 1``."""

    code: ClassVar[int] = KERNEL_CODES["l2"]
    scale_m: ClassVar[float] = 1.0

    def weight(self, residuals_m: np.ndarray) -> np.ndarray:
        return _weight_ufunc(self.code, self.scale_m, np.asarray(residuals_m, dtype=np.float64))


def _check_scale(name: str, k: float) -> float:
    k = float(k)
    if not np.isfinite(k) or k <= 0.0:
        raise InputError(f"{name}.scale_m must be > 0, got {k!r}")
    return k


@dataclass(frozen=True)
class Huber:
    """Huber: ``w(r) = 1`` for ``|r| ≤ k`` else ``k/|r|``."""

    code: ClassVar[int] = KERNEL_CODES["huber"]

    scale_m: float = 0.05

    def __post_init__(self) -> None:
        object.__setattr__(self, "scale_m", _check_scale("Huber", self.scale_m))

    def weight(self, residuals_m: np.ndarray) -> np.ndarray:
        return _weight_ufunc(self.code, self.scale_m, np.asarray(residuals_m, dtype=np.float64))


@dataclass(frozen=True)
class Cauchy:
    """Cauchy (Lorentzian): ``w(r) = 1 / (1 + (r/k)²)``."""

    code: ClassVar[int] = KERNEL_CODES["cauchy"]

    scale_m: float = 0.05

    def __post_init__(self) -> None:
        object.__setattr__(self, "scale_m", _check_scale("Cauchy", self.scale_m))

    def weight(self, residuals_m: np.ndarray) -> np.ndarray:
        return _weight_ufunc(self.code, self.scale_m, np.asarray(residuals_m, dtype=np.float64))


@dataclass(frozen=True)
class Tukey:
    """Tukey biweight: ``w(r) = (1 - (r/k)²)²`` for ``|r| < k`` else 0."""

    code: ClassVar[int] = KERNEL_CODES["tukey"]

    scale_m: float = 0.1

    def __post_init__(self) -> None:
        object.__setattr__(self, "scale_m", _check_scale("Tukey", self.scale_m))

    def weight(self, residuals_m: np.ndarray) -> np.ndarray:
        return _weight_ufunc(self.code, self.scale_m, np.asarray(residuals_m, dtype=np.float64))


_KERNELS = {"l2": L2, "huber": Huber, "cauchy": Cauchy, "tukey": Tukey}


def kernel_from_name(name: str, scale_m: float) -> RobustKernel:
    """Build a kernel from its config name (``"l2"``, ``"huber"``, ``"cauchy"``, ``"tukey"``)."""
    key = str(name).lower()
    if key not in _KERNELS:
        raise InputError(f"kernel must be one of {sorted(_KERNELS)}, got {name!r}")
    return L2() if key == "l2" else _KERNELS[key](scale_m)

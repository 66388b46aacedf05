"""Robust kernels (M-estimators) for iteratively reweighted least squares.

A kernel maps residuals ``r`` (metres) to IRLS weights ``w(r) = ρ'(r)/r``
(Zhang, "Parameter estimation techniques: a tutorial with application to
conic fitting", 1997, table 1). Kernels are strategy objects passed to
:func:`factorloc.registration.icp2d.align`, like Open3D's
``TransformationEstimationPointToPlane(loss)``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from factorloc.errors import InputError

__all__ = ["Cauchy", "Huber", "L2", "RobustKernel", "Tukey", "kernel_from_name"]


@runtime_checkable
class RobustKernel(Protocol):
    """IRLS weight function of residuals (metres)."""

    def weight(self, residuals_m: np.ndarray) -> np.ndarray:
        """Per-residual weights in [0, 1], same shape as ``residuals_m``."""
        ...


@dataclass(frozen=True)
class L2:
    """Plain least squares: ``w(r) = 1``."""

    def weight(self, residuals_m: np.ndarray) -> np.ndarray:
        return np.ones_like(np.asarray(residuals_m, dtype=np.float64))


def _check_scale(name: str, k: float) -> float:
    k = float(k)
    if not np.isfinite(k) or k <= 0.0:
        raise InputError(f"{name}.scale_m must be > 0, got {k!r}")
    return k


@dataclass(frozen=True)
class Huber:
    """Huber: ``w(r) = 1`` for ``|r| ≤ k`` else ``k/|r|``."""

    scale_m: float = 0.05

    def __post_init__(self) -> None:
        object.__setattr__(self, "scale_m", _check_scale("Huber", self.scale_m))

    def weight(self, residuals_m: np.ndarray) -> np.ndarray:
        a = np.abs(np.asarray(residuals_m, dtype=np.float64))
        return np.where(a <= self.scale_m, 1.0, self.scale_m / np.maximum(a, 1e-300))


@dataclass(frozen=True)
class Cauchy:
    """Cauchy (Lorentzian): ``w(r) = 1 / (1 + (r/k)²)``."""

    scale_m: float = 0.05

    def __post_init__(self) -> None:
        object.__setattr__(self, "scale_m", _check_scale("Cauchy", self.scale_m))

    def weight(self, residuals_m: np.ndarray) -> np.ndarray:
        u = np.asarray(residuals_m, dtype=np.float64) / self.scale_m
        return 1.0 / (1.0 + u * u)


@dataclass(frozen=True)
class Tukey:
    """Tukey biweight: ``w(r) = (1 - (r/k)²)²`` for ``|r| < k`` else 0."""

    scale_m: float = 0.1

    def __post_init__(self) -> None:
        object.__setattr__(self, "scale_m", _check_scale("Tukey", self.scale_m))

    def weight(self, residuals_m: np.ndarray) -> np.ndarray:
        u = np.asarray(residuals_m, dtype=np.float64) / self.scale_m
        return np.where(np.abs(u) < 1.0, (1.0 - u * u) ** 2, 0.0)


_KERNELS = {"l2": L2, "huber": Huber, "cauchy": Cauchy, "tukey": Tukey}


def kernel_from_name(name: str, scale_m: float) -> RobustKernel:
    """Build a kernel from its config name (``"l2"``, ``"huber"``, ``"cauchy"``, ``"tukey"``)."""
    key = str(name).lower()
    if key not in _KERNELS:
        raise InputError(f"kernel must be one of {sorted(_KERNELS)}, got {name!r}")
    return L2() if key == "l2" else _KERNELS[key](scale_m)

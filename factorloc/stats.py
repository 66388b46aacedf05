"""Small statistics the rules and the metrics share: χ² quantiles, 2×2 eigenvalues, Mahalanobis distances.

Each helper has this one home; the gate (:mod:`factorloc.gating`), the metrics
(:mod:`factorloc.evaluation.metrics`), the plots and the benchmarks import it.
Plain Python for the 2×2 cases: a handful per query, where a numpy call costs
more than the arithmetic.
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np

__all__ = [
    "chi2_quantile",
    "largest_sigma",
    "mahalanobis_sq",
    "mahalanobis_sq_2d",
    "smallest_sigma",
    "sym2_eigenvalues",
]


@lru_cache(maxsize=64)
def chi2_quantile(probability: float, dof: int) -> float:
    """The χ² quantile ``χ²_dof⁻¹(probability)`` (e.g. 13.82 for 0.999 and 2 dof; 11.34 for 0.99 and 3).

    scipy's ``chi2.ppf``, imported on first use (``scipy.stats`` alone takes ~0.4 s to import).
    """
    from scipy.stats import chi2

    return float(chi2.ppf(probability, dof))


def sym2_eigenvalues(a: float, b: float, c: float) -> tuple[float, float]:
    """The eigenvalues ``(smallest, largest)`` of the symmetric 2×2 matrix ``[[a, b], [b, c]]``, closed form.

    ``(a + c)/2 ∓ √(((a − c)/2)² + b²)``. The smallest of a positive semi-definite matrix can come out
    at about −1e-16 when it is 0 in theory: callers compare it with a stated tolerance
    (:data:`factorloc.verdicts.ROUNDING_TOLERANCE`) or clamp it.
    """
    mean = 0.5 * (a + c)
    radius = math.sqrt(0.25 * (a - c) ** 2 + b * b)
    return mean - radius, mean + radius


def largest_sigma(covariance: np.ndarray) -> float:
    """Square root of the largest eigenvalue of a covariance's 2×2 position block (m), clamped at 0.

    Without an x–y term it is the larger of the two σ exactly (the closed form would round it).
    """
    a, b, c = float(covariance[0, 0]), float(covariance[0, 1]), float(covariance[1, 1])
    hi = max(a, c) if b == 0.0 else sym2_eigenvalues(a, b, c)[1]
    return math.sqrt(max(hi, 0.0))


def smallest_sigma(covariance: np.ndarray) -> float:
    """Square root of the smallest eigenvalue of a covariance's 2×2 position block (m), clamped at 0."""
    lo, _ = sym2_eigenvalues(float(covariance[0, 0]), float(covariance[0, 1]), float(covariance[1, 1]))
    return math.sqrt(max(lo, 0.0))


def mahalanobis_sq_2d(error: np.ndarray, covariance: np.ndarray) -> float:
    """``eᵀ S⁻¹ e`` of a 2-vector and a 2×2 covariance, in closed form."""
    s00, s01, s11 = float(covariance[0, 0]), float(covariance[0, 1]), float(covariance[1, 1])
    ex, ey = float(error[0]), float(error[1])
    return (s11 * ex * ex - 2.0 * s01 * ex * ey + s00 * ey * ey) / (s00 * s11 - s01 * s01)


def mahalanobis_sq(error: np.ndarray, covariance: np.ndarray) -> float:
    """``eᵀ S⁻¹ e`` of a k-vector and a k×k covariance (by a linear solve, not an inverse)."""
    e = np.asarray(error, dtype=np.float64)
    return float(e @ np.linalg.solve(np.asarray(covariance, dtype=np.float64), e))

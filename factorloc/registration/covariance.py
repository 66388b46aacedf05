"""Covariance of a 2D ICP solution.

Three estimators, all 3×3 over (x, y, θ) of the source pose in the target
frame (the parametrisation of :mod:`factorloc.registration.icp2d`):

* :func:`chamfer_covariance` — the patent's: an isotropic uncertainty
  proportional to the Chamfer distance of the aligned scans. Blind to
  geometry (a corridor gets a round ellipse).
* :func:`hessian_covariance` — ``s² H⁻¹`` with ``H = Σ wᵢ JᵢᵀJᵢ`` the
  Gauss–Newton Hessian of the point-to-line cost and ``s²`` the weighted
  residual variance (Bengtsson & Baerveldt, "Robot localization based on
  scan-matching — estimating the covariance matrix for the IDC algorithm",
  RAS 2003). Captures geometry: along a corridor ``H`` is nearly singular.
* :func:`censi_covariance` — Censi's closed form ("An accurate closed-form
  estimate of ICP's covariance", ICRA 2007):
  ``Σ = H⁻¹ (∂²E/∂x∂z) Σ_z (∂²E/∂x∂z)ᵀ H⁻¹``. For the point-to-line
  cost with fixed correspondences and point noise ``σ`` on both the query and
  the reference points, ``∂²E/∂x∂zᵢ`` reduces to ``wᵢ Jᵢᵀ nᵢᵀ`` per point,
  so ``Σ = H⁻¹ (Σ wᵢ² σᵢ² JᵢᵀJᵢ) H⁻¹`` with ``σᵢ²`` the sum of the pair's
  two point variances; the residual-driven
  term ``Σ wᵢ² rᵢ² JᵢᵀJᵢ`` (the sandwich estimator) is added so that a
  poor fit (map change, misassociation) widens it.

A singular direction of ``H`` (corridor, single wall) is given the variance
``max_variance`` instead of infinity, so the covariance stays positive
definite and the direction is down-weighted or gated downstream.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from factorloc.errors import InputError
from factorloc.registration.icp2d import IcpResult

__all__ = [
    "bias_covariance",
    "censi_bias_covariance",
    "censi_covariance",
    "chamfer_covariance",
    "hessian_covariance",
    "safe_inverse",
    "scale_heading",
]


def safe_inverse(h: np.ndarray, max_variance: float, rel_eps: float = 1e-9) -> tuple[np.ndarray, np.ndarray]:
    """Pseudo-inverse of a symmetric PSD matrix and the projector onto its null space.

    Eigenvalues below ``rel_eps·λ_max`` (or ``1/max_variance``) count as zero:
    the pseudo-inverse ignores them, and the returned projector ``N = Σ v vᵀ``
    over those eigenvectors lets the caller give them ``max_variance``.
    """
    h = np.asarray(h, dtype=np.float64)
    h = 0.5 * (h + h.T)
    lam, vec = np.linalg.eigh(h)
    eps = max(rel_eps * max(float(lam[-1]), 0.0), 1.0 / max_variance)
    good = lam > eps
    inv = (vec[:, good] / lam[good]) @ vec[:, good].T
    null = vec[:, ~good] @ vec[:, ~good].T
    return inv, null


def _finish(cov: np.ndarray, null: np.ndarray, max_variance: float) -> np.ndarray:
    cov = 0.5 * (cov + cov.T) + max_variance * null
    lam, vec = np.linalg.eigh(cov)
    lam = np.clip(lam, 1e-12, max_variance)
    return (vec * lam) @ vec.T


def _check(result: IcpResult) -> None:
    if not isinstance(result, IcpResult):
        raise InputError(f"result must be an IcpResult, got {type(result).__name__}")


def hessian_covariance(result: IcpResult, max_variance: float = 1e4) -> np.ndarray:
    """``s² H⁺`` with ``s² = Σ wᵢ rᵢ² / (Σ wᵢ − 3)`` (m², m·rad, rad²); null directions get ``max_variance``."""
    _check(result)
    w, r = result.weights, result.residuals_m
    if len(r) < 4:
        return np.eye(3) * max_variance
    s2 = float(np.sum(w * r * r) / max(np.sum(w) - 3.0, 1.0))
    inv, null = safe_inverse(result.hessian, max_variance)
    return _finish(s2 * inv, null, max_variance)


def censi_covariance(result: IcpResult, max_variance: float = 1e4) -> np.ndarray:
    """Censi's closed form for point-to-line ICP plus the residual sandwich term (see module docstring).

    The pair noise variances ``σᵢ²`` are the result's ``variances_m2`` (the
    range-dependent model of :class:`~factorloc.registration.icp2d.IcpParams`):
    ``Σ = H⁺ (Σ wᵢ² (σᵢ² + rᵢ²) JᵢᵀJᵢ) H⁺``.
    """
    _check(result)
    J, w, r = result.jacobians, result.weights, result.residuals_m
    if len(r) < 4:
        return np.eye(3) * max_variance
    inv, null = safe_inverse(result.hessian, max_variance)
    meat = (J * (w * w * (result.variances_m2 + r * r))[:, None]).T @ J
    return _finish(inv @ meat @ inv, null, max_variance)


def bias_covariance(result: IcpResult, sigma_bias_m: float, max_variance: float = 1e4) -> np.ndarray:
    """A correlated (non-averaging) error of ``sigma_bias_m`` per point, spread by the geometry: ``σ_b² (H/Σwᵢ)⁺``.

    Censi's formula assumes independent point errors, whose effect shrinks
    as 1/N; errors shared by many points (a slightly wrong association on a
    door frame, a wall that is not straight, timing) do not shrink. With
    ``H/Σwᵢ`` the mean per-point information, this term gives each direction
    the variance ``σ_b²`` divided by the fraction of points that constrain
    it: round in a room, long along a corridor (where only door frames and
    far walls constrain the motion).
    """
    _check(result)
    w = result.weights
    if len(w) < 4 or not np.sum(w) > 0.0:
        return np.eye(3) * max_variance
    inv, null = safe_inverse(result.hessian / float(np.sum(w)), max_variance / max(sigma_bias_m**2, 1e-300))
    return _finish(sigma_bias_m**2 * inv, null, max_variance)


def chamfer_covariance(result: IcpResult, scale: float = 1.0, mean_range_m: float = 3.0) -> np.ndarray:
    """The patent's isotropic uncertainty: σ_xy = scale·chamfer, σ_θ = σ_xy / mean_range_m (diagonal)."""
    _check(result)
    s = max(scale * result.chamfer_m, 1e-4)
    st = s / max(mean_range_m, 1e-3)
    return np.diag([s * s, s * s, st * st])


def scale_heading(cov: np.ndarray, k: float) -> np.ndarray:
    """``D cov D`` with ``D = diag(1, 1, k)``: the heading σ times ``k``, the position block kept, the
    position–heading covariances times ``k``."""
    if k == 1.0:
        return cov
    d = np.array([1.0, 1.0, k])
    return cov * d[:, None] * d[None, :]


def censi_bias_covariance(
    result: IcpResult, scale: float, sigma_bias_m: float, max_variance: float = 1e4, heading_scale: float = 1.0
) -> np.ndarray:
    """``scale · censi_covariance(result) + D bias_covariance(result, sigma_bias_m) D`` from one eigen-decomposition
    of H, with ``D = diag(1, 1, heading_scale)`` (:func:`scale_heading`: the correlated term's heading σ scaled).

    The same figures as the two calls (to rounding, ~1e-12 m²) when H has
    full rank for both (the usual case, computed in one compiled call,
    :func:`_censi_bias_core`); otherwise it falls back to them.
    """
    _check(result)
    J, w, r = result.jacobians, result.weights, result.residuals_m
    if len(r) >= 4:
        ok, cov = _censi_bias_core(
            result.hessian,
            J,
            w,
            r,
            result.variances_m2,
            float(scale),
            float(sigma_bias_m),
            float(max_variance),
            float(heading_scale),
        )
        if ok:
            return cov
    cov = scale * censi_covariance(result, max_variance)
    if sigma_bias_m > 0.0:
        cov = cov + scale_heading(bias_covariance(result, sigma_bias_m, max_variance), heading_scale)
    return cov


@njit(cache=True, inline="always")
def _mul3(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """3×3 product in plain loops (the summation order of the reference form, bit for bit)."""
    out = np.zeros((3, 3))
    for a in range(3):
        for b in range(3):
            acc = 0.0
            for e in range(3):
                acc += x[a, e] * y[e, b]
            out[a, b] = acc
    return out


@njit(cache=True)
def _censi_bias_core(
    hessian: np.ndarray,
    J: np.ndarray,
    w: np.ndarray,
    r: np.ndarray,
    var: np.ndarray,
    scale: float,
    sigma_bias_m: float,
    max_variance: float,
    heading_scale: float,
) -> tuple[bool, np.ndarray]:
    """:func:`censi_bias_covariance`'s full-rank case, compiled: ``(True, Σ)``, or ``(False, ·)`` when H (its
    symmetric part) has an eigenvalue at or below the floor, Σw ≤ 0, or a variance reaches ``max_variance``.

    ``H⁻¹ = V Λ⁻¹ Vᵀ`` (``numpy.linalg.eigh``), ``Σ = scale · sym(H⁻¹ M H⁻¹) + σ_b² Σwᵢ · H⁻¹`` with the
    meat ``M = Σ wᵢ² (σᵢ² + rᵢ²) JᵢJᵢᵀ`` (``J`` K×3 C-contiguous rows); the σ_b term's heading row and column
    times ``heading_scale``.
    """
    out = np.zeros((3, 3))
    sw = 0.0
    for i in range(len(w)):
        sw += w[i]
    if not sw > 0.0:
        return False, out
    h = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            h[a, b] = 0.5 * (hessian[a, b] + hessian[b, a])
    lam, vec = np.linalg.eigh(h)
    floor = max(1e-9 * max(lam[2], 0.0), 1.0 / max_variance)
    if sigma_bias_m > 0.0:
        floor = max(floor, sw * sigma_bias_m**2 / max_variance)
    if not lam[0] > floor:
        return False, out
    inv = np.zeros((3, 3))
    for a in range(3):
        for b in range(3):
            acc = 0.0
            for e in range(3):
                acc += vec[a, e] / lam[e] * vec[b, e]
            inv[a, b] = acc
    meat = np.zeros((3, 3))
    for i in range(len(w)):
        f = w[i] * w[i] * (var[i] + r[i] * r[i])
        for a in range(3):
            for b in range(3):
                meat[a, b] += J[i, a] * f * J[i, b]
    c = _mul3(_mul3(inv, meat), inv)
    sb = sigma_bias_m**2 * sw
    d = (1.0, 1.0, heading_scale)
    cov = np.empty((3, 3))
    for a in range(3):
        for b in range(3):
            cov[a, b] = scale * (0.5 * (c[a, b] + c[b, a]))
            if sigma_bias_m > 0.0:
                cov[a, b] += sb * inv[a, b] * d[a] * d[b]
    for a in range(3):
        if not cov[a, a] < max_variance:
            return False, out
    for a in range(3):
        for b in range(3):
            out[a, b] = 0.5 * (cov[a, b] + cov[b, a])
    return True, out

"""The covariance of an ICP solution, and the geometry measures derived from its Hessian.

``Σ = a·(s·Σ_white + D Σ_bias D) + diag(f_m², f_m², f_rad²)`` (reference frame; m², m·rad, rad²):

* ``Σ_white`` — independent point noise: Censi's closed form with the residual sandwich
  (:func:`~factorloc.registration.covariance.censi_covariance`; A. Censi, "An accurate closed-form estimate of
  ICP's covariance", ICRA 2007), or ``s²H⁻¹`` (Bengtsson & Baerveldt, RAS 2003), or the patent's isotropic σ
  from the Chamfer distance;
* ``Σ_bias = σ_b² (H/Σwᵢ)⁻¹`` — an error shared by the points (a lidar's per-surface range offset, a wall that
  is not straight), which averaging over points does not shrink
  (:func:`~factorloc.registration.covariance.bias_covariance`); ``σ_b`` proportional to the fit's RMSE;
* ``D = diag(1, 1, k)`` scales that term's heading σ, ``a`` is an inflation, ``f`` are floors (what no
  statistic of the pair shows: the ground truth's own error, the sensor's motion during the sweep).

Along a direction the scan does not constrain (one wall, a corridor), :func:`unconstrained_along` gives the
position :data:`UNCONSTRAINED_SIGMA_M`.
"""

from __future__ import annotations

import math
from dataclasses import replace
from functools import lru_cache

import numpy as np

from factorloc.estimators.icp.config import IcpConfig
from factorloc.registration.covariance import (
    bias_covariance,
    censi_bias_covariance,
    chamfer_covariance,
    hessian_covariance,
    scale_heading,
)
from factorloc.registration.icp2d import IcpResult
from factorloc.verdicts import ROUNDING_TOLERANCE

__all__ = [
    "UNCONSTRAINED_SIGMA_M",
    "cloud_config",
    "constraint_strength",
    "heading_strength",
    "covariance",
    "largest_sigma_position",
    "sigma_bias",
    "smallest_sigma_position",
    "unconstrained_along",
    "weak",
]

#: σ (m) the ICP estimate states along a direction its scan does not constrain (the position along one wall or
#: a corridor): large against any room (next to a 30 cm seed it weighs 1e-4), small enough for GTSAM's Cholesky
#: against a 1 mm σ across (the smoother's placeholder prior, ``PLACEHOLDER_SIGMA``, is 30 m for the same
#: reason). A fused position whose largest σ reaches half of it is reported undetermined by the pipeline
#: (:func:`factorloc.gating.unconstrained_position`).
UNCONSTRAINED_SIGMA_M = 30.0


def sigma_bias(result: IcpResult, config: IcpConfig) -> float:
    """σ_b (m) of the correlated-error term: ``bias_rmse_ratio × rmse × max(1, bias_fitness_ref / fitness)``.

    The fitness factor only widens; it is left out when ``bias_fitness_ref`` is 0. 1 m when the RMSE or fitness
    is not finite or the fitness is not positive (no inliers: the estimate is unreliable anyway).
    """
    c = config.covariance
    rmse, fit = result.rmse_m, result.fitness
    if not math.isfinite(rmse):
        return 1.0
    sigma = c.bias_rmse_ratio * rmse
    if c.bias_fitness_ref > 0.0:
        if not (math.isfinite(fit) and fit > 0.0):
            return 1.0
        sigma *= max(1.0, c.bias_fitness_ref / fit)
    return sigma


def covariance(result: IcpResult, config: IcpConfig) -> np.ndarray:
    """The 3×3 covariance (reference frame; m², m·rad, rad²) of an ICP solution (see the module docstring)."""
    c = config.covariance
    sb = sigma_bias(result, config)
    k = c.bias_heading_scale
    if c.model == "censi":
        cov = censi_bias_covariance(result, c.scale, sb, heading_scale=k)
    else:
        cov = hessian_covariance(result) if c.model == "hessian" else chamfer_covariance(result, c.chamfer_scale)
        cov = c.scale * cov
        if sb > 0.0:
            cov = cov + scale_heading(bias_covariance(result, sb), k)
    # the sums below entry by entry in plain floats: numpy's elementwise operations on a 3×3, in the same order (the
    # zeros of the weak term and of the floors added too), so the same bits without their calls' cost
    rows = np.asarray(cov, dtype=np.float64).tolist()
    if c.weak_exponent != 1.0 and sb > 0.0:
        weak_term = _weak_direction(result, sb, c.weak_exponent)
        rows = [[rows[i][j] + weak_term[i][j] for j in range(3)] for i in range(3)]
    if c.inflation != 1.0:
        rows = [[c.inflation * x for x in row] for row in rows]
    floors = (c.sigma_floor_m**2, c.sigma_floor_m**2, c.sigma_floor_rad**2)
    rows = [[rows[i][j] + (floors[i] if i == j else 0.0) for j in range(3)] for i in range(3)]
    return np.array([[0.5 * (rows[i][j] + rows[j][i]) for j in range(3)] for i in range(3)])


#: Smallest constraint strength the weak-direction term divides by (below it the geometry is degenerate and the
#: position is unknown along the walls anyway, :func:`unconstrained_along`).
_WEAK_FLOOR = 1e-3


def _weak_direction(result: IcpResult, sigma_b: float, p: float) -> list[list[float]]:
    """The extra variance ``σ_b² (λ^-p − λ^-1) v vᵀ`` along the weakest position direction ``v`` (eigenvalue λ of
    the normal scatter ``H_pos / Σw``), 3×3 (nested lists) with zeros outside the position block."""
    w = result.weights
    out = [[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.0, 0.0]]
    sw = float(w.sum()) if len(w) >= 3 else 0.0
    if not sw > 0.0:
        return out
    h00, h01, _, _, h11 = result.hessian.ravel().tolist()[:5]
    a, b, c = h00 / sw, h01 / sw, h11 / sw
    lam = max(0.5 * (a + c) - math.sqrt(0.25 * (a - c) ** 2 + b * b), _WEAK_FLOOR)
    v0, v1 = (b, lam - a) if abs(lam - a) >= abs(lam - c) else (lam - c, b)
    n = float(np.hypot(v0, v1))
    v0, v1 = (1.0, 0.0) if n == 0.0 else (v0 / n, v1 / n)
    # σ_b² (λ^-p − λ^-1) v vᵀ in plain floats (the same products as with 2-vectors, without their allocations)
    f = sigma_b**2 * (lam**-p - 1.0 / lam)
    out[0][0], out[0][1], out[1][0], out[1][1] = f * (v0 * v0), f * (v0 * v1), f * (v1 * v0), f * (v1 * v1)
    return out


@lru_cache(maxsize=8)
def cloud_config(config: IcpConfig) -> IcpConfig:
    """``config`` with the depth-cloud cut's correlated-error ratio (``covariance.bias_rmse_ratio_cloud``)."""
    c = config.covariance
    return replace(config, covariance=replace(c, bias_rmse_ratio=c.bias_rmse_ratio_cloud))


def constraint_strength(result: IcpResult, *, debias: bool = False) -> float:
    """Smallest eigenvalue of the mean weighted normal scatter ``Σ wᵢ nᵢnᵢᵀ / Σ wᵢ``, in [0, 0.5].

    0 for one wall or a corridor without features, 0.5 for a round room. The scatter is positive
    semi-definite, so the eigenvalue is ≥ 0 in theory; for one straight wall it is exactly 0, and rounding
    leaves it at about ±1e-16 depending on the instruction set. Values within
    :data:`~factorloc.verdicts.ROUNDING_TOLERANCE` of 0 are returned as 0, so that no verdict depends on the
    sign of that rounding.

    With ``debias``, the part that the normals' own estimation noise adds is taken off: a normal tilted by a
    random δ of variance vᵢ (``IcpResult.normal_variances_rad2``) adds about vᵢ to the scatter along the
    wall, so a noisier laser's corridor would look constrained (measured on MIT CSAIL with 1 cm of extra range
    noise: corridor loops at 0.010 → 0.049, above the limit; ``docs/calibration/icp.md``). The value is then
    the eigenvalue minus ``Σ wᵢ vᵢ / Σ wᵢ``, at least 0.
    """
    w = result.weights
    sw = float(w.sum()) if len(w) >= 3 else 0.0
    if not sw > 0.0:
        return 0.0
    # Σ wᵢ nᵢnᵢᵀ is the position block of the Hessian (the Jacobian's first two columns are the normals)
    h = result.hessian
    a, b, c = float(h[0, 0]) / sw, float(h[0, 1]) / sw, float(h[1, 1]) / sw
    lam = 0.5 * (a + c) - math.sqrt(0.25 * (a - c) ** 2 + b * b)
    if debias and result.normal_variances_rad2 is not None:
        lam -= float(w @ result.normal_variances_rad2) / sw
    return 0.0 if lam < ROUNDING_TOLERANCE else lam


def heading_strength(result: IcpResult) -> float:
    """How much the aligned scan constrains the heading beyond what translation explains, dimensionless in [0, 1].

    The Schur complement of the heading in the Hessian, ``H_θθ − H_θp H_pp⁻¹ H_pθ`` (the position block
    regularized by 1e-9 of its trace, so that a wall's free direction does not divide by zero), over
    ``Σ wᵢ |R qᵢ|²`` of the same weighted correspondences (``IcpResult.heading_lever_m2``: the largest ``H_θθ``
    they could give, every normal perpendicular to its point's ray). 0 for a circle centred on the sensor (every
    normal along its ray: rotating changes nothing); a wall or a room constrain it. Values within
    :data:`~factorloc.verdicts.ROUNDING_TOLERANCE` of 0 are returned as 0.

    The scale is the correspondences' own: the points the Hessian weighs (inliers, near points weighted up by the
    range-dependent noise) rather than the mean squared range of every query point, which on a partial overlap
    or a long-range scan counted far points the alignment barely uses (``docs/calibration/icp.md``).
    """
    w = result.weights
    lever = float(result.heading_lever_m2) if len(w) >= 3 else 0.0
    if not lever > 0.0:
        return 0.0
    h00, h01, h02, h10, h11, h12, h20, h21, h22 = np.asarray(result.hessian, dtype=np.float64).ravel().tolist()
    reg = 1e-9 * max(h00 + h11, 1e-300)
    # H_θp (H_pp + reg·I)⁻¹ H_pθ by the 2×2 inverse in plain floats: the same operations on every CPU (LAPACK's
    # solve picks its kernels, and with them its rounding, by the instruction set) and without numpy's call costs
    a, b, c, d = h00 + reg, h01, h10, h11 + reg
    det = a * d - b * c
    # det ≥ reg·(h00 + h11) = 1e-9·tr² for the PSD position block (one wall included), seven orders above the
    # rounding of a·d − b·c (~1e-16·tr²): a non-positive det is no geometry but a non-finite Hessian
    if not det > 0.0:
        return 0.0
    x0 = (d * h02 - b * h12) / det
    x1 = (a * h12 - c * h02) / det
    schur = h22 - (h20 * x0 + h21 * x1)
    value = min(max(schur / lever, 0.0), 1.0)
    return 0.0 if value < ROUNDING_TOLERANCE else value


def weak(strength: float, limit: float) -> bool:
    """Whether a constraint strength is below ``limit`` beyond rounding (:data:`~factorloc.verdicts.ROUNDING_TOLERANCE`)."""
    return strength < limit - ROUNDING_TOLERANCE


def largest_sigma_position(cov: np.ndarray) -> float:
    """Square root of the largest eigenvalue of the 2×2 position block (m; closed form)."""
    a, b, c = float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1])
    return math.sqrt(max(0.5 * (a + c) + math.sqrt(0.25 * (a - c) ** 2 + b * b), 0.0))


def smallest_sigma_position(cov: np.ndarray) -> float:
    """Square root of the smallest eigenvalue of the 2×2 position block (m; closed form, clamped at 0)."""
    a, b, c = float(cov[0, 0]), float(cov[0, 1]), float(cov[1, 1])
    return math.sqrt(max(0.5 * (a + c) - math.sqrt(0.25 * (a - c) ** 2 + b * b), 0.0))


def unconstrained_along(result: IcpResult, cov: np.ndarray) -> np.ndarray:
    """``cov`` (reference frame) made *unknown* along the direction the scan does not constrain.

    The direction is the eigenvector ``v`` of the smallest eigenvalue of the position block of the ICP Hessian
    (the weighted normal scatter ``Σ wᵢ nᵢnᵢᵀ``, see :func:`constraint_strength`): along one wall or a
    corridor, the wall's direction. Returns ``cov + S² [v; 0][v; 0]ᵀ`` with ``S = UNCONSTRAINED_SIGMA_M`` (m):
    the variance across the walls, the heading's and their correlation are kept; the position along the walls
    carries no information, so a fusion takes it from the other steps.
    """
    h = result.hessian
    a, b, c = float(h[0, 0]), float(h[0, 1]), float(h[1, 1])
    lam_min = 0.5 * (a + c) - math.sqrt(0.25 * (a - c) ** 2 + b * b)
    # eigenvector of [[a, b], [b, c]] for lam_min (the better-conditioned of the two standard forms)
    v = np.array([b, lam_min - a]) if abs(lam_min - a) >= abs(lam_min - c) else np.array([lam_min - c, b])
    n = float(np.hypot(v[0], v[1]))
    v = np.array([1.0, 0.0]) if n == 0.0 else v / n
    out = np.array(cov, dtype=np.float64, copy=True)
    out[:2, :2] += UNCONSTRAINED_SIGMA_M**2 * np.outer(v, v)
    return 0.5 * (out + out.T)

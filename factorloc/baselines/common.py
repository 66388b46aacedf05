"""The baselines' sensor model: :func:`log_likelihood` of an estimate at many poses.

Between two queries a sequential strategy moves its belief by the odometry's relative motion
(:class:`~factorloc.fusion.sequential.MotionModel`, :class:`~factorloc.fusion.sequential.OdometryLink`,
shared with the smoothers in :mod:`factorloc.fusion.sequential`); at each query the grid and particle
filters weigh the hierarchy's gated estimates with :func:`log_likelihood`.
"""

from __future__ import annotations

import math

import numpy as np

from factorloc.types import Component, Estimate, component_indices


def log_likelihood(
    estimate: Estimate, poses: np.ndarray, outlier_probability: float | None = 0.05, area_m2: float = 100.0
) -> np.ndarray:
    """Log-likelihood density of ``estimate`` at each of N×3 world-frame ``poses``.

    The robust sensor model of Thrun et al. (*Probabilistic Robotics* §6.3): a
    Gaussian mixed with a uniform density for wrong measurements,

        p(z | pose) = (1 − ε) N(z; H·pose, R) + ε U,

    with ε = ``outlier_probability``, R the estimate's covariance, θ residuals
    wrapped, and U = 1/``area_m2`` per measured position, 1/(2π) per measured
    heading — so that one wrong estimate cannot wipe out the true hypothesis,
    and the floor stays small against a sharp Gaussian. ``outlier_probability=None``
    gives the pure Gaussian.
    """
    p = np.asarray(poses, dtype=np.float64).reshape(-1, 3)
    idx = component_indices(estimate.components)
    r = np.asarray(estimate.values)[None, :] - p[:, idx]
    if estimate.measures(Component.THETA):
        r[:, -1] = np.mod(r[:, -1] + math.pi, 2.0 * math.pi) - math.pi
    cov = np.asarray(estimate.covariance)
    info = np.linalg.inv(cov)
    d2 = np.einsum("ni,ij,nj->n", r, info, r)
    log_gauss = -0.5 * d2 - 0.5 * float(np.linalg.slogdet(2.0 * math.pi * cov)[1])
    if outlier_probability is None:
        return log_gauss
    eps = float(outlier_probability)
    log_u = 0.0
    if estimate.measures(Component.X):
        log_u -= math.log(float(area_m2))
    if estimate.measures(Component.THETA):
        log_u -= math.log(2.0 * math.pi)
    return np.logaddexp(math.log1p(-eps) + log_gauss, math.log(eps) + log_u)


__all__ = ["log_likelihood"]

"""The patent's closed form: the product of Gaussians, per axis.

WO 2015/158682 fuses the reliable estimates as GLOB(x) = ∏ G(x_i),
GLOB(y) = ∏ G(y_i), GLOB(θ) = ∏ G(θ_i). For 1-D Gaussians the product is
again Gaussian, with information (1/σ²) the sum of the informations and mean
the information-weighted mean:

    1/σ² = Σ 1/σ_i²,    μ = σ² Σ μ_i/σ_i².

This module computes exactly that in information form: each estimate adds
``Hᵀ Σ_i⁻¹ H`` and ``Hᵀ Σ_i⁻¹ z_i`` to a 3×3 system, H selecting its components.
With per-axis (diagonal) covariances it *is* the per-axis product; an estimate
with a full covariance (e.g. ICP's 2×2 position covariance) is the
multivariate product. Headings are fused on the circle, in the tangent space
around the most certain heading.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from factorloc.fusion.base import (
    Fused,
    check_conditioning,
    check_estimates,
    fusion_errors,
    heading_anchor,
    indices,
    undetermined_components,
    unwrap_values,
)
from factorloc.geometry import Pose2
from factorloc.types import Component, Estimate


class ProductFusion:
    """The patent's per-axis Gaussian product, in closed form."""

    name = "product"

    def fuse(self, estimates: Sequence[Estimate]) -> Fused:
        """The product; :class:`~factorloc.errors.FusionError` naming the estimates when their information is too
        ill-conditioned to invert (:func:`~factorloc.fusion.base.check_conditioning`)."""
        ests = check_estimates(estimates)
        check_conditioning(ests)
        with fusion_errors(ests, "product"):
            return self._fuse(ests)

    def _fuse(self, ests: list[Estimate]) -> Fused:
        anchor = heading_anchor(ests)
        info = np.zeros((3, 3))
        vec = np.zeros(3)
        for e in ests:
            idx = indices(e)
            z = unwrap_values(e, anchor)
            lam = np.linalg.inv(e.covariance)
            info[np.ix_(idx, idx)] += lam
            vec[idx] += lam @ z
        undetermined = undetermined_components(ests)
        det = [i for i, c in enumerate((Component.X, Component.Y, Component.THETA)) if c not in undetermined]
        mean = np.zeros(3)
        cov = np.diag(np.full(3, np.inf))
        sub = info[np.ix_(det, det)]
        # Cholesky-based inverse of the information of the determined components
        chol = np.linalg.cholesky(sub)
        inv_chol = np.linalg.solve(chol, np.eye(len(det)))
        sub_cov = inv_chol.T @ inv_chol
        cov[np.ix_(det, det)] = 0.5 * sub_cov + 0.5 * sub_cov.T
        mean[det] = sub_cov @ vec[det]
        if Component.THETA in undetermined:
            mean[2] = 0.0
        return Fused(Pose2(mean[0], mean[1], mean[2]), cov, undetermined)

    def __repr__(self) -> str:
        return "ProductFusion()"

"""Accuracy and honesty metrics of pose estimates against ground truth.

All functions are vectorized over N results and work on plain arrays, so the
same code scores a fused :class:`~factorloc.types.Localization`, a
sequential strategy's belief or a single step's :class:`~factorloc.types.Estimate`.

Conventions
-----------
* Poses are ``(x_m, y_m, theta_rad)`` rows in the world frame.
* The error is ``estimate − truth`` per component, world frame, the heading
  wrapped to [-π, π) (:func:`factorloc.geometry.wrap_angle`).
* A component is **determined** when its variance is finite. A fused
  localization leaves a component it has no evidence for with variance
  ``inf`` (see :class:`~factorloc.types.Localization`); a step's estimate
  determines only the components it measures. Errors of undetermined
  components are ``nan`` and never enter a statistic.

Honesty
-------
* **NEES** (normalized estimation error squared, Bar-Shalom, Li & Kirubarajan,
  *Estimation with Applications to Tracking and Navigation*, 2001, §5.4):
  ``ε = eᵀ Σ⁻¹ e`` over the determined components only; its number of degrees
  of freedom ``k`` is the number of determined components (3 for a full pose).
  For a calibrated Gaussian estimator ``ε ~ χ²(k)``, so its mean is ``k``.
  :func:`nees_mean` averages ε over the fully determined results (k = 3),
  whose expected mean is 3; results with fewer determined components enter
  :func:`normalized_nees_mean` (mean of ε/k, expected 1) and the
  outside-ellipse test (each against its own χ²(k) quantile).
* **Outside the p ellipse**: ``ε > χ²_k⁻¹(p)``; for a calibrated estimator the
  rate is ``1 − p`` (1 % for p = 0.99).
* **Confidently wrong**: a result the estimator called *reliable* (for a
  fused localization: every component determined) whose error exceeds
  ``n_sigma`` (default 3) marginal standard deviations in **any** component:
  ``|e_i| > 3 σ_i``. For a calibrated Gaussian the per-result probability is
  ``1 − (1 − 0.0027)³ ≈ 0.8 %`` (independent components).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from factorloc.errors import InputError
from factorloc.geometry import Pose2, wrap_angle
from factorloc.stats import chi2_quantile
from factorloc.types import Estimate, component_indices

__all__ = [
    "ErrorSummary",
    "chi2_quantile",
    "confidently_wrong",
    "covariance_of_estimate",
    "determined_mask",
    "heading_error_rad",
    "nees",
    "nees_mean",
    "normalized_nees_mean",
    "outside_ellipse",
    "overlap_fraction",
    "pose_errors",
    "position_error_m",
    "summarize",
    "values_of_estimate",
]


# --------------------------------------------------------------------------
# Array helpers
# --------------------------------------------------------------------------
def _poses(name: str, value: np.ndarray | Sequence[Pose2]) -> np.ndarray:
    if isinstance(value, np.ndarray):
        arr = np.asarray(value, dtype=np.float64)
    else:
        items = list(value)
        if items and all(isinstance(p, Pose2) for p in items):
            arr = np.array([p.as_array() for p in items], dtype=np.float64).reshape(-1, 3)
        else:
            arr = np.asarray(items, dtype=np.float64)
    if arr.ndim == 1 and arr.shape[0] == 3:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] != 3:
        raise InputError(f"{name} must be N×3 (x_m, y_m, theta_rad) or a sequence of Pose2, got shape {arr.shape}")
    return arr


def _covariances(name: str, value: np.ndarray, n: int) -> np.ndarray:
    cov = np.asarray(value, dtype=np.float64)
    if cov.ndim == 2:
        cov = cov[None]
    if cov.shape != (n, 3, 3):
        raise InputError(f"{name} must be N×3×3 with N = {n}, got shape {cov.shape}")
    return cov


def determined_mask(covariances: np.ndarray) -> np.ndarray:
    """N×3 bool: which of (x, y, θ) each covariance determines (finite variance).

    Parameters
    ----------
    covariances
        N×3×3 (or 3×3) world-frame covariances, m² and rad²; ``inf`` (or ``nan``)
        on the diagonal marks an undetermined component.
    """
    cov = np.asarray(covariances, dtype=np.float64)
    if cov.ndim == 2:
        cov = cov[None]
    return np.isfinite(np.diagonal(cov, axis1=1, axis2=2))


def pose_errors(estimates: np.ndarray | Sequence[Pose2], truths: np.ndarray | Sequence[Pose2]) -> np.ndarray:
    """World-frame errors ``estimate − truth``, N×3 (m, m, rad), heading wrapped.

    ``nan`` entries in ``estimates`` (unmeasured components) stay ``nan``.
    """
    est = _poses("estimates", estimates)
    tru = _poses("truths", truths)
    if est.shape != tru.shape:
        raise InputError(f"estimates and truths must have the same shape, got {est.shape} and {tru.shape}")
    err = est - tru
    with np.errstate(invalid="ignore"):
        err[:, 2] = np.where(np.isnan(err[:, 2]), np.nan, wrap_angle(np.nan_to_num(err[:, 2])))
    return err


def position_error_m(errors: np.ndarray) -> np.ndarray:
    """Euclidean position error ``√(e_x² + e_y²)`` (m) of N×3 errors (``nan`` where undetermined)."""
    e = np.asarray(errors, dtype=np.float64).reshape(-1, 3)
    return np.hypot(e[:, 0], e[:, 1])


def heading_error_rad(errors: np.ndarray) -> np.ndarray:
    """Absolute heading error ``|wrap(θ − θ_true)|`` (rad) of N×3 errors."""
    e = np.asarray(errors, dtype=np.float64).reshape(-1, 3)
    return np.abs(e[:, 2])


# --------------------------------------------------------------------------
# Summary statistics
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class ErrorSummary:
    """RMSE, median, 95th percentile and max of non-negative errors (same unit as the input).

    ``count`` is the number of finite values used; every statistic is ``nan``
    when it is 0.
    """

    rmse: float
    median: float
    p95: float
    max: float
    count: int

    def scaled(self, factor: float) -> ErrorSummary:
        """The same summary in another unit (e.g. ``180/π`` for degrees)."""
        return ErrorSummary(self.rmse * factor, self.median * factor, self.p95 * factor, self.max * factor, self.count)


def summarize(errors: np.ndarray) -> ErrorSummary:
    """RMSE ``√(mean e²)``, median, 95th percentile (linear interpolation) and max of ``|errors|``.

    ``nan`` values (undetermined results) are ignored.
    """
    e = np.abs(np.asarray(errors, dtype=np.float64).ravel())
    e = e[np.isfinite(e)]
    if e.size == 0:
        return ErrorSummary(math.nan, math.nan, math.nan, math.nan, 0)
    return ErrorSummary(
        float(math.sqrt(np.mean(e * e))), float(np.median(e)), float(np.percentile(e, 95.0)), float(e.max()), int(e.size)
    )


# --------------------------------------------------------------------------
# Honesty
# --------------------------------------------------------------------------
def nees(errors: np.ndarray, covariances: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """NEES ``ε = eᵀ Σ⁻¹ e`` of each result over its determined components.

    Parameters
    ----------
    errors
        N×3 world-frame errors (m, m, rad), e.g. from :func:`pose_errors`.
    covariances
        N×3×3 world-frame covariances (m², rad²); ``inf`` variance marks an
        undetermined component, which is left out (with its cross terms).

    Returns
    -------
    nees, dof
        ``ε`` (``nan`` where nothing is determined) and the number of
        determined components ``k`` (0–3) of each result.
    """
    err = np.asarray(errors, dtype=np.float64).reshape(-1, 3)
    cov = _covariances("covariances", covariances, err.shape[0])
    mask = determined_mask(cov) & np.isfinite(err)
    out = np.full(err.shape[0], np.nan)
    dof = mask.sum(axis=1)
    # group by pattern of determined components: at most 8 patterns, each solved in one batch
    patterns, inverse = np.unique(mask, axis=0, return_inverse=True)
    for p, pattern in enumerate(patterns):
        idx = np.flatnonzero(inverse.ravel() == p)
        comps = np.flatnonzero(pattern)
        if comps.size == 0:
            continue
        sub_cov = cov[np.ix_(idx, comps, comps)]
        sub_err = err[np.ix_(idx, comps)]
        sol = np.linalg.solve(sub_cov, sub_err[..., None])[..., 0]
        out[idx] = np.einsum("ni,ni->n", sub_err, sol)
    return out, dof


def nees_mean(nees_values: np.ndarray, dof: np.ndarray) -> float:
    """Mean NEES over the fully determined results (3 dof; a calibrated estimator gives ≈ 3).

    ``nan`` when no result is fully determined.
    """
    v = np.asarray(nees_values, dtype=np.float64)
    sel = (np.asarray(dof) == 3) & np.isfinite(v)
    return float(v[sel].mean()) if sel.any() else math.nan


def normalized_nees_mean(nees_values: np.ndarray, dof: np.ndarray) -> float:
    """Mean of ``ε/k`` over every result with at least one determined component (calibrated ≈ 1)."""
    v = np.asarray(nees_values, dtype=np.float64)
    k = np.asarray(dof, dtype=np.float64)
    sel = (k > 0) & np.isfinite(v)
    return float((v[sel] / k[sel]).mean()) if sel.any() else math.nan


def outside_ellipse(nees_values: np.ndarray, dof: np.ndarray, probability: float = 0.99) -> np.ndarray:
    """Whether each result lies outside its ``probability`` confidence ellipse(oid): ``ε > χ²_k⁻¹(p)``.

    Results with no determined component are ``False`` (they claim nothing).
    """
    if not 0.0 < probability < 1.0:
        raise InputError(f"probability must be in (0, 1), got {probability!r}")
    v = np.asarray(nees_values, dtype=np.float64)
    k = np.asarray(dof, dtype=np.int64)
    thresholds = np.array([math.inf] + [chi2_quantile(probability, d) for d in (1, 2, 3)])
    with np.errstate(invalid="ignore"):
        return np.isfinite(v) & (v > thresholds[k])


def confidently_wrong(
    errors: np.ndarray, covariances: np.ndarray, reliable: np.ndarray | None = None, n_sigma: float = 3.0
) -> np.ndarray:
    """Reliable results whose error exceeds ``n_sigma`` marginal σ in any determined component.

    Parameters
    ----------
    errors, covariances
        N×3 and N×3×3 as in :func:`nees`.
    reliable
        N bools: what the estimator called reliable. Default: the result
        determines all three components (the definition for a fused pose).
    n_sigma
        The threshold in marginal standard deviations (3).
    """
    err = np.asarray(errors, dtype=np.float64).reshape(-1, 3)
    cov = _covariances("covariances", covariances, err.shape[0])
    if n_sigma <= 0:
        raise InputError(f"n_sigma must be > 0, got {n_sigma!r}")
    mask = determined_mask(cov) & np.isfinite(err)
    rel = mask.all(axis=1) if reliable is None else np.asarray(reliable, dtype=bool).reshape(-1)
    if rel.shape[0] != err.shape[0]:
        raise InputError(f"reliable must have {err.shape[0]} entries, got {rel.shape[0]}")
    with np.errstate(invalid="ignore"):
        sigma = np.sqrt(np.diagonal(cov, axis1=1, axis2=2))
        beyond = np.where(mask, np.abs(np.nan_to_num(err)) > n_sigma * np.where(mask, sigma, 1.0), False)
    return rel & mask.any(axis=1) & beyond.any(axis=1)


# --------------------------------------------------------------------------
# Overlap of what a query sensed with what the reference sensed
# --------------------------------------------------------------------------
def overlap_fraction(query_points_m: np.ndarray, reference_points_m: np.ndarray | cKDTree, radius_m: float = 0.05) -> float:
    """Fraction of the query's surface points that lie within ``radius_m`` of a reference surface point.

    Parameters
    ----------
    query_points_m
        N×2 (or N×3: only x, y are used) surface points the query sensed, in
        the **world** frame (placed by the query's *true* pose).
    reference_points_m
        M×2 (or M×3) surface points the reference sensed, world frame, or a
        ``scipy.spatial.cKDTree`` of such 2D points (built once per reference).
    radius_m
        The match radius in the plane (m): the sensors' noise plus the
        reference's point spacing.

    Returns
    -------
    float
        In [0, 1]; ``nan`` when either set is empty. Walls are vertical, so
        points are compared in the horizontal plane: a surface seen by both at
        different heights still counts.
    """
    q = np.asarray(query_points_m, dtype=np.float64)
    if isinstance(reference_points_m, cKDTree):
        tree = reference_points_m
        if tree.m != 2:
            raise InputError(f"a reference KD-tree must hold 2D points, got {tree.m}D")
        n_ref = tree.n
    else:
        r = np.asarray(reference_points_m, dtype=np.float64)
        if r.ndim != 2 or r.shape[1] not in (2, 3):
            raise InputError(f"reference_points_m must be M×2 or M×3, got shape {r.shape}")
        n_ref = len(r)
        tree = cKDTree(r[:, :2]) if n_ref else None
    if q.ndim != 2 or q.shape[1] not in (2, 3):
        raise InputError(f"query_points_m must be N×2 or N×3, got shape {q.shape}")
    if not radius_m > 0:
        raise InputError(f"radius_m must be > 0, got {radius_m!r}")
    if len(q) == 0 or n_ref == 0 or tree is None:
        return math.nan
    d, _ = tree.query(q[:, :2], distance_upper_bound=radius_m)
    return float(np.mean(np.isfinite(d)))


# --------------------------------------------------------------------------
# A step's estimate as (x, y, θ) rows
# --------------------------------------------------------------------------
def values_of_estimate(estimate: Estimate) -> np.ndarray:
    """The estimate as a 3-vector (x_m, y_m, theta_rad), ``nan`` where it measures nothing."""
    out = np.full(3, np.nan)
    out[component_indices(estimate.components)] = estimate.values
    return out


def covariance_of_estimate(estimate: Estimate) -> np.ndarray:
    """The estimate's covariance embedded in 3×3 (x, y, θ), ``inf`` variance where it measures nothing."""
    out = np.diag(np.full(3, np.inf))
    idx = component_indices(estimate.components)
    out[np.ix_(idx, idx)] = estimate.covariance
    return out

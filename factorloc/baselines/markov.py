"""Markov (grid) localization (Fox, Burgard & Thrun, *Markov localization for mobile robots in
dynamic environments*, JAIR 11, 1999), fed by the hierarchy's estimates.

The belief Bel(x, y, θ) is a histogram on a bounded regular grid: ``bounds_xy``
at ``resolution_m``, and ``n_theta`` heading bins. The two steps of the
discrete Bayes filter (*Probabilistic Robotics*, Table 4.1):

* **Predict**: Bel⁻(s) = Σ_s' p(s | s', Δ) Bel(s'). The odometry motion Δ
  (robot frame) moves every heading slice by its own world-frame translation
  R(θ)·Δxy (a sub-cell shift with linear interpolation) and the slices by Δθ
  (a shift along the circular θ axis); the motion noise is a Gaussian blur
  with the :class:`~factorloc.fusion.sequential.MotionModel` σ. Mass that
  leaves the grid is lost (the grid is bounded). A share ``uniform_mix`` of
  the belief is spread uniformly, so that a kidnapped robot can be found again.
* **Correct**: Bel(s) ∝ Bel⁻(s) · Π_i p(z_i | s), every reliable estimate's
  robust likelihood (:func:`~factorloc.baselines.common.log_likelihood`)
  evaluated at every cell centre.

The reported pose is the belief's mean in a window around its mode (the
mode's neighbourhood, so that the outlier floor spread over the grid does not
drag the mean), with covariance from the same window plus the quantization
variance (resolution²/12). The cost is proportional to the number of cells,
(width/resolution)·(height/resolution)·n_theta: halving the resolution costs
8× in time and memory — why the grid scales badly, and why its accuracy is
bounded by the cell size.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
from scipy import ndimage

from factorloc.baselines.common import log_likelihood
from factorloc.errors import InputError
from factorloc.fusion.base import Fused
from factorloc.fusion.sequential import ODOMETRY_STEP, MotionModel, OdometryLink, gated, reliable_estimates
from factorloc.gating import GatingConfig
from factorloc.geometry import Pose2
from factorloc.types import Component, Estimate, Query, StepReport, component_indices


class MarkovGridLocalization:
    """Histogram (grid) localization (a :class:`~factorloc.fusion.base.SequentialStrategy`).

    Parameters
    ----------
    bounds_xy
        ``(x_min, y_min, x_max, y_max)`` of the grid (m).
    resolution_m
        Cell size in x and y (m).
    n_theta
        Number of heading bins over [-π, π).
    motion
        As in :class:`~factorloc.baselines.mcl.MonteCarloLocalization`.
    gating
        As in :class:`~factorloc.baselines.mcl.MonteCarloLocalization`.
    outlier_probability
        As in :class:`~factorloc.baselines.mcl.MonteCarloLocalization`.
    continuous
        As in :class:`~factorloc.baselines.mcl.MonteCarloLocalization`.
    uniform_mix
        Share of the predicted belief spread uniformly over the grid (recovery from kidnapping).
    undetermined_sigma_m, undetermined_sigma_rad
        When the whole belief's position (heading) σ exceeds this, that component is reported
        under-determined (the estimate near the mode would mean nothing).
    window_cells
        Half-width (cells, and heading bins / 2) of the window around the mode used for the estimate.
    """

    def __init__(
        self,
        bounds_xy: tuple[float, float, float, float],
        resolution_m: float = 0.1,
        n_theta: int = 72,
        motion: MotionModel = MotionModel(),
        gating: GatingConfig | None = GatingConfig(),
        outlier_probability: float = 0.05,
        continuous: bool = True,
        window_cells: int = 4,
        uniform_mix: float = 1e-3,
        undetermined_sigma_m: float = 1.0,
        undetermined_sigma_rad: float = 1.0,
    ) -> None:
        b = tuple(float(v) for v in bounds_xy)
        if len(b) != 4 or not (b[0] < b[2] and b[1] < b[3]) or not all(map(math.isfinite, b)):
            raise InputError(f"bounds_xy must be (x_min, y_min, x_max, y_max) with min < max, got {bounds_xy!r}")
        if not (math.isfinite(resolution_m) and resolution_m > 0):
            raise InputError(f"resolution_m must be > 0, got {resolution_m!r}")
        if isinstance(n_theta, bool) or not isinstance(n_theta, int) or n_theta < 4:
            raise InputError(f"n_theta must be an integer >= 4, got {n_theta!r}")
        self.bounds_xy = b
        self.resolution_m = float(resolution_m)
        self.n_theta = n_theta
        self.motion = motion
        self.gating = gating
        if not 0.0 < outlier_probability < 1.0:
            raise InputError(f"outlier_probability must be in (0, 1), got {outlier_probability!r}")
        self.outlier_probability = float(outlier_probability)
        self.window_cells = int(window_cells)
        if not 0.0 <= uniform_mix < 1.0:
            raise InputError(f"uniform_mix must be in [0, 1), got {uniform_mix!r}")
        self.uniform_mix = float(uniform_mix)
        self.undetermined_sigma_m = float(undetermined_sigma_m)
        self.undetermined_sigma_rad = float(undetermined_sigma_rad)
        self.link = OdometryLink(continuous)
        self.xs = np.arange(b[0] + 0.5 * resolution_m, b[2], resolution_m)
        self.ys = np.arange(b[1] + 0.5 * resolution_m, b[3], resolution_m)
        self.thetas = -math.pi + (np.arange(n_theta) + 0.5) * (2.0 * math.pi / n_theta)
        self.dtheta = 2.0 * math.pi / n_theta
        self.name = f"markov_{resolution_m * 100:g}cm"
        self._centres: np.ndarray | None = None
        self.reset()

    @property
    def n_cells(self) -> int:
        """Number of cells of the grid (θ × y × x)."""
        return self.n_theta * len(self.ys) * len(self.xs)

    def reset(self) -> None:
        self.link.reset()
        self.belief: np.ndarray | None = None  # n_theta × ny × nx, sums to 1

    def _uniform(self) -> np.ndarray:
        return np.full((self.n_theta, len(self.ys), len(self.xs)), 1.0 / self.n_cells)

    # --- the discrete Bayes filter ---------------------------------------------------
    def predict(self, delta: Pose2) -> None:
        """Shift each heading slice by R(θ)·Δxy and the slices by Δθ, then blur with the motion noise."""
        out = np.empty_like(self.belief)
        for k, th in enumerate(self.thetas):  # one vectorized image shift per heading bin
            c, s = math.cos(th), math.sin(th)
            dx, dy = c * delta.x - s * delta.y, s * delta.x + c * delta.y
            out[k] = ndimage.shift(self.belief[k], (dy / self.resolution_m, dx / self.resolution_m), order=1, mode="constant")
        # rotate the θ axis by Δθ (fractional, circular)
        shift = delta.theta / self.dtheta
        lo = math.floor(shift)
        frac = shift - lo
        out = (1.0 - frac) * np.roll(out, lo, axis=0) + frac * np.roll(out, lo + 1, axis=0)
        sig = self.motion.sigmas(delta)
        sigma_cells = (sig[2] / self.dtheta, sig[1] / self.resolution_m, sig[0] / self.resolution_m)
        out = ndimage.gaussian_filter(out, sigma_cells, mode=("wrap", "constant", "constant"), truncate=3.0)
        total = out.sum()
        if total <= 0:
            raise InputError("MarkovGridLocalization: the belief left the grid (bounds_xy too small for the motion)")
        # a small uniform share: the robot may be anywhere (kidnapping), Fox et al.'s robust variant
        self.belief = (1.0 - self.uniform_mix) * out / total + self.uniform_mix / self.n_cells

    def correct(self, estimates: Sequence[Estimate]) -> None:
        """Multiply by every estimate's likelihood at the cell centres, normalize."""
        if not estimates:
            return
        log_b = np.log(np.maximum(self.belief, 1e-300))
        if self._centres is None:
            tt, yy, xx = np.meshgrid(self.thetas, self.ys, self.xs, indexing="ij")
            self._centres = np.column_stack([xx.ravel(), yy.ravel(), tt.ravel()])
        quant = np.array([self.resolution_m**2, self.resolution_m**2, self.dtheta**2]) / 12.0
        for e in estimates:
            # the likelihood of a cell, not of its centre: the estimate's covariance plus the cell's extent
            idx = component_indices(e.components)
            cell = Estimate(e.step, e.components, e.values, np.asarray(e.covariance) + np.diag(quant[idx]))
            area = (self.bounds_xy[2] - self.bounds_xy[0]) * (self.bounds_xy[3] - self.bounds_xy[1])
            log_b += log_likelihood(cell, self._centres, self.outlier_probability, area).reshape(self.belief.shape)
        b = np.exp(log_b - log_b.max())
        self.belief = b / b.sum()

    def estimate(self) -> tuple[np.ndarray, np.ndarray]:
        """Mean (circular in θ) and covariance of the belief in the window around its mode, plus quantization."""
        k, j, i = np.unravel_index(int(np.argmax(self.belief)), self.belief.shape)
        w = self.window_cells
        kk = np.arange(k - w // 2, k + w // 2 + 1) % self.n_theta
        jj = np.arange(max(0, j - w), min(len(self.ys), j + w + 1))
        ii = np.arange(max(0, i - w), min(len(self.xs), i + w + 1))
        sub = self.belief[np.ix_(kk, jj, ii)]
        sub = sub / sub.sum()
        tt, yy, xx = np.meshgrid(self.thetas[kk], self.ys[jj], self.xs[ii], indexing="ij")
        mx, my = float((sub * xx).sum()), float((sub * yy).sum())
        mt = math.atan2(float((sub * np.sin(tt)).sum()), float((sub * np.cos(tt)).sum()))
        r = np.stack([xx - mx, yy - my, np.mod(tt - mt + math.pi, 2 * math.pi) - math.pi], axis=-1).reshape(-1, 3)
        wv = sub.ravel()
        cov = (r * wv[:, None]).T @ r
        cov += np.diag([self.resolution_m**2 / 12.0, self.resolution_m**2 / 12.0, self.dtheta**2 / 12.0])
        return np.array([mx, my, mt]), 0.5 * (cov + cov.T)

    # --- SequentialStrategy ------------------------------------------------------------
    def update(self, query: Query, reports: Sequence[StepReport]) -> Fused:
        delta = self.link.motion(query)
        reliable = reliable_estimates(reports)
        if delta is None or self.belief is None:
            self.belief = self._uniform()
            measurements, _ = gated(reliable, self.gating)  # a new run: the odometry's absolute pose too
        else:
            self.predict(delta)
            measurements, _ = gated([e for e in reliable if e.step != ODOMETRY_STEP], self.gating)
        self.correct(measurements)
        mean, cov = self.estimate()
        return Fused(Pose2.from_array(mean), cov, self._undetermined())

    def _undetermined(self) -> tuple[Component, ...]:
        """Components whose whole-grid marginal σ exceeds the thresholds."""
        out: tuple[Component, ...] = ()
        px, py = self.belief.sum(axis=(0, 1)), self.belief.sum(axis=(0, 2))
        sx = math.sqrt(float(px @ (self.xs - px @ self.xs) ** 2))
        sy = math.sqrt(float(py @ (self.ys - py @ self.ys) ** 2))
        if max(sx, sy) > self.undetermined_sigma_m:
            out += (Component.X, Component.Y)
        pt = self.belief.sum(axis=(1, 2))
        r = abs(complex(float(pt @ np.cos(self.thetas)), float(pt @ np.sin(self.thetas))))
        if math.sqrt(-2.0 * math.log(max(r, 1e-300))) > self.undetermined_sigma_rad:
            out += (Component.THETA,)
        return out

    def __repr__(self) -> str:
        return f"MarkovGridLocalization(resolution_m={self.resolution_m}, n_theta={self.n_theta}, cells={self.n_cells})"


__all__ = ["MarkovGridLocalization"]

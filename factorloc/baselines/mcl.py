"""Monte Carlo localization (Thrun, Fox, Burgard & Dellaert, *Robust Monte Carlo localization
for mobile robots*, Artificial Intelligence 128, 2001), fed by the hierarchy's estimates.

The belief is a set of N weighted particles (x, y, θ) in the world frame.

* **Predict** (sample the odometry motion model, *Probabilistic Robotics*
  Table 5.6 in the robot frame): each particle moves by the odometry motion Δ
  perturbed with its own draw of the :class:`~factorloc.fusion.sequential.MotionModel` noise.
* **Correct**: weights are multiplied by the likelihood of every reliable
  estimate of the query (gated as in the hierarchy), with the robust sensor
  model (Gaussian with a uniform outlier floor,
  :func:`~factorloc.baselines.common.log_likelihood`).
* **Mixture proposal** (the paper's *Mixture-MCL*): a fraction ``dual_fraction``
  of the particles is drawn from the measurements themselves (their Gaussian
  product, when they fix the full pose) — this keeps MCL from starving when
  the sensor is much sharper than the motion (ICP σ ≈ 5 mm against several cm
  of odometry noise). All particles are then weighted by importance sampling
  against the mixture proposal, w = p(z|x)·prior(x) / ((1−φ)·prior(x) + φ·sensor(x)),
  with Gaussian fits of the predicted particles and of the measurements (the
  paper normalizes the two sets separately, which keeps a fixed share of the
  mass on forward particles even when they all miss the measurement).
* **Resampling**: low-variance (systematic) resampling, *Probabilistic
  Robotics* Table 4.4, when the effective sample size falls under N/2,
  followed by a small regularization jitter (the regularized particle filter).
* **Random particles** for kidnapped-robot recovery (Augmented MCL, *Probabilistic
  Robotics* Table 8.3): short- and long-term averages w_fast, w_slow of how
  well the measurements fit the belief; a fraction max(0, 1 − w_fast/w_slow) of
  the particles is replaced by random ones — drawn around the measurements
  when they fix the full pose (sensor resetting, Lenser & Veloso 2000), else
  uniform in ``bounds_xy``. *Deviation from the textbook*: the fit is
  exp(−d²/(2·dof)) of the measurements' Mahalanobis distance to the particles'
  mean and covariance, not the mean particle weight — with sensors ten times
  sharper than the motion noise the mean weight drops at every step and reads
  as a kidnapping (measured: particles scattered over the whole apartment).

The returned belief is the weighted mean (circular for θ) and covariance of the particles.
Everything is vectorized over particles; the RNG is seeded (``seed``) and re-seeded by :meth:`reset`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from factorloc.baselines.common import log_likelihood
from factorloc.errors import InputError
from factorloc.fusion.base import Fused
from factorloc.fusion.product import ProductFusion
from factorloc.fusion.sequential import ODOMETRY_STEP, MotionModel, OdometryLink, gated, reliable_estimates
from factorloc.gating import GatingConfig
from factorloc.geometry import Pose2
from factorloc.types import Component, Estimate, Query, StepReport, component_indices


def _wrap(a: np.ndarray) -> np.ndarray:
    return np.mod(a + math.pi, 2.0 * math.pi) - math.pi


def low_variance_resample(weights: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Indices drawn by low-variance (systematic) resampling: one random offset, N evenly spaced pointers."""
    w = np.asarray(weights, dtype=np.float64)
    n = w.size
    positions = (rng.random() + np.arange(n)) / n
    cum = np.cumsum(w / w.sum())
    cum[-1] = 1.0
    return np.searchsorted(cum, positions, side="left")


def weighted_mean_covariance(particles: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean (circular mean for θ) and covariance (θ residuals wrapped) of N×3 particles."""
    w = weights / weights.sum()
    mean = np.empty(3)
    mean[:2] = w @ particles[:, :2]
    mean[2] = math.atan2(float(w @ np.sin(particles[:, 2])), float(w @ np.cos(particles[:, 2])))
    r = particles - mean
    r[:, 2] = _wrap(r[:, 2])
    cov = (r * w[:, None]).T @ r
    return mean, 0.5 * (cov + cov.T)


class MonteCarloLocalization:
    """Particle-filter localization (a :class:`~factorloc.fusion.base.SequentialStrategy`).

    Parameters
    ----------
    n_particles
        Number of particles N.
    bounds_xy
        ``(x_min, y_min, x_max, y_max)`` (m) for random particles (global
        initialization and kidnap recovery); None: random particles are drawn
        around the measurements (3× their σ) instead.
    motion
        Odometry motion noise.
    gating
        The consistency gate applied among the query's estimates (default: the library's).
    dual_fraction
        Fraction of particles drawn from the measurements (Mixture-MCL); 0 gives plain MCL.
    alpha_slow, alpha_fast
        Averaging rates of the long- and short-term likelihood (Augmented MCL; 0 < slow ≪ fast).
    outlier_probability
        ε of the robust sensor model (:func:`~factorloc.baselines.common.log_likelihood`); its uniform
        part spreads over ``bounds_xy`` (100 m² without bounds).
    continuous
        Whether consecutive queries share one odometry run.
    seed
        Seed of the random generator.
    trust_verdicts
        True (default): the estimates their estimator judged reliable; False: every estimate
        (the robust sensor model and the random particles alone deal with the wrong ones).
    undetermined_sigma_m, undetermined_sigma_rad
        A belief spread wider than this (largest position σ, heading σ) is reported as
        under-determined in that component, like a per-query fusion without a position measurement.
    """

    def __init__(
        self,
        n_particles: int = 2000,
        bounds_xy: tuple[float, float, float, float] | None = None,
        motion: MotionModel = MotionModel(),
        gating: GatingConfig | None = GatingConfig(),
        dual_fraction: float = 0.1,
        alpha_slow: float = 0.05,
        alpha_fast: float = 0.5,
        outlier_probability: float = 0.05,
        continuous: bool = True,
        seed: int = 0,
        trust_verdicts: bool = True,
        undetermined_sigma_m: float = 1.0,
        undetermined_sigma_rad: float = 1.0,
    ) -> None:
        if isinstance(n_particles, bool) or not isinstance(n_particles, int) or n_particles < 10:
            raise InputError(f"n_particles must be an integer >= 10, got {n_particles!r}")
        if bounds_xy is not None:
            b = tuple(float(v) for v in bounds_xy)
            if len(b) != 4 or not (b[0] < b[2] and b[1] < b[3]) or not all(map(math.isfinite, b)):
                raise InputError(f"bounds_xy must be (x_min, y_min, x_max, y_max) with min < max, got {bounds_xy!r}")
            bounds_xy = b
        if not 0.0 <= dual_fraction < 1.0:
            raise InputError(f"dual_fraction must be in [0, 1), got {dual_fraction!r}")
        if not 0.0 < alpha_slow < alpha_fast <= 1.0:
            raise InputError(f"need 0 < alpha_slow < alpha_fast <= 1, got {alpha_slow!r}, {alpha_fast!r}")
        self.n = n_particles
        self.bounds_xy = bounds_xy
        self.motion = motion
        self.gating = gating
        self.dual_fraction = float(dual_fraction)
        self.alpha_slow, self.alpha_fast = float(alpha_slow), float(alpha_fast)
        if not 0.0 < outlier_probability < 1.0:
            raise InputError(f"outlier_probability must be in (0, 1), got {outlier_probability!r}")
        self.outlier_probability = float(outlier_probability)
        self.area_m2 = 100.0 if bounds_xy is None else (bounds_xy[2] - bounds_xy[0]) * (bounds_xy[3] - bounds_xy[1])
        self.seed = int(seed)
        self.link = OdometryLink(continuous)
        self.trust_verdicts = bool(trust_verdicts)
        self.undetermined_sigma_m = float(undetermined_sigma_m)
        self.undetermined_sigma_rad = float(undetermined_sigma_rad)
        self.name = f"mcl_{n_particles}" + ("" if trust_verdicts else "_all")
        self.reset()

    def reset(self) -> None:
        self.link.reset()
        self.rng = np.random.default_rng(self.seed)
        self.particles: np.ndarray | None = None
        self.weights = np.full(self.n, 1.0 / self.n)
        self.w_slow = self.w_fast = None
        self.injected = 0

    # --- pieces ------------------------------------------------------------------------
    def _random(self, m: int, around: tuple[np.ndarray, np.ndarray] | None) -> np.ndarray:
        """``m`` random particles: uniform in the bounds, else around ``(mean, cov)``."""
        if m == 0:
            return np.zeros((0, 3))
        if around is not None:
            mean, cov = around
            return self._gaussian(mean, 9.0 * cov, m)
        if self.bounds_xy is not None:
            x0, y0, x1, y1 = self.bounds_xy
            return np.column_stack(
                [self.rng.uniform(x0, x1, m), self.rng.uniform(y0, y1, m), self.rng.uniform(-math.pi, math.pi, m)]
            )
        raise InputError("MonteCarloLocalization needs bounds_xy, or measurements of the full pose, to draw random particles")

    def _gaussian(self, mean: np.ndarray, cov: np.ndarray, m: int) -> np.ndarray:
        out = self.rng.multivariate_normal(mean, cov + 1e-12 * np.eye(3), size=m, method="cholesky")
        out[:, 2] = _wrap(out[:, 2])
        return out

    def predict(self, delta: Pose2) -> None:
        """Move every particle by Δ with its own motion-noise draw (robot frame)."""
        sig = self.motion.sigmas(delta)
        noisy = np.array([delta.x, delta.y, delta.theta]) + self.rng.standard_normal((self.n, 3)) * sig
        c, s = np.cos(self.particles[:, 2]), np.sin(self.particles[:, 2])
        self.particles = np.column_stack(
            [
                self.particles[:, 0] + c * noisy[:, 0] - s * noisy[:, 1],
                self.particles[:, 1] + s * noisy[:, 0] + c * noisy[:, 1],
                _wrap(self.particles[:, 2] + noisy[:, 2]),
            ]
        )

    def _loglik(self, estimates: Sequence[Estimate], poses: np.ndarray) -> np.ndarray:
        ll = np.zeros(len(poses))
        for e in estimates:
            ll += log_likelihood(e, poses, self.outlier_probability, self.area_m2)
        return ll

    def correct(self, estimates: Sequence[Estimate]) -> None:
        """Weight by the measurements, mix in dual and random particles, resample when degenerate."""
        if not estimates:
            return
        measured = _gaussian_of(estimates)
        fit = self._fit(estimates)
        n_dual = int(round(self.dual_fraction * self.n)) if measured is not None else 0
        if n_dual:
            # Mixture-MCL: a share of the particles is drawn from the sensor model. Every particle is
            # weighted by importance sampling against the mixture proposal q = (1−φ)·prior + φ·sensor
            # (Gaussian fits of both): w = p(z|x)·prior(x) / q(x).
            prior_mean, prior_cov = weighted_mean_covariance(self.particles, self.weights)
            keep = self.rng.choice(self.n, self.n - n_dual, replace=False, p=self.weights / self.weights.sum())
            dual = self._gaussian(measured[0], measured[1], n_dual)
            self.particles = np.vstack([self.particles[keep], dual])
            ll = self._loglik(estimates, self.particles)
            lp = _log_gauss(self.particles, prior_mean, prior_cov)
            lm = _log_gauss(self.particles, measured[0], measured[1])
            lq = np.logaddexp(math.log1p(-self.dual_fraction) + lp, math.log(self.dual_fraction) + lm)
            logw = ll + lp - lq
            weights = np.exp(logw - logw.max())
        else:
            ll = self._loglik(estimates, self.particles)
            weights = self.weights * np.exp(ll - ll.max())
        self.weights = weights / weights.sum()
        # Augmented MCL: compare the short- and long-term fit of the measurements
        if self.w_slow is None:
            self.w_slow = self.w_fast = fit
        else:
            self.w_slow += self.alpha_slow * (fit - self.w_slow)
            self.w_fast += self.alpha_fast * (fit - self.w_fast)
        p_random = max(0.0, 1.0 - self.w_fast / self.w_slow) if self.w_slow > 0 else 0.0
        n_eff = 1.0 / float(np.sum(self.weights**2))
        if n_eff < 0.5 * self.n or p_random > 0:
            self._resample(p_random, measured, estimates)

    def _fit(self, estimates: Sequence[Estimate]) -> float:
        """exp(−d²/(2·dof)): Mahalanobis fit of the measurements to the predicted particles (1 = perfect)."""
        mean, cov = weighted_mean_covariance(self.particles, self.weights)
        d2, dof = 0.0, 0
        for e in estimates:
            idx = component_indices(e.components)
            r = np.asarray(e.values) - mean[idx]
            if e.measures(Component.THETA):
                r[-1] = _wrap(r[-1])
            d2 += float(r @ np.linalg.solve(np.asarray(e.covariance) + cov[np.ix_(idx, idx)], r))
            dof += len(idx)
        return math.exp(-0.5 * d2 / max(dof, 1))

    def _resample(self, p_random: float, measured: tuple[np.ndarray, np.ndarray] | None, estimates: Sequence[Estimate]) -> None:
        mean, cov = weighted_mean_covariance(self.particles, self.weights)
        idx = low_variance_resample(self.weights, self.rng)
        parts = self.particles[idx]
        # regularized PF: jitter with the optimal kernel bandwidth for a Gaussian, h = (4/(N(d+2)))^(1/(d+4))
        h = (4.0 / (self.n * 5.0)) ** (1.0 / 7.0)
        parts = parts + self.rng.multivariate_normal(np.zeros(3), h * h * cov + 1e-12 * np.eye(3), size=self.n, method="cholesky")
        parts[:, 2] = _wrap(parts[:, 2])
        m = int(self.rng.binomial(self.n, min(1.0, p_random))) if p_random > 0 else 0
        if m:
            parts[self.rng.choice(self.n, m, replace=False)] = self._random(m, measured)
            self.injected += m
            # the random particles must earn their weight from this query's evidence
            ll = self._loglik(estimates, parts)
            w = np.exp(ll - ll.max())
            self.particles, self.weights = parts, w / w.sum()
            return
        self.particles, self.weights = parts, np.full(self.n, 1.0 / self.n)

    # --- SequentialStrategy ------------------------------------------------------------
    def update(self, query: Query, reports: Sequence[StepReport]) -> Fused:
        delta = self.link.motion(query)
        reliable = reliable_estimates(reports)
        if not self.trust_verdicts:
            reliable = [r.estimate for r in reports if r.estimate is not None]
        if delta is None or self.particles is None:
            accepted, _ = gated(reliable, self.gating)
            odo = [e for e in accepted if e.step == ODOMETRY_STEP and e.kind == "full"]
            measurements = [e for e in accepted if e.step != ODOMETRY_STEP]
            if odo:
                self.particles = self._gaussian(np.array(odo[0].values), np.asarray(odo[0].covariance), self.n)
            else:
                self.particles = self._random(self.n, _gaussian_of(measurements))
            self.weights = np.full(self.n, 1.0 / self.n)
            self.w_slow = self.w_fast = None
        else:
            self.predict(delta)
            measurements, _ = gated([e for e in reliable if e.step != ODOMETRY_STEP], self.gating)
        self.correct(measurements)
        mean, cov = weighted_mean_covariance(self.particles, self.weights)
        return Fused(
            Pose2.from_array(mean), cov, spread_undetermined(cov, self.undetermined_sigma_m, self.undetermined_sigma_rad)
        )

    def __repr__(self) -> str:
        return f"MonteCarloLocalization(n_particles={self.n}, seed={self.seed})"


def spread_undetermined(covariance: np.ndarray, sigma_m: float, sigma_rad: float) -> tuple[Component, ...]:
    """The components of a sample-based belief too spread out to count as determined."""
    out: tuple[Component, ...] = ()
    if math.sqrt(max(float(np.linalg.eigvalsh(covariance[:2, :2])[-1]), 0.0)) > sigma_m:
        out += (Component.X, Component.Y)
    if math.sqrt(max(float(covariance[2, 2]), 0.0)) > sigma_rad:
        out += (Component.THETA,)
    return out


def _log_gauss(x: np.ndarray, mean: np.ndarray, cov: np.ndarray) -> np.ndarray:
    """log N(x; mean, cov) of N×3 poses (θ residual wrapped)."""
    c = np.asarray(cov) + 1e-12 * np.eye(3)
    r = x - mean
    r[:, 2] = _wrap(r[:, 2])
    d2 = np.einsum("ni,ij,nj->n", r, np.linalg.inv(c), r)
    return -0.5 * d2 - 0.5 * float(np.linalg.slogdet(2.0 * math.pi * c)[1])


def _gaussian_of(estimates: Sequence[Estimate]) -> tuple[np.ndarray, np.ndarray] | None:
    """The Gaussian product of ``estimates`` when it determines the full pose, else None."""
    if not estimates:
        return None
    fused = ProductFusion().fuse(estimates)
    if fused.undetermined:
        return None
    return fused.pose.as_array(), np.asarray(fused.covariance)


__all__ = ["MonteCarloLocalization", "low_variance_resample", "weighted_mean_covariance"]

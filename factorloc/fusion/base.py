"""What a fusion strategy is, and what it returns."""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Protocol, runtime_checkable

import numpy as np

from factorloc.errors import FactorlocError, FusionError
from factorloc.geometry import Pose2, wrap_angle
from factorloc.types import FULL, Component, Estimate, Query, StepReport, component_indices


@dataclass(frozen=True, eq=False)
class Fused:
    """A fused pose: its maximum-likelihood value and world-frame covariance.

    ``covariance`` is 3×3, order (x, y, θ); an under-determined component has
    variance ``inf`` (no cross terms) and a placeholder value.
    """

    pose: Pose2
    covariance: np.ndarray
    undetermined: tuple[Component, ...] = ()


@runtime_checkable
class FusionStrategy(Protocol):
    """Fuses independent estimates of one pose into one Gaussian."""

    name: str

    def fuse(self, estimates: Sequence[Estimate]) -> Fused:
        """The maximum-likelihood pose and its world-frame covariance."""
        ...


@runtime_checkable
class SequentialStrategy(Protocol):
    """A strategy with memory across consecutive queries of one run.

    Trajectory smoothers, EKFs, Monte Carlo and Markov localization keep a
    belief from one query to the next and move it with the odometry between
    them (``query.odometry``: consecutive ``T_world_robot`` give the relative
    motion). At each query they receive the step reports of the hierarchy
    (every estimate with its reliability verdict and gate status) and return
    their current pose belief. The evaluation runs them in scenario order
    after :meth:`reset`.
    """

    name: str

    def reset(self) -> None:
        """Forget everything (start of a run)."""
        ...

    def update(self, query: Query, reports: Sequence[StepReport]) -> Fused:
        """Take one query's evidence, return the current pose belief (world frame)."""
        ...


def indices(estimate: Estimate) -> list[int]:
    """Positions of the estimate's components in (x, y, θ)."""
    return component_indices(estimate.components)


def undetermined_components(estimates: Sequence[Estimate]) -> tuple[Component, ...]:
    """Components that no estimate measures (position counts as x and y together)."""
    measured = {c for e in estimates for c in e.components}
    return tuple(c for c in FULL if c not in measured)


def mark_undetermined(covariance: np.ndarray, undetermined: Sequence[Component]) -> np.ndarray:
    """A copy of a 3×3 (x, y, θ) covariance with each ``undetermined`` component unknown.

    Its variance becomes ``inf`` and its cross terms 0: the convention of :class:`Fused` and
    :class:`~factorloc.types.Localization` for a component that no fused estimate constrains.
    """
    cov = np.array(covariance, dtype=np.float64)
    if undetermined:
        idx = component_indices(undetermined)
        cov[idx, :] = 0.0
        cov[:, idx] = 0.0
        cov[idx, idx] = np.inf
    return cov


def check_estimates(estimates: Sequence[Estimate]) -> list[Estimate]:
    """Validate the input of a strategy: a non-empty sequence of :class:`Estimate`."""
    ests = list(estimates)
    if not ests:
        raise FusionError("nothing to fuse: the list of estimates is empty")
    for i, e in enumerate(ests):
        if not isinstance(e, Estimate):
            raise FusionError(f"estimates[{i}] is a {type(e).__name__}, not an Estimate")
    return ests


def heading_anchor(estimates: Sequence[Estimate]) -> float:
    """The heading of the most certain heading-measuring estimate (0 if none).

    Headings are fused in the tangent space around it, so that 179° and −179°
    average to 180°, not 0°.
    """
    best, best_var = 0.0, math.inf
    for e in estimates:
        if e.measures(Component.THETA):
            var = e.sigma(Component.THETA) ** 2
            if var < best_var:
                best, best_var = e.value(Component.THETA), var
    return best


def unwrap_values(estimate: Estimate, anchor_rad: float) -> np.ndarray:
    """The estimate's values with θ expressed as ``anchor + wrap(θ - anchor)``."""
    z = np.array(estimate.values, dtype=np.float64)
    if estimate.measures(Component.THETA):
        z[-1] = anchor_rad + wrap_angle(z[-1] - anchor_rad)
    return z


#: The largest condition number (λmax/λmin) of the fused position information that a strategy inverts.
#: Measured on one full pose at θ = 1 rad (``tests/fusion/test_conditioning.py``): at 1e12 the graph's σ are
#: within 1e-5 relative of the truth, at 1e14 1e-3, at 1e16 off by 80 %. Beyond it fusion raises
#: :class:`~factorloc.errors.FusionError` instead of reporting digits it does not have.
MAX_CONDITION = 1e12


def information(covariance: np.ndarray) -> np.ndarray:
    """The inverse of a validated k×k covariance, computed through its correlation matrix (``S⁻¹ R⁻¹ S⁻¹``).

    The scaling keeps the inverse exact for any σ of the documented range; the correlation matrix is bounded
    away from singular at construction (:data:`factorloc._validate.MIN_CORRELATION_EIGENVALUE`).
    """
    cov = np.asarray(covariance, dtype=np.float64)
    scale = 1.0 / np.sqrt(np.diagonal(cov))
    outer = np.outer(scale, scale)
    return np.linalg.inv(cov * outer) * outer


def steps_of(estimates: Sequence[Estimate]) -> str:
    """The steps of ``estimates`` for a message: ``['odometry', 'icp']`` (the first 8 and a count beyond)."""
    names = [e.step for e in estimates]
    shown = repr(names[:8])
    return shown if len(names) <= 8 else f"{shown[:-1]}, … ({len(names)} estimates)]"


def check_conditioning(estimates: Sequence[Estimate]) -> float:
    """The condition number of the estimates' fused position information; :class:`FusionError` beyond
    :data:`MAX_CONDITION` (or when the heading's information is not finite).

    The position block is what a graph rotates between the world and the body frame, so its plain condition
    number (rotation-invariant) bounds the digits lost; the heading is one number and the x–θ coupling is
    bounded per estimate at construction. Returns the condition number (1.0 with no position).
    """
    info = np.zeros((3, 3))
    for e in estimates:
        idx = indices(e)
        info[np.ix_(idx, idx)] += information(e.covariance)
    if not np.isfinite(info).all():
        raise FusionError(f"the information of estimates {steps_of(estimates)} is not finite")
    if not any(e.measures(Component.X) for e in estimates):
        return 1.0
    eig = np.linalg.eigvalsh(info[:2, :2])
    cond = math.inf if eig[0] <= 0.0 else float(eig[1] / eig[0])
    if not cond <= MAX_CONDITION:
        raise FusionError(
            f"the position information of estimates {steps_of(estimates)} is too ill-conditioned to invert: "
            f"condition number {cond:.3g} > {MAX_CONDITION:g} (σ along one direction {math.sqrt(1 / eig[0]):.3g} m, "
            f"across {math.sqrt(1 / eig[1]):.3g} m)"
        )
    return cond


@contextlib.contextmanager
def fusion_errors(estimates: Sequence[Estimate], strategy: str) -> Iterator[None]:
    """Re-raise a GTSAM or numpy failure inside ``strategy`` as :class:`FusionError` naming the estimates.

    GTSAM raises ``RuntimeError`` (indeterminate system) and ``ValueError`` (constrained noise model); numpy
    ``LinAlgError``; arithmetic ``ArithmeticError``. The library's own errors pass through unchanged.
    """
    try:
        yield
    except FactorlocError:
        raise
    except (RuntimeError, ValueError, ArithmeticError, np.linalg.LinAlgError) as exc:
        detail = " ".join(str(exc).split())[:200]
        raise FusionError(f"{strategy} fusion of estimates {steps_of(estimates)} failed: {type(exc).__name__}: {detail}") from exc

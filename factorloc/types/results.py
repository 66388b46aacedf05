"""What became of each step, and the fused pose: :class:`StepStatus`, :class:`StepReport`, :class:`Localization`."""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import StrEnum
from typing import TYPE_CHECKING, Any

import numpy as np

from factorloc._validate import nonnegative_float
from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.types.components import Component
from factorloc.types.estimate import Estimate
from factorloc.verdicts import Check

if TYPE_CHECKING:  # pragma: no cover
    from factorloc.config import Config

__all__ = ["Localization", "StepReport", "StepStatus"]


class StepStatus(StrEnum):
    """What became of one step's estimate."""

    FUSED = "fused"
    UNRELIABLE = "unreliable"  # failed the estimator's own test or a reliability gate
    INCONSISTENT = "inconsistent"  # reliable, but rejected by the consistency gate
    SKIPPED = "skipped"  # its inputs were absent
    FAILED = "failed"  # it raised on this input (the error is the reason)


@dataclass(frozen=True)
class StepReport:
    """One step of one localization: its estimate, its fate, why, and its run time (s).

    ``checks`` are the typed verdicts that decided ``status`` (:func:`factorloc.gating.gate`): the estimate's
    failed checks when ``UNRELIABLE``, the gate's when ``INCONSISTENT`` or (partly) ``FUSED``; ``reason`` is
    the sentence rendered from them (:func:`factorloc.gating.report_reason`). Counts by rule read
    :attr:`rule_codes`, never the reason.
    """

    name: str
    status: StepStatus
    estimate: Estimate | None = None
    reason: str = ""
    seconds: float = 0.0
    checks: tuple[Check, ...] = ()

    def __post_init__(self) -> None:
        object.__setattr__(self, "status", StepStatus(self.status))
        checks = tuple(self.checks)
        for c in checks:
            if not isinstance(c, Check):
                raise InputError(f"StepReport({self.name}).checks must hold factorloc.verdicts.Check, got {type(c).__name__}")
        object.__setattr__(self, "checks", checks)

    @property
    def fused(self) -> bool:
        return self.status is StepStatus.FUSED

    @property
    def rule_codes(self) -> tuple[str, ...]:
        """Why the step was not (wholly) fused, as rule codes: its failed checks' codes.

        A report without failed checks that is not fused counts under ``"<step>.<status>"`` (``"compass.skipped"``,
        ``"icp.failed"``, or ``"<step>.unreliable"`` for an estimator that gives a reason but no checks: a user's own step;
        every built-in step reports typed checks).
        """
        codes = tuple(c.code for c in self.checks if not c.passed)
        if codes or self.status is StepStatus.FUSED:
            return codes
        return (f"{self.name}.{self.status.value}",)

    def to_dict(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "status": self.status.value,
            "fused": self.fused,
            "reason": self.reason,
            "seconds": self.seconds,
            "checks": [c.to_dict() for c in self.checks],
            "estimate": None if self.estimate is None else self.estimate.to_dict(),
        }


@dataclass(frozen=True, eq=False)
class Localization:
    """The result of :func:`factorloc.localize` or :func:`factorloc.fuse`.

    ``covariance`` is 3×3 in the world frame, order (x, y, θ), m² and rad².
    A component that no fused estimate constrains is *under-determined*: it
    is listed in ``undetermined``, its variance is ``inf`` and its value in
    ``pose`` is a placeholder (the seed, or 0) that must not be used.
    ``checks`` are the gate's rules on the fused result (``gate.undetermined.position``).
    """

    pose: Pose2
    covariance: np.ndarray
    steps: tuple[StepReport, ...]
    fused_with: str
    undetermined: tuple[Component, ...] = ()
    config: Config | None = None
    checks: tuple[Check, ...] = ()

    @property
    def sigmas(self) -> np.ndarray:
        """σx (m), σy (m), σθ (rad); ``inf`` where under-determined."""
        return np.sqrt(np.diag(self.covariance))

    @property
    def determined(self) -> bool:
        """True when every component is constrained by at least one fused estimate."""
        return not self.undetermined

    def step(self, name: str) -> StepReport:
        """The report of the step called ``name``."""
        for report in self.steps:
            if report.name == name:
                return report
        raise KeyError(f"no step named {name!r}; steps are {[r.name for r in self.steps]}")

    def certainty(self, radius_m: float, angle_rad: float) -> float:
        """The patent's degree of certainty: the probability mass of the fused
        Gaussian within ``radius_m`` of the position and ``angle_rad`` of the heading.

        Computed from the cumulative distribution: the position part integrates
        the 2D Gaussian over a disc of radius ``radius_m`` (Gauss–Legendre
        quadrature, exact to ~1e-10), the heading part is ``erf(a / (σθ√2))``;
        the two are multiplied (position and heading are independent in the
        per-axis product). Under-determined components give 0.
        """
        r = nonnegative_float("certainty.radius_m", radius_m)
        a = nonnegative_float("certainty.angle_rad", angle_rad)
        return _disc_probability(self.covariance[:2, :2], r) * _interval_probability(self.covariance[2, 2], a)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready: pose, covariance (``null`` where infinite), sigmas, steps."""
        cov = [[None if not math.isfinite(v) else v for v in row] for row in self.covariance.tolist()]
        return {
            "pose": {
                "x_m": self.pose.x,
                "y_m": self.pose.y,
                "theta_rad": self.pose.theta,
                "theta_deg": math.degrees(self.pose.theta),
            },
            "covariance": cov,
            "sigmas": {
                "x_m": _finite_or_none(self.sigmas[0]),
                "y_m": _finite_or_none(self.sigmas[1]),
                "theta_rad": _finite_or_none(self.sigmas[2]),
            },
            "undetermined": [c.value for c in self.undetermined],
            "fused_with": self.fused_with,
            "steps": [s.to_dict() for s in self.steps],
        }


def _finite_or_none(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None


_GL_NODES, _GL_WEIGHTS = np.polynomial.legendre.leggauss(96)


def _interval_probability(variance: float, half_width: float) -> float:
    if not math.isfinite(variance):
        return 0.0
    if variance <= 0.0:
        return 1.0
    return math.erf(half_width / math.sqrt(2.0 * variance))


def _disc_probability(cov2: np.ndarray, radius: float) -> float:
    """P(|e| ≤ radius) for e ~ N(0, cov2) in 2D, by Gauss–Legendre quadrature.

    Along the principal axes (σ1 ≤ σ2): P = ∫ φ(u; σ2) · erf(√(r²−u²) / (σ1√2)) du over
    |u| ≤ r. With u = r·sin φ the integrand is smooth; when r > 12σ2 the range is cut
    to |u| ≤ 12σ2 (the rest weighs < 1e-31), where √(r²−u²) is smooth already.
    """
    if not np.all(np.isfinite(cov2)):
        return 0.0
    if radius == 0.0:
        return 0.0
    l1, l2 = np.linalg.eigvalsh(cov2)  # l1 <= l2
    s1, s2 = math.sqrt(max(l1, 0.0)), math.sqrt(max(l2, 0.0))
    if s2 == 0.0:
        return 1.0
    if radius <= 12.0 * s2:
        phi = 0.5 * math.pi * _GL_NODES
        u = radius * np.sin(phi)
        jac = radius * np.cos(phi) * 0.5 * math.pi
    else:
        u = 12.0 * s2 * _GL_NODES
        jac = np.full_like(u, 12.0 * s2)
    half = np.sqrt(np.maximum(radius * radius - u * u, 0.0))
    inner = np.ones_like(u) if s1 == 0.0 else np.array([math.erf(h / (s1 * math.sqrt(2.0))) for h in half])
    density = np.exp(-0.5 * (u / s2) ** 2) / (s2 * math.sqrt(2.0 * math.pi))
    return float(np.clip(np.sum(_GL_WEIGHTS * jac * density * inner), 0.0, 1.0))

"""The step protocol every estimator implements, the hypotheses it is seeded with, and the σ rule it applies."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

from factorloc.stats import largest_sigma
from factorloc.types import Component, Estimate, Query, Reference
from factorloc.verdicts import Check, Unit


@dataclass(frozen=True)
class Hypotheses:
    """The reliable estimates of the earlier steps, in hierarchy order.

    An estimator reads the seed it needs: :meth:`heading` gives the *latest*
    reliable heading (θ3, else θ2, else θ1 — the later steps are the more
    exact ones in the patent's hierarchy), :meth:`position` the latest
    reliable position.
    """

    estimates: tuple[Estimate, ...] = ()

    def heading(self) -> tuple[float, float, str] | None:
        """``(theta_rad, sigma_rad, step)`` of the latest reliable heading, or None."""
        for est in reversed(self.estimates):
            if est.reliable and est.measures(Component.THETA):
                return est.value(Component.THETA), est.sigma(Component.THETA), est.step
        return None

    def position(self) -> tuple[float, float, float, float, str] | None:
        """``(x_m, y_m, sigma_x_m, sigma_y_m, step)`` of the latest reliable position, or None."""
        for est in reversed(self.estimates):
            if est.reliable and est.measures(Component.X):
                return (
                    est.value(Component.X),
                    est.value(Component.Y),
                    est.sigma(Component.X),
                    est.sigma(Component.Y),
                    est.step,
                )
        return None

    def plus(self, estimate: Estimate) -> Hypotheses:
        """These hypotheses and ``estimate`` (only kept when reliable)."""
        return Hypotheses(self.estimates + (estimate,)) if estimate.reliable else self

    @classmethod
    def of(cls, estimates: Sequence[Estimate]) -> Hypotheses:
        return cls(tuple(e for e in estimates if e.reliable))


@runtime_checkable
class Step(Protocol):
    """One estimator in the hierarchy.

    ``prepare`` does the work that depends only on the reference (keypoints,
    KD-trees, pyramids) once; ``estimate`` runs per query and returns None
    when the query lacks this step's inputs (the step is then reported as
    skipped). Steps never call each other: the pipeline hands each the
    reliable hypotheses of the earlier ones.
    """

    name: str

    def prepare(self, reference: Reference) -> Any:
        """Reference-only precomputation (returned object is passed back to ``estimate``)."""
        ...

    def estimate(self, prepared: Any, query: Query, hypotheses: Hypotheses) -> Estimate | None:
        """This step's estimate for ``query``, or None when its inputs are absent."""
        ...


def sigma_checks(
    estimate: Estimate,
    max_sigma_position_m: float | None = None,
    max_sigma_heading_rad: float | None = None,
) -> tuple[Check, ...]:
    """The σ rule (the patent's reliability thresholds): the estimate's σ against its step's limits.

    Codes ``"<step>.sigma_position"`` (the largest standard deviation of the 2×2 world-frame position
    covariance, m: a corridor-shaped uncertainty fails on its long axis) and ``"<step>.sigma_heading"`` (rad),
    one per limit given and component measured; a σ passes when it is at most the limit.
    """
    checks = []
    if max_sigma_position_m is not None and estimate.measures(Component.X):
        sigma = largest_sigma(estimate.covariance)
        checks.append(Check.at_most(f"{estimate.step}.sigma_position", "σ position", sigma, max_sigma_position_m, Unit.METRE))
    if max_sigma_heading_rad is not None and estimate.measures(Component.THETA):
        sigma = estimate.sigma(Component.THETA)
        checks.append(Check.at_most(f"{estimate.step}.sigma_heading", "σθ", sigma, max_sigma_heading_rad, Unit.RADIAN))
    return tuple(checks)

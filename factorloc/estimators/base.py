"""The step protocol every estimator implements, the hypotheses it is seeded with, and the rules every step shares:
the σ rule (:func:`sigma_checks`) and the heading steps' seed consistency (:func:`heading_seed_check`)."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Protocol, runtime_checkable

from factorloc.geometry import wrap_angle
from factorloc.stats import largest_sigma
from factorloc.types import Component, Estimate, Query, Reference
from factorloc.verdicts import Check, Unit, render_checks


@dataclass(frozen=True)
class Hypotheses:
    """The reliable estimates of the earlier steps, in hierarchy order, and the unreliable ones as weak priors.

    An estimator reads the seed it needs: :meth:`heading` gives the *latest*
    reliable heading (θ3, else θ2, else θ1 — the later steps are the more
    exact ones in the patent's hierarchy), :meth:`position` the latest
    reliable position. ``weak`` holds the earlier steps' *unreliable* estimates
    (too broad to fuse or seed, e.g. an odometry whose σ exceeds its limit):
    :meth:`weak_pose` gives the latest one with a finite σ, which a step may
    only use to scrutinize a solution that contradicts it, never as a seed.
    """

    estimates: tuple[Estimate, ...] = ()
    weak: tuple[Estimate, ...] = ()

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

    def weak_pose(self) -> tuple[tuple[float, float, float, float, str], tuple[float, float, str] | None] | None:
        """The latest unreliable estimate that measures the position with a finite σ, as ``((x_m, y_m, sigma_x_m,
        sigma_y_m, step), (theta_rad, sigma_rad, step) or None)`` (its heading when it measures one with a finite
        σ), or None."""
        for est in reversed(self.weak):
            if not est.measures(Component.X):
                continue
            sx, sy = est.sigma(Component.X), est.sigma(Component.Y)
            if not (math.isfinite(sx) and math.isfinite(sy)):
                continue
            position = (est.value(Component.X), est.value(Component.Y), sx, sy, est.step)
            heading = None
            if est.measures(Component.THETA) and math.isfinite(est.sigma(Component.THETA)):
                heading = (est.value(Component.THETA), est.sigma(Component.THETA), est.step)
            return position, heading
        return None

    def plus(self, estimate: Estimate) -> Hypotheses:
        """These hypotheses and ``estimate``: a reliable one among the estimates, one unreliable only by the σ rule
        (:func:`too_broad`) a weak prior, any other left out."""
        if estimate.reliable:
            return Hypotheses(self.estimates + (estimate,), self.weak)
        if too_broad(estimate):
            return Hypotheses(self.estimates, self.weak + (estimate,))
        return self

    @classmethod
    def of(cls, estimates: Sequence[Estimate]) -> Hypotheses:
        return cls(tuple(e for e in estimates if e.reliable), tuple(e for e in estimates if too_broad(e)))


def too_broad(estimate: Estimate) -> bool:
    """Whether an unreliable estimate failed only the σ rule (:func:`sigma_checks`: ``<step>.sigma_position`` /
    ``<step>.sigma_heading``): a hypothesis too broad to fuse or seed, not one its own tests refuted."""
    failed = [c for c in estimate.checks if not c.passed]
    return (
        not estimate.reliable
        and bool(failed)
        and all(c.code in (f"{estimate.step}.sigma_position", f"{estimate.step}.sigma_heading") for c in failed)
    )


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


def heading_seed_check(
    step: str, theta_rad: float, sigma_rad: float, seed: tuple[float, float, str] | None, n_sigma: float
) -> Check | None:
    """The heading steps' seed-consistency rule (``"<step>.seed_consistency"``): the measured world-frame heading
    ``theta_rad`` ± ``sigma_rad`` within ``n_sigma`` of the heading seed ``(θ_rad, σ_rad, step)`` it was given
    (:meth:`Hypotheses.heading`), σ of both; None without a seed. A heading searched in a window around a seed
    and found at its far side is one the seed pulled there, not a confirmation."""
    if seed is None:
        return None
    gap = abs(float(wrap_angle(theta_rad - seed[0])))
    return Check.at_most(
        f"{step}.seed_consistency",
        f"gap to the {seed[2]} seed",
        gap,
        n_sigma * math.hypot(sigma_rad, seed[1]),
        Unit.RADIAN,
        note=f"{n_sigma:g} σ of both",
    )


def heading_not_measured(step: str, theta_rad: float, check: Check, diagnostics: dict[str, Any]) -> Estimate:
    """A heading step that stopped before measuring anything: unreliable at ``theta_rad`` (world frame; the seed's
    heading or the reference's) with σ = π, the failed ``check`` that stopped it as its verdict and reason."""
    return Estimate.heading(
        step, theta_rad, math.pi, reliable=False, reason=render_checks((check,)), diagnostics=diagnostics, checks=(check,)
    )

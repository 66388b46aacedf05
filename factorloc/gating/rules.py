"""The gate's small rules on a fused result and on seeds: each returns :class:`~factorloc.verdicts.Check` records.

- :func:`position_determined` — the "undetermined" rule on a fused position covariance;
- :func:`seed_misfit` / :func:`seed_audit` — the seed audit: a later step whose own data refute the seed
  it was given contradicts that seed (a kidnapped robot's odometry cannot know it was moved; without the
  audit it is fused as reliable while metres wrong). The step decides and says so in typed evidence
  (``Estimate.seed``, :class:`~factorloc.verdicts.SeedEvidence`); the audit only reads it.

The σ rule the estimators apply to themselves is :func:`factorloc.estimators.base.sigma_checks`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from factorloc.stats import sym2_eigenvalues
from factorloc.types import Component, Estimate
from factorloc.verdicts import Check, Unit, render_checks

__all__ = [
    "POSITION_DETERMINED",
    "SEED_AUDIT",
    "SEED_AUDIT_WINDOWED",
    "fixes_full_pose",
    "measures_position",
    "position_determined",
    "seed_audit",
    "seed_misfit",
]

#: Rule codes of this module.
POSITION_DETERMINED = "gate.undetermined.position"
SEED_AUDIT = "gate.seed_audit"
SEED_AUDIT_WINDOWED = "gate.seed_audit.windowed"


def position_determined(covariance: np.ndarray, limit_sigma_m: float) -> Check:
    """Whether a fused position covariance (world frame, m²) constrains every direction.

    Fails when the largest eigen-σ of its 2×2 position block exceeds ``limit_sigma_m``
    (``GatingConfig.undetermined_sigma_m``: half the σ an estimate states along a direction its data do not
    constrain): only estimates that say "unknown" along that direction were fused. Non-finite covariances fail.
    """
    a, b, c = float(covariance[0, 0]), float(covariance[0, 1]), float(covariance[1, 1])
    if math.isfinite(a) and math.isfinite(b) and math.isfinite(c):
        sigma = math.sqrt(max(sym2_eigenvalues(a, b, c)[1], 0.0))
    else:
        sigma = math.inf
    return Check.at_most(POSITION_DETERMINED, "largest σ of the fused position", sigma, limit_sigma_m, Unit.METRE)


def measures_position(estimate: Estimate, limit_sigma_m: float) -> bool:
    """Whether ``estimate`` measures a position that :func:`position_determined` accepts at ``limit_sigma_m``: not
    heading-only, and not "unknown" along some direction (an ICP position along a corridor)."""
    return estimate.measures(Component.X) and position_determined(estimate.covariance, limit_sigma_m).passed


def fixes_full_pose(estimate: Estimate, limit_sigma_m: float) -> bool:
    """Whether ``estimate`` is reliable, measures the full pose (x, y, θ) and :func:`measures_position`: what a loop
    closure or a verified place needs."""
    return estimate.reliable and estimate.kind == "full" and measures_position(estimate, limit_sigma_m)


def seed_misfit(estimate: Estimate) -> tuple[Check, ...]:
    """The failed seed checks of ``estimate``: why its own data contradict the seed it was given (empty if none).

    The step reports them in ``estimate.seed`` (:class:`~factorloc.verdicts.SeedEvidence`); e.g. the ICP step,
    when its *seeded* alignment puts more than ``max_violation`` of either scan into space the other sensor
    saw empty, when its seeded alignment failed and its global search found nothing reliable, or when it
    converged far from its seed to a fit of its own. An estimate that reliably measures a position of its
    own contradicts nothing here (the consistency gate weighs it against the seed); a reliable heading-only
    one may still report a misfit.
    """
    if estimate.reliable and estimate.measures(Component.X):
        return ()
    evidence = estimate.seed
    if evidence is None:
        return ()
    return tuple(c for c in evidence.checks if not c.passed)


def seed_audit(estimates: Sequence[Estimate], drop_seeded: bool = True) -> dict[int, Check]:
    """The reliable estimates that a later step's data contradict as seeds, each with the failed check.

    ``estimates`` are one query's estimates in hierarchy order (reliable or not). For each estimate with a
    :func:`seed_misfit`, its *position seed* — the latest reliable position-measuring estimate before it, the
    one :meth:`factorloc.estimators.base.Hypotheses.position` handed it — is contradicted unless a reliable
    estimate from that step on measures the position (then the consistency gate decides between them). The
    whole seed estimate is rejected, heading included: a robot carried away was also turned. With
    ``drop_seeded``, the reliable heading-only estimates between the seed and the step that contradicts it
    that searched only a window around the seed (``SeedEvidence.windowed``) are rejected too: they verified
    that window and nothing outside it.

    Returns
    -------
    dict
        Index in ``estimates`` → the failed :class:`~factorloc.verdicts.Check` (``gate.seed_audit`` for the
        seed, ``gate.seed_audit.windowed`` for the estimates searched around it).
    """
    out: dict[int, Check] = {}
    for j, e in enumerate(estimates):
        misfit = seed_misfit(e)
        if not misfit:
            continue
        if any(later.reliable and later.measures(Component.X) for later in estimates[j:]):
            continue
        seed = next((i for i in range(j - 1, -1, -1) if estimates[i].reliable and estimates[i].measures(Component.X)), None)
        if seed is None or seed in out:
            continue
        why = render_checks(misfit)
        out[seed] = Check.flag(
            SEED_AUDIT, f"seed confirmed by {e.step}", False, note=why, failure=f"seed contradicted by {e.step}"
        )
        if drop_seeded:
            for k in range(seed + 1, j):
                e_k = estimates[k]
                windowed = e_k.seed is not None and e_k.seed.windowed
                if e_k.reliable and not e_k.measures(Component.X) and windowed and k not in out:
                    out[k] = Check.flag(
                        SEED_AUDIT_WINDOWED,
                        f"the {estimates[seed].step} seed it searched around confirmed by {e.step}",
                        False,
                        note=why,
                        failure=f"searched around the {estimates[seed].step} seed, contradicted by {e.step}",
                    )
    return out

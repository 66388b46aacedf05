"""The reliability rules of the ICP step: each a small pure function of a solution's :class:`Evidence` and the
configuration that returns a typed :class:`~factorloc.verdicts.Check` (``icp.<rule>``), or None where the rule
does not apply to that solution.

:data:`RULES` lists them in the order they apply, in stages: a stage is evaluated only on a solution that
passed the stages before it. A solution is reliable when every check passes; the reason a user reads is
rendered from the checks (:func:`~factorloc.verdicts.render_checks`). The checks of the *seed* (what the scan
says about the hypothesis that seeded the alignment, read by the pipeline's seed audit) are
:func:`seed_checks`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from factorloc.estimators.icp.config import IcpConfig
from factorloc.estimators.icp.covariance import weak
from factorloc.verdicts import ROUNDING_TOLERANCE, Check, Unit

__all__ = [
    "RULES",
    "Contest",
    "Evidence",
    "Rivalry",
    "SeedFit",
    "across_walls",
    "judge",
    "passed",
    "seed_checks",
]


@dataclass(frozen=True)
class Rivalry:
    """A global solution found without a position seed, against its best distinct rival.

    ``ratio`` is the rival's score over this one's (inf when this score is not positive; 0 without a rival);
    ``overlap`` / ``rival_overlap`` their overlap fitness (the fitness over what both sensors could see; 0
    without a rival).
    """

    ratio: float
    overlap: float
    rival_overlap: float


@dataclass(frozen=True)
class Contest:
    """A global solution among the others: its score, the best distinct rival's, and the position seed it lies
    outside the region of (``overturns``: that seed's step, None when inside or without one) with the seeded
    alignment's (fitness, violation). ``weak``: what it overturns is a weak prior (an estimate too broad to
    seed, ``global_init.weak_prior``), not a reliable seed."""

    score: float
    rival_score: float
    overturns: str | None = None
    seeded_fit: tuple[float, float] = (math.nan, math.nan)
    weak: bool = False

    @property
    def overturned(self) -> str:
        """What it overturns, for people: ``"<step> seed"`` or ``"<step> prior"``."""
        return f"{self.overturns} {'prior' if self.weak else 'seed'}"


@dataclass(frozen=True)
class SeedFit:
    """A seeded solution against its position seed: the squared Mahalanobis distance (seed and ICP covariances
    summed), its χ² limit, and whether the test applies (the geometry lets ICP slide, or it jumped)."""

    step: str
    mahalanobis2: float
    limit: float
    applies: bool


@dataclass(frozen=True)
class Evidence:
    """What the rules read about one ICP solution (metres, radians).

    ``violation`` is NaN while the free-space test has not been run (it is the costliest; the rules that need
    it then treat it as 0, the free-space rule does not apply). ``rivalry`` only for global solutions without
    a position seed, ``contest`` for every global solution, ``seed_fit`` for a seeded one.
    """

    fitness: float
    strength: float
    violation: float
    rivalry: Rivalry | None = None
    contest: Contest | None = None
    seed_fit: SeedFit | None = None

    def score(self, config: IcpConfig) -> float:
        """``fitness − violation_weight · violation`` (the violation taken as 0 while not measured)."""
        v = 0.0 if math.isnan(self.violation) else self.violation
        return self.fitness - config.reliability.violation_weight * v


Rule = Callable[[Evidence, IcpConfig], "Check | None"]


def _rule(code: str) -> Callable[[Rule], Rule]:
    """Name a rule by the code of the checks it returns (``config.ablate`` leaves it out by that code)."""

    def mark(fn: Rule) -> Rule:
        fn.code = code  # type: ignore[attr-defined]
        return fn

    return mark


def _waiver(code: str, config: IcpConfig) -> bool:
    """Whether the waiver ``code`` may apply (not left out by ``config.ablate``)."""
    return code not in config.ablate


# --------------------------------------------------------------------------
# waivers of a global solution without a position seed (a loop closure, a robot without odometry)
# --------------------------------------------------------------------------
def _dominates_degenerate(ev: Evidence, config: IcpConfig) -> bool:
    """Degenerate, but explaining nearly the whole scan and dominating every distinct rival."""
    g = config.global_init
    r = ev.rivalry
    return (
        _waiver("icp.waiver.dominant_degenerate", config)
        and r is not None
        and r.ratio < g.degenerate_ratio
        and ev.score(config) >= g.degenerate_min_score
    )


def _low_but_clear(ev: Evidence, config: IcpConfig) -> bool:
    """Scoring below ``min_score`` but at least ``low_min_score``, not degenerate, every rival far below."""
    g = config.global_init
    r = ev.rivalry
    return (
        _waiver("icp.waiver.low_but_clear", config)
        and r is not None
        and not weak(ev.strength, config.reliability.min_constraint)
        and r.ratio < g.low_score_ratio
        and ev.score(config) >= g.low_min_score
    )


def _overlap_supported(ev: Evidence, config: IcpConfig) -> bool:
    """Little shared, but what is shared is explained, and no rival explains it as well."""
    g = config.global_init
    r = ev.rivalry
    return (
        _waiver("icp.waiver.overlap_supported", config)
        and r is not None
        and not weak(ev.strength, config.reliability.min_constraint)
        and r.overlap >= g.overlap_min_fitness
        and r.ratio < g.overlap_rival_ratio
        and ev.score(config) >= g.overlap_min_score
        and (r.ratio < g.low_score_ratio or r.rival_overlap <= r.overlap - g.overlap_rival_margin)
    )


# --------------------------------------------------------------------------
# stage 1: every solution
# --------------------------------------------------------------------------
@_rule("icp.constraint")
def constraint(ev: Evidence, config: IcpConfig) -> Check:
    """The scan constrains every direction: the smallest eigenvalue of the normal scatter reaches ``min_constraint``."""
    c = Check.at_least(
        "icp.constraint",
        "constraint strength",
        ev.strength,
        config.reliability.min_constraint,
        tolerance=ROUNDING_TOLERANCE,
        note="" if not weak(ev.strength, config.reliability.min_constraint) else "degenerate geometry: one wall or a corridor",
    )
    if not c.passed and _dominates_degenerate(ev, config):
        return c.waived("degenerate geometry, but a global solution that dominates its rivals")
    return c


@_rule("icp.free_space")
def free_space(ev: Evidence, config: IcpConfig) -> Check | None:
    """At most ``max_violation`` of either scan lies in space the other's sensor saw empty."""
    if math.isnan(ev.violation):
        return None
    return Check.at_most(
        "icp.free_space", "share in seen-free space", ev.violation, config.reliability.max_violation, Unit.FRACTION
    )


@_rule("icp.score")
def score(ev: Evidence, config: IcpConfig) -> Check:
    """The score ``fitness − violation_weight · violation`` reaches ``min_score``."""
    c = Check.at_least("icp.score", "score (fitness − violation)", ev.score(config), config.reliability.min_score)
    if not c.passed and _low_but_clear(ev, config):
        return c.waived("a global solution without rivals near it")
    if not c.passed and _overlap_supported(ev, config):
        return c.waived("a global solution that explains what both sensors could see")
    return c


@_rule("icp.global.overlap")
def overlap_ambiguity(ev: Evidence, config: IcpConfig) -> Check | None:
    """A global solution without a position seed that has a comparable rival explains its overlap well."""
    g = config.global_init
    r = ev.rivalry
    if r is None or not r.ratio >= g.ambiguity_overlap_ratio:
        return None
    return Check.at_least(
        "icp.global.overlap",
        "overlap fitness",
        r.overlap,
        g.overlap_min_fitness,
        note=f"ambiguous: a distinct solution scores {r.ratio:.2f}×",
    )


# --------------------------------------------------------------------------
# stage 2: a global solution among the others
# --------------------------------------------------------------------------
@_rule("icp.global.seed_refuted")
def seed_refuted(ev: Evidence, config: IcpConfig) -> Check | None:
    """A global solution outside the region of a reliable position seed (or of a weak prior,
    ``global_init.weak_prior``) overturns it only when the seed's own alignment put more than ``max_violation`` of
    the scan into seen-free space (the scan refutes it)."""
    c = ev.contest
    if c is None or c.overturns is None or (c.weak and "icp.global.seed_refuted.weak" in config.ablate):
        return None
    s_fit, s_v = c.seeded_fit
    consistent = s_v <= config.reliability.max_violation
    return Check.flag(
        "icp.global.seed_refuted",
        f"free to overturn the {c.overturned}",
        not consistent,
        note=f"it contradicts the {c.overturned}, whose own alignment is free-space consistent "
        f"(fitness {s_fit:.2f}, {100 * s_v:.0f} % in seen-free space)"
        if consistent
        else "",
    )


@_rule("icp.global.ambiguity")
def ambiguity(ev: Evidence, config: IcpConfig) -> Check | None:
    """No distinct rival scores ``ambiguity_ratio`` × the best (``seed_contradiction_ambiguity_ratio`` for a
    solution that overturns a position seed)."""
    c = ev.contest
    if c is None:
        return None
    g = config.global_init
    strict = c.overturns is not None and "icp.global.ambiguity.overturn" not in config.ablate
    limit = min(g.ambiguity_ratio, g.seed_contradiction_ambiguity_ratio) if strict else g.ambiguity_ratio
    ambiguous = c.rival_score >= limit * c.score
    return Check.flag(
        "icp.global.ambiguity",
        "unambiguous",
        not ambiguous,
        note=f"a distinct solution scores {c.rival_score:.2f} vs {c.score:.2f} (limit {limit:.2f}×)" if ambiguous else "",
    )


# --------------------------------------------------------------------------
# stage 3: a seeded solution that passed its own tests
# --------------------------------------------------------------------------
@_rule("icp.seed.consistency")
def seed_consistency(ev: Evidence, config: IcpConfig) -> Check | None:
    """A seeded solution stays within its position seed's region where the geometry lets ICP slide or it jumped."""
    s = ev.seed_fit
    if s is None or not s.applies:
        return None
    return Check.at_most(
        "icp.seed.consistency",
        f"Mahalanobis² to the {s.step} seed",
        s.mahalanobis2,
        s.limit,
        Unit.SQUARED,
        note="" if s.mahalanobis2 <= s.limit else f"inconsistent with the {s.step} seed: ICP slid or jumped",
    )


#: The rules in the order they apply, in stages (a stage runs only on a solution that passed the earlier ones).
RULES: tuple[tuple[Rule, ...], ...] = (
    (constraint, free_space, score, overlap_ambiguity),
    (seed_refuted, ambiguity),
    (seed_consistency,),
)

#: The rules a solution that is unknown along the walls (:func:`across_walls`) is not judged by.
POSITION_RULES = frozenset({"icp.constraint"})


def passed(checks: Sequence[Check]) -> bool:
    """Whether every check passed."""
    for c in checks:
        if not c.passed:
            return False
    return True


def judge(ev: Evidence, config: IcpConfig, after: tuple[Check, ...] | None = None) -> tuple[Check, ...]:
    """The checks of :data:`RULES` on one solution, stage by stage (later stages only once the earlier pass).

    ``after``: the checks of the stages that apply to every solution, already judged on this evidence; only the
    later stages are evaluated (a seeded solution's seed-consistency stage, once it is known to be the result).
    """
    out: list[Check] = [] if after is None else list(after)
    if not passed(out):
        return tuple(out)
    ablate = config.ablate
    for stage in RULES if after is None else RULES[2:]:
        for rule in stage:
            if rule.code in ablate:  # type: ignore[attr-defined]
                continue
            c = rule(ev, config)
            if c is not None:
                out.append(c)
        if not passed(out):
            break
    return tuple(out)


def across_walls(
    ev: Evidence,
    checks: tuple[Check, ...],
    config: IcpConfig,
    heading_error_rad: float,
    heading_limit_rad: float,
    sigma_across_m: float,
) -> tuple[Check, ...] | None:
    """The checks of a seeded solution that only the position-degeneracy rules reject, as a solution unknown along
    the walls, or None when it fails other rules too.

    The first stage's checks with :data:`POSITION_RULES` waived and the score judged against
    ``seed.across_walls_min_score``; then its heading must agree with the heading seed (``heading_error_rad`` ≤
    ``heading_limit_rad``, 3σ of both) and its σ across the walls (``sigma_across_m``) reach
    ``max_sigma_position_m`` at most.
    """
    r, s = config.reliability, config.seed
    out: list[Check] = []
    for c in checks:
        if c.code in POSITION_RULES:
            c = c if c.passed else c.waived("the position along the walls is left to the other steps")
        elif c.code == "icp.score":
            c = Check.at_least(c.code, c.label, c.value, min(r.min_score, s.across_walls_min_score), note="across the walls")
        out.append(c)
    if not passed(tuple(out)):
        return None
    out.append(
        Check.at_most(
            "icp.across_walls.heading", "heading error to the heading seed", heading_error_rad, heading_limit_rad, Unit.RADIAN
        )
    )
    out.append(Check.at_most("icp.across_walls.sigma", "σ across the walls", sigma_across_m, r.max_sigma_position_m, Unit.METRE))
    return tuple(out)


def seed_checks(
    seeded_fit: tuple[float, float], used_global: bool, reliable: bool, n_points: int, config: IcpConfig
) -> tuple[Check, ...]:
    """The checks of a seeded ICP's position seed against the scan (one failed: the scan refutes the seed, or at
    least does not confirm it); what the pipeline's seed audit reads (:class:`~factorloc.verdicts.SeedEvidence`).

    ``icp.seed.free_space``: the seeded alignment put at most ``max_violation`` of a scan into space the other
    sensor saw empty. ``icp.seed.fits_near``: the seeded alignment did not fail while the global search found
    nothing reliable either (the scan fits nowhere near the seed). A third, ``icp.seed.stays_near``, is added by
    :func:`~factorloc.estimators.icp.estimate` when the seeded alignment converged far from its seed to a fit
    that passes ICP's own criteria.
    """
    s_fit, s_v = seeded_fit
    checks: list[Check] = []
    if not math.isnan(s_v) and "icp.seed.free_space" not in config.ablate:
        checks.append(
            Check.at_most(
                "icp.seed.free_space",
                "share of the scan the seeded alignment puts in space the reference saw empty",
                s_v,
                config.reliability.max_violation,
                Unit.FRACTION,
            )
        )
    if "icp.seed.fits_near" in config.ablate:
        return tuple(checks)
    checks.append(
        Check.flag(
            "icp.seed.fits_near",
            "the scan fits near the seed",
            not (used_global and not reliable),
            note=f"{n_points} query points; seeded alignment fitness {s_fit:.2f}; global search unreliable"
            if used_global and not reliable
            else "",
        )
    )
    return tuple(checks)

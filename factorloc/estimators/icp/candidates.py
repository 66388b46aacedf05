"""The candidate solutions of the ICP step: the seeded alignment, and the global initialization's.

* :func:`seeded_attempt` — point-to-line ICP (:func:`~factorloc.registration.icp2d.align`) from the latest
  reliable position and heading, with a first correspondence gate from the seed's σ;
* :func:`global_attempts` — the correlative search (:func:`~factorloc.registration.global_search.search`,
  Olson, ICRA 2009) over a window bounded by the seeds (then, when nothing reliable lies inside, the whole
  window), whose best candidates ICP refines; each window's best solution is judged against its distinct
  rivals (the other refined candidates and the solutions found before).

Every solution carries the :class:`~factorloc.estimators.icp.rules.Evidence` the rules read and the checks
they returned.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from functools import cached_property, lru_cache

import numpy as np
from scipy.stats import chi2

from factorloc.estimators.icp.config import IcpConfig
from factorloc.estimators.icp.covariance import (
    constraint_strength,
    covariance,
    weak,
)
from factorloc.estimators.icp.reference import IcpReference
from factorloc.estimators.icp.rules import Contest, Evidence, Rivalry, SeedFit, judge, passed
from factorloc.geometry import Pose2
from factorloc.registration.global_search import search
from factorloc.registration.icp2d import IcpResult, align
from factorloc.registration.kernels import RobustKernel, kernel_from_name
from factorloc.registration.scan2d import (
    alignment_violation,
    median_range_m,
    overlap_fitness,
    polar_profile,
    profile_and_violation,
)
from factorloc.verdicts import Check

__all__ = ["QueryScan", "Seeds", "Solution", "evidence", "global_attempts", "near_seed", "seed_fit", "seeded_attempt"]


def _strength(result: IcpResult, config: IcpConfig) -> float:
    """The constraint strength of ``result`` as the configuration measures it (``reliability.debias_constraint``)."""
    return constraint_strength(result, debias=config.reliability.debias_constraint)


@dataclass(frozen=True)
class Seeds:
    """The reliable hypotheses that seed the step: ``position`` ``(x_m, y_m, σx_m, σy_m, step)`` and ``heading``
    ``(θ_rad, σ_rad, step)`` in the world frame (see :class:`~factorloc.estimators.base.Hypotheses`); ``weak``:
    without a reliable position, the weak prior a global solution is held against (``global_init.weak_prior``),
    as seeds of the same form (never a seed of the step's result)."""

    position: tuple[float, float, float, float, str] | None
    heading: tuple[float, float, str] | None
    weak: Seeds | None = None

    @property
    def full(self) -> bool:
        """Both a position and a heading: a seeded alignment runs."""
        return self.position is not None and self.heading is not None


class QueryScan:
    """The query points (N×2, query frame) and their free-space profile, computed once on first use."""

    def __init__(self, points_m: np.ndarray, config: IcpConfig) -> None:
        self.points_m = points_m
        self.gap_free_m = config.alignment.gap_free_m
        self._profile: np.ndarray | None = None

    @property
    def profile(self) -> np.ndarray:
        if self._profile is None:
            self._profile = polar_profile(self.points_m, gap_free_m=self.gap_free_m)
        return self._profile

    def violation(self, prepared: IcpReference, T: Pose2) -> float:
        """Free-space violation of the alignment ``T`` (query in reference frame), the larger of the two
        directions (:func:`~factorloc.registration.scan2d.alignment_violation`; with the profile in one call,
        :func:`~factorloc.registration.scan2d.profile_and_violation`, when it is not known yet).

        Only for an alignment :func:`~factorloc.registration.icp2d.align` returned: the query points passed its
        checks then (and the reference's :func:`~factorloc.registration.icp2d.prepare_target`'s), so they are not
        checked again."""
        if self._profile is None:
            self._profile, v = profile_and_violation(
                prepared.profile, prepared.points_m, self.points_m, T, self.gap_free_m, validate=False
            )
            return v
        return alignment_violation(prepared.profile, prepared.points_m, self._profile, self.points_m, T, validate=False)

    def overlap(self, prepared: IcpReference, T: Pose2, config: IcpConfig) -> tuple[float, int]:
        """Fitness over the points each scan's sensor could have seen, the smaller of the two directions, and that
        count (:func:`~factorloc.registration.scan2d.overlap_fitness`)."""
        return overlap_fitness(
            prepared.profile, prepared.points_m, self.profile, self.points_m, T, config.alignment.icp.fitness_distance_m
        )


@dataclass(frozen=True, eq=False)
class Solution:
    """One ICP solution: the alignment (query in the reference frame), its covariance (reference frame), the
    evidence the rules read, their checks, and where it came from (``origin``: ``"seeded by a/b"``, ``"global
    initialization"``, ``"global initialization, widened"``). ``n_candidates`` and ``overlap_points`` are
    figures of a global solution."""

    result: IcpResult
    covariance: np.ndarray
    evidence: Evidence
    checks: tuple[Check, ...]
    origin: str
    used_global: bool = False
    n_candidates: int = 0

    @cached_property
    def reliable(self) -> bool:
        """Whether every check passed."""
        return passed(self.checks)

    @property
    def T_reference_query(self) -> Pose2:
        return self.result.T_target_source

    @property
    def violation(self) -> float:
        return self.evidence.violation

    @property
    def strength(self) -> float:
        return self.evidence.strength


def evidence(
    result: IcpResult,
    cov: np.ndarray,
    strength: float,
    violation: float,
    *,
    rivalry: Rivalry | None = None,
    contest: Contest | None = None,
    seed: SeedFit | None = None,
) -> Evidence:
    """The :class:`~factorloc.estimators.icp.rules.Evidence` of an ICP result (``cov``: its covariance, kept for the
    callers' symmetry; no rule reads it)."""
    return Evidence(
        fitness=result.fitness,
        strength=strength,
        violation=violation,
        rivalry=rivalry,
        contest=contest,
        seed_fit=seed,
    )


@lru_cache(maxsize=16)
def _kernel(name: str, scale: float) -> RobustKernel:
    return kernel_from_name(name, scale)


def kernel(config: IcpConfig) -> RobustKernel:
    """The configured robust kernel (cached)."""
    return _kernel(config.alignment.kernel, config.alignment.kernel_scale_m)


@lru_cache(maxsize=16)
def chi2_2dof(probability: float) -> float:
    """The χ² quantile of ``probability`` with 2 degrees of freedom."""
    return float(chi2.ppf(probability, 2))


def mahalanobis2(e: np.ndarray, s: np.ndarray) -> float:
    """``eᵀ S⁻¹ e`` of a 2-vector and a 2×2 covariance, in closed form."""
    s00, s01, s11 = float(s[0, 0]), float(s[0, 1]), float(s[1, 1])
    ex, ey = float(e[0]), float(e[1])
    return (s11 * ex * ex - 2.0 * s01 * ex * ey + s00 * ey * ey) / (s00 * s11 - s01 * s01)


def seed_distance2(prepared: IcpReference, T_reference_query: Pose2, cov: np.ndarray, seeds: Seeds) -> tuple[float, float]:
    """Squared Mahalanobis distance of a solution's position from the position seed (ICP and seed covariances
    summed, world frame), and the distance (m). Plain floats: 2×2 numpy calls cost more than the arithmetic."""
    x, y, sx, sy, _ = seeds.position
    T_wr = prepared.T_world_reference
    c, s = math.cos(T_wr.theta), math.sin(T_wr.theta)
    t = T_reference_query
    ex = T_wr.x + c * t.x - s * t.y - x
    ey = T_wr.y + s * t.x + c * t.y - y
    a, b, d = float(cov[0, 0]), 0.5 * (float(cov[0, 1]) + float(cov[1, 0])), float(cov[1, 1])
    s00 = c * c * a - 2.0 * c * s * b + s * s * d + sx * sx
    s01 = c * s * (a - d) + (c * c - s * s) * b
    s11 = s * s * a + 2.0 * c * s * b + c * c * d + sy * sy
    d2 = (s11 * ex * ex - 2.0 * s01 * ex * ey + s00 * ey * ey) / (s00 * s11 - s01 * s01)
    return d2, math.hypot(ex, ey)


def seed_fit(prepared: IcpReference, sol: Solution, seeds: Seeds, config: IcpConfig) -> SeedFit:
    """A seeded solution against its position seed (see :class:`~factorloc.estimators.icp.rules.SeedFit`)."""
    pos = seeds.position
    d2, dist = seed_distance2(prepared, sol.T_reference_query, sol.covariance, seeds)
    s = config.seed
    jump = dist > s.jump_margin_m + 3.0 * max(pos[2], pos[3])
    return SeedFit(pos[4], d2, chi2_2dof(s.consistency_probability), jump or weak(sol.strength, s.check_max_constraint))


def near_seed(prepared: IcpReference, sol: Solution, seeds: Seeds, config: IcpConfig) -> Solution:
    """A seeded solution that passed its own tests, with its :func:`seed_fit` and the rules' last stage judged
    (:func:`~factorloc.estimators.icp.rules.judge` after its checks): once no other solution replaces it."""
    ev = sol.evidence
    ev = Evidence(ev.fitness, ev.strength, ev.violation, ev.rivalry, ev.contest, seed_fit(prepared, sol, seeds, config))
    return Solution(
        sol.result, sol.covariance, ev, judge(ev, config, after=sol.checks), sol.origin, sol.used_global, sol.n_candidates
    )


def _seeded_gate(config: IcpConfig, points: np.ndarray, seeds: Seeds) -> float:
    """The first correspondence gate of a seeded ICP: the seed's 3σ (position and heading at the median range)."""
    pos, head = seeds.position, seeds.heading
    rho = median_range_m(points)
    sigma = math.hypot(max(pos[2], pos[3]), head[1] * rho)
    p = config.alignment.icp
    return min(p.max_correspondence_m, max(2.0 * p.min_correspondence_m, 3.0 * sigma + config.alignment.seed_gate_margin_m))


def seeded_attempt(prepared: IcpReference, query: QueryScan, seeds: Seeds, config: IcpConfig) -> Solution:
    """ICP from the seeds, its free-space violation, judged by the rules (the stages that apply to every solution;
    the seed-consistency stage is the caller's, once no other solution replaces this one)."""
    pos, head = seeds.position, seeds.heading
    pts = query.points_m
    T_seed = prepared.T_reference_world * Pose2(pos[0], pos[1], head[0])
    gate = _seeded_gate(config, pts, seeds)
    result = align(prepared.target, pts, T_seed, config.alignment.icp, kernel(config), max_correspondence_m=gate)
    cov = covariance(result, config)
    ev = evidence(
        result,
        cov,
        _strength(result, config),
        query.violation(prepared, result.T_target_source),
    )
    return Solution(result, cov, ev, judge(ev, config), f"seeded by {pos[4]}/{head[2]}")


def with_violation(sol: Solution, prepared: IcpReference, query: QueryScan) -> Solution:
    """``sol`` with its free-space violation measured (its checks kept)."""
    if not math.isnan(sol.violation):
        return sol
    return replace(sol, evidence=replace(sol.evidence, violation=query.violation(prepared, sol.T_reference_query)))


def _distinct(a: Pose2, b: Pose2, config: IcpConfig) -> bool:
    d = a.between(b)
    g = config.global_init
    return math.hypot(d.x, d.y) > g.distinct_m or abs(d.theta) > g.distinct_rad


@dataclass(frozen=True)
class _Found:
    """A refined global candidate: its score, free-space violation and ICP result."""

    score: float
    violation: float
    result: IcpResult


def _search_window(
    prepared: IcpReference,
    query: QueryScan,
    config: IcpConfig,
    center: tuple[float, float],
    heading: float,
    half: float,
    radius: float,
) -> tuple[list[_Found], int]:
    """The correlative search in one window and the ICP refinement of its best candidates, best first (score,
    then RMSE), and the number of candidates."""
    g = config.global_init
    params = g.search if radius >= g.search.radius_m else replace(g.search, radius_m=radius)
    cands = search(
        prepared.points_m,
        query.points_m,
        params,
        center_m=center,
        heading_rad=heading,
        heading_half_width_rad=half,
        fields=prepared.fields,
    )
    found = []
    for c in cands[: g.refine]:
        r = align(prepared.target, query.points_m, c.T_reference_query, config.alignment.global_icp, kernel(config))
        v = query.violation(prepared, r.T_target_source)
        found.append(_Found(r.fitness - config.reliability.violation_weight * v, v, r))
    found.sort(key=lambda f: (-f.score, f.result.rmse_m))
    return found, len(cands)


def _windows(
    prepared: IcpReference, seeds: Seeds, config: IcpConfig, *, weak: bool = False
) -> list[tuple[tuple[float, float], float, float, float, str]]:
    """The search windows ``(center, heading, half-width, radius, origin)`` in the reference frame: the one the
    seeds bound, then (``widen``) the whole one around the position seed. ``weak``: ``seeds`` is a weak prior, and
    the second window is the one searched without any prior (around the reference, every heading): a prior too
    broad to seed may lie far from where the scans overlap."""
    g = config.global_init
    full = g.search.radius_m
    pos, head = seeds.position, seeds.heading
    T_wr = prepared.T_world_reference
    if pos is not None:
        center = tuple(prepared.T_reference_world.transform_points(np.array([[pos[0], pos[1]]]))[0])
        radius = min(full, config.seed.radius_margin_m + 3.0 * max(pos[2], pos[3]))
    else:
        center, radius = (0.0, 0.0), full
    if head is not None:
        heading = head[0] - T_wr.theta
        half = min(math.pi, max(config.seed.heading_window_rad, 3.0 * head[1]))
    else:
        heading, half = 0.0, math.pi
    out = [(center, heading, half, radius, "global initialization")]
    if weak:
        out.append(((0.0, 0.0), 0.0, math.pi, full, "global initialization, widened"))
    elif g.widen and (radius < full or half < math.pi):
        out.append((center, 0.0, math.pi, full, "global initialization, widened"))
    return out


def global_attempts(
    prepared: IcpReference, query: QueryScan, seeds: Seeds, config: IcpConfig, seeded: Solution | None
) -> tuple[Solution | None, Solution | None]:
    """The global initialization, window after window until a reliable solution: ``(best, seeded)``.

    ``best`` is the first reliable window solution, else the best-fitting one or ``seeded`` when it fits better;
    ``seeded`` comes back with its free-space violation measured. A window's solution is judged against its
    distinct rivals: the window's other refined candidates and the solutions found before (the seeded one, the
    earlier window's), so that a solution elsewhere must explain the scan clearly better than the seed does.

    Without a reliable position but with a weak prior (``seeds.weak``, ``global_init.weak_prior``), the first
    window is the one the weak prior bounds, and its best solution stands for the prior's own alignment (never the
    result): the whole window's solution is its rival, and outside the prior's region contested with it as with a
    seeded alignment.
    """
    r = config.reliability
    g = config.global_init
    earlier: list[tuple[float, Pose2, float]] = []  # (score, pose, constraint strength)
    best = seeded
    query.profile  # noqa: B018 - computed first: the search and every violation below use it
    if seeded is not None:
        seeded = with_violation(seeded, prepared, query)
        best = seeded
        earlier.append((seeded.evidence.score(config), seeded.T_reference_query, seeded.strength))
    on_prior = seeds.position is None and seeds.weak is not None
    prior = seeds.weak if on_prior else seeds
    prior_fit = (seeded.result.fitness, seeded.violation) if seeded is not None else (math.nan, math.nan)
    for i, (center, heading, half, radius, origin) in enumerate(_windows(prepared, prior, config, weak=on_prior)):
        found, n = _search_window(prepared, query, config, center, heading, half, radius)
        if not found:
            continue
        top = found[0]
        if on_prior and i == 0:
            # the best solution in the weak prior's window stands for the prior's alignment: a rival of the later
            # window's and what a solution outside the prior's region contests, never the result (the window hides
            # the rivals outside it, which a prior too broad to seed must not hide)
            prior_fit = (top.result.fitness, top.violation)
            earlier.append(
                (
                    top.score,
                    top.result.T_target_source,
                    _strength(top.result, config),
                )
            )
            continue
        g_res, T = top.result, top.result.T_target_source
        rivals = [
            (f.score, f.result.T_target_source, _strength(f.result, config))
            for f in found[1:]
            if _distinct(f.result.T_target_source, T, config)
        ]
        rivals += [e for e in earlier if _distinct(e[1], T, config)]
        strength = _strength(g_res, config)
        earlier.append((top.score, T, strength))
        cov = covariance(g_res, config)
        rival, rival_T = max(((sc, P) for sc, P, _ in rivals), key=lambda x: x[0], default=(0.0, None))
        rivalry = None
        if seeds.position is None:
            # without a position seed: how well the solution, and its best rival, explain what both sensors could
            # see; a well-constrained solution that explains it is not made ambiguous by degenerate rivals
            ov = query.overlap(prepared, T, config)[0]
            if g.ignore_degenerate_rivals and not weak(strength, r.min_constraint) and ov >= g.overlap_min_fitness:
                rival, rival_T = max(
                    ((sc, P) for sc, P, st in rivals if not weak(st, r.min_constraint)), key=lambda x: x[0], default=(0.0, None)
                )
            rival_ov = 0.0 if rival_T is None else query.overlap(prepared, rival_T, config)[0]
            rivalry = Rivalry(rival / top.score if top.score > 0.0 else math.inf, ov, rival_ov)
        overturns = None
        if prior.position is not None and seed_distance2(prepared, T, cov, prior)[0] > chi2_2dof(
            config.seed.consistency_probability
        ):
            overturns = prior.position[4]
        ev = evidence(
            g_res,
            cov,
            strength,
            top.violation,
            rivalry=rivalry,
            contest=Contest(top.score, rival, overturns, prior_fit, weak=on_prior),
        )

        sol = Solution(g_res, cov, ev, judge(ev, config), origin, used_global=True, n_candidates=n)
        if best is None or sol.reliable or g_res.fitness > best.result.fitness:
            best = sol
        if best.reliable:
            break
    return best, seeded

"""The ICP step's estimator: :func:`estimate` composes the candidate solutions (:mod:`.candidates`), their
covariance (:mod:`.covariance`) and the rules (:mod:`.rules`); :class:`IcpStep` plugs it into the pipeline."""

from __future__ import annotations

import logging
import math
from dataclasses import replace
from typing import Any

import numpy as np

from factorloc.errors import InputError, UnusableInputError
from factorloc.estimators.base import Hypotheses
from factorloc.estimators.icp.candidates import (
    QueryScan,
    Seeds,
    Solution,
    global_attempts,
    near_seed,
    seed_distance2,
    seeded_attempt,
    with_violation,
)
from factorloc.estimators.icp.config import IcpConfig
from factorloc.estimators.icp.covariance import (
    cloud_config,
    heading_strength,
    smallest_sigma_position,
    unconstrained_along,
    weak,
)
from factorloc.estimators.icp.reference import IcpReference, bounded_points, prepare_reference, query_points
from factorloc.estimators.icp.rules import across_walls, judge, passed, seed_checks
from factorloc.geometry import rotate_covariance
from factorloc.types import POSITION, Estimate, Query, Reference
from factorloc.verdicts import Check, SeedEvidence, render_checks

log = logging.getLogger(__name__)

__all__ = ["IcpStep", "estimate"]


def estimate(
    prepared: IcpReference,
    query_points_m: np.ndarray,
    hypotheses: Hypotheses = Hypotheses(),
    config: IcpConfig | None = None,
    *,
    query_from_cloud: bool = False,
) -> Estimate:
    """ICP estimate of the query pose (world frame), seeded by ``hypotheses``.

    Parameters
    ----------
    prepared
        The reference (see :func:`~factorloc.estimators.icp.prepare_reference`).
    query_points_m
        N×2 query scan, query robot frame (metres).
    hypotheses
        Reliable estimates of the earlier steps: the latest position and heading seed ICP; without both (or
        when the seeded solution is unreliable, and not merely degenerate) the global initialization runs.
        Without a reliable position, the latest weak prior (``global_init.weak_prior``) contests a global
        solution that lies outside its region.
    config
        Defaults to ``prepared.config``.
    query_from_cloud
        The query points are a cut of a depth cloud, not a laser scan: the correlated-error term uses
        ``covariance.bias_rmse_ratio_cloud``.

    Returns
    -------
    Estimate
        Full (x, y, θ) world-frame estimate, ``T_world_query = T_world_reference · T_reference_query``, with the
        3×3 covariance rotated into the world frame; ``checks`` are the rules' verdicts
        (:mod:`~factorloc.estimators.icp.rules`) and, when seeded, ``seed`` the typed evidence the pipeline's seed
        audit reads. Diagnostics (figures, not decisions): ``fitness``, ``rmse_m``, ``chamfer_m``,
        ``iterations``, ``converged``, ``n_inliers``, ``n_query_points``, ``used_global_init``, ``violation``
        (NaN when not measured), ``constraint``, ``seed_mahalanobis2``, ``global_score``, ``rival_score``,
        ``global_candidates``, ``seeded_fitness``, ``seeded_violation``, ``sigma_chamfer_m``,
        ``T_reference_query``; after a global initialization ``overlap_fitness`` / ``overlap_points`` and,
        without a position seed, ``rival_overlap_fitness``.
    """
    config, query = _inputs(prepared, query_points_m, config, query_from_cloud)
    seeds = _seeds(hypotheses, config)
    seeded = seeded_attempt(prepared, query, seeds, config) if seeds.full else None
    best = seeded
    run_global, seeded = _global_needed(prepared, query, seeded, config)
    if run_global:
        best, seeded = global_attempts(prepared, query, seeds, config, seeded)
    if best is None:
        return _without_seed(prepared)
    if not best.used_global:
        # a seeded solution that passes its own tests must also stay near its seed where it could slide or jumped
        best = near_seed(prepared, best, seeds, config)
    left_seed = any(c.code == "icp.seed.consistency" and not c.passed for c in best.checks)
    evidence = None
    if seeded is not None:
        checks = seed_checks(
            (seeded.result.fitness, seeded.violation), best.used_global, best.reliable, len(query.points_m), config
        )
        if left_seed and passed(checks) and _fits_on_its_own(best, config) and "icp.seed.stays_near" not in config.ablate:
            checks += (_stays_near(prepared, best, seeds),)
        evidence = SeedEvidence(position_step=seeds.position[4], heading_step=seeds.heading[2], windowed=False, checks=checks)
    if config.seed.across_walls and not best.reliable and seeded is not None and not best.used_global and not left_seed:
        best = with_violation(best, prepared, query)
        best = replace(best, checks=judge(replace(best.evidence, seed_fit=None), config))
        out = _across_walls(prepared, query, best, seeded, seeds, config, evidence)
        if out is not None:
            return _heading_checked(out, best, config)
    est = Estimate.pose(
        "icp",
        prepared.T_world_reference * best.T_reference_query,
        covariance=rotate_covariance(best.covariance, prepared.T_world_reference.theta),
        reliable=best.reliable,
        reason=_reason(best),
        checks=best.checks,
        diagnostics=_diagnostics(prepared, query, best, seeded, seeds, config),
        seed=evidence,
    )
    return _heading_checked(est, best, config)


def _heading_checked(est: Estimate, sol: Solution, config: IcpConfig) -> Estimate:
    """``est``, or its position alone when the scan does not constrain the heading (a round room from its centre).

    The constraint rule's heading half (:func:`~factorloc.estimators.icp.covariance.heading_strength` against
    ``config.reliability.min_heading_strength``, beyond rounding): the heading ICP would
    report is whatever its seed was, so it is left to the other steps (a waived check says so) rather than fused
    with a σ the geometry does not support. An unreliable estimate is returned as it is.
    """
    if not est.reliable:
        return est
    limit = config.reliability.min_heading_strength
    strength = heading_strength(sol.result)
    if not weak(strength, limit):
        return est
    check = Check.at_least(
        "icp.constraint.heading",
        "heading constraint strength",
        strength,
        limit,
        note="degenerate geometry: a round scan",
    ).waived("the heading is left to the other steps")
    position = est.marginal(POSITION)
    reason = f"position only, heading unconstrained (strength {strength:.3g} < {limit:g}): {est.reason}"
    out = position.with_verdict(True, reason, (*est.checks, check))
    return replace(out, diagnostics={**out.diagnostics, "heading_strength": strength})


def _seeds(hypotheses: Hypotheses, config: IcpConfig) -> Seeds:
    """The reliable seeds and, without a reliable position (``global_init.weak_prior``), the weak prior: its
    position, and the reliable heading or else its own."""
    position, heading = hypotheses.position(), hypotheses.heading()
    weak = None
    if position is None and config.global_init.weak_prior:
        prior = hypotheses.weak_pose()
        if prior is not None:
            weak = Seeds(prior[0], heading if heading is not None else prior[1])
    return Seeds(position, heading, weak)


def _inputs(
    prepared: IcpReference, query_points_m: np.ndarray, config: IcpConfig | None, query_from_cloud: bool
) -> tuple[IcpConfig, QueryScan]:
    """The configuration to use and the validated query points."""
    if not isinstance(prepared, IcpReference):
        raise InputError(f"prepared must be an IcpReference, got {type(prepared).__name__}")
    config = prepared.config if config is None else config
    if not isinstance(config, IcpConfig):
        raise InputError(f"config must be an IcpConfig, got {type(config).__name__}")
    if query_from_cloud:
        config = cloud_config(config)
    pts = np.asarray(query_points_m, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 2:
        raise InputError(f"query_points_m must be N×2, got shape {pts.shape}")
    n_min = max(3, config.reliability.min_inliers)
    if len(pts) < n_min:
        raise InputError(f"query scan has {len(pts)} point(s); need >= {n_min}")
    return config, QueryScan(pts, config)


def _global_needed(
    prepared: IcpReference, query: QueryScan, seeded: Solution | None, config: IcpConfig
) -> tuple[bool, Solution | None]:
    """Whether the global initialization runs: it is enabled and no seeded solution is reliable, except a
    degenerate one that fits (one wall, a corridor: the scan is the same elsewhere) and is free-space consistent
    (a degenerate seeded alignment that puts points into space the reference saw empty puts the seed itself in
    doubt, e.g. a kidnapped robot in a corridor). Returns the seeded solution with what was measured."""
    if not config.global_init.enabled or (seeded is not None and seeded.reliable):
        return False, seeded
    r = config.reliability
    degenerate = weak(seeded.strength, r.min_constraint) and seeded.result.fitness >= r.min_fitness if seeded else False
    if degenerate and "icp.degenerate_skips_global" not in config.ablate:
        seeded = with_violation(seeded, prepared, query)
        return seeded.violation > r.max_violation, seeded
    return True, seeded


def _fits_on_its_own(sol: Solution, config: IcpConfig) -> bool:
    """Whether a converged alignment passes ICP's own criteria without the seed: fitness, free space, constraint."""
    r = config.reliability
    v = sol.violation
    return (
        sol.result.fitness >= r.min_fitness
        and math.isfinite(v)
        and v <= r.max_violation
        and not weak(sol.strength, r.min_constraint)
    )


def _stays_near(prepared: IcpReference, sol: Solution, seeds: Seeds) -> Check:
    """The seed check of a seeded alignment that converged far from its seed to a fit of its own: one of the two
    is wrong and the data cannot say which, so the seed is not confirmed."""
    d2, dist = seed_distance2(prepared, sol.T_reference_query, sol.covariance, seeds)
    return Check.flag(
        "icp.seed.stays_near",
        "the seeded alignment stays near its seed",
        False,
        note=f"it converged {dist:.2f} m from the seed to a fit of its own "
        f"(fitness {sol.result.fitness:.2f}, Mahalanobis² {d2:.1f})",
    )


def _across_walls(
    prepared: IcpReference,
    query: QueryScan,
    sol: Solution,
    seeded: Solution,
    seeds: Seeds,
    config: IcpConfig,
    seed: SeedEvidence | None,
) -> Estimate | None:
    """A seeded solution that only the position-degeneracy rules reject, whose heading agrees with the heading
    seed, returned reliable with its position unknown along the walls (or None)."""
    T_wr = prepared.T_world_reference
    cov_world = rotate_covariance(sol.covariance, T_wr.theta)
    T = T_wr * sol.T_reference_query
    head = seeds.heading
    dth = abs(math.remainder(T.theta - head[0], 2.0 * math.pi))
    cov_deg = unconstrained_along(sol.result, sol.covariance)
    sigma_across = smallest_sigma_position(cov_deg)
    checks = across_walls(
        sol.evidence, sol.checks, config, dth, 3.0 * math.hypot(head[1], math.sqrt(float(cov_world[2, 2]))), sigma_across
    )
    if checks is None or not passed(checks):
        return None
    diagnostics = _diagnostics(prepared, query, sol, seeded, seeds, config)
    diagnostics["sigma_across_m"] = sigma_across
    return Estimate.pose(
        "icp",
        T,
        covariance=rotate_covariance(cov_deg, T_wr.theta),
        reliable=True,
        reason=f"across the walls and heading only (σ across {100 * sigma_across:.1f} cm): {_reason(sol)}",
        checks=checks,
        diagnostics=diagnostics,
        seed=seed,
    )


def _without_seed(prepared: IcpReference) -> Estimate:
    """No seed and the global initialization disabled: nothing to align from."""
    check = Check.flag("icp.seed.available", "a reliable position and heading hypothesis, or global initialization", False)
    return Estimate.pose(
        "icp",
        prepared.T_world_reference,
        1e3,
        1e3,
        math.pi,
        reliable=False,
        reason=render_checks((check,)),
        checks=(check,),
        diagnostics={"used_global_init": False},
    )


_SUMMARY = ("icp.score", "icp.free_space")


def _reason(sol: Solution) -> str:
    """The failed checks (or, for a reliable solution, its score and free-space share) and where it came from."""
    shown = sol.checks if not sol.reliable else tuple(c for c in sol.checks if c.code in _SUMMARY)
    return f"{render_checks(shown, only_failed=not sol.reliable)} ({sol.origin})"


def _diagnostics(
    prepared: IcpReference, query: QueryScan, sol: Solution, seeded: Solution | None, seeds: Seeds, config: IcpConfig
) -> dict[str, Any]:
    """Figures for people and plots (no decision reads them)."""
    r, ev = sol.result, sol.evidence
    contest, rivalry = ev.contest, ev.rivalry
    if ev.seed_fit is not None:
        d2 = ev.seed_fit.mahalanobis2
    elif seeds.position is not None:
        d2 = seed_distance2(prepared, sol.T_reference_query, sol.covariance, seeds)[0]
    else:
        d2 = math.nan
    out: dict[str, Any] = {
        "fitness": r.fitness,
        "rmse_m": r.rmse_m,
        "chamfer_m": r.chamfer_m,
        "iterations": r.iterations,
        "converged": r.converged,
        "n_inliers": r.n_inliers,
        "n_query_points": int(len(query.points_m)),
        "used_global_init": sol.used_global,
        "violation": sol.violation,
        "constraint": sol.strength,
        "seed_mahalanobis2": d2,
        "global_score": contest.score if sol.used_global else 0.0,
        "rival_score": contest.rival_score if sol.used_global else 0.0,
        "global_candidates": sol.n_candidates,
        "seeded_fitness": seeded.result.fitness if seeded is not None else math.nan,
        "seeded_violation": seeded.violation if seeded is not None else math.nan,
        "sigma_chamfer_m": max(config.covariance.chamfer_scale * r.chamfer_m, 1e-4),
        "T_reference_query": r.T_target_source.as_array(),
    }
    if sol.used_global:
        out["overlap_fitness"], out["overlap_points"] = query.overlap(prepared, sol.T_reference_query, config)
        if rivalry is not None:
            out["rival_overlap_fitness"] = rivalry.rival_overlap
    return out


class IcpStep:
    """The ICP step: needs a reference scan/cloud and a query scan/cloud."""

    name = "icp"

    def __init__(self, config: IcpConfig = IcpConfig()) -> None:
        if not isinstance(config, IcpConfig):
            raise InputError(f"config must be an IcpConfig, got {type(config).__name__}")
        self.config = config

    def prepare(self, reference: Reference) -> IcpReference | UnusableInputError | None:
        """The prepared reference scan; None when the reference has no scan or cloud; the error when it has one
        that cannot be used (a cloud with nothing in the height band), raised by :meth:`estimate`."""
        try:
            return prepare_reference(reference, self.config)
        except InputError as exc:
            log.warning("ICP step cannot use reference %r: %s", reference.name, exc)
            return UnusableInputError(f"reference {reference.name!r}: {exc}")

    def estimate(
        self, prepared: IcpReference | UnusableInputError | None, query: Query, hypotheses: Hypotheses
    ) -> Estimate | None:
        """The step's estimate for ``query`` (None without a reference scan/cloud or query points).

        Raises :class:`~factorloc.errors.UnusableInputError` when the reference's or the query's scan is present
        but unusable (the pipeline reports ``unusable: <why>``).
        """
        if isinstance(prepared, UnusableInputError):
            raise prepared
        if prepared is None:
            return None
        try:
            pts = query_points(query, self.config)
        except InputError as exc:
            raise UnusableInputError(f"query scan: {exc}") from exc
        if pts is None:
            return None
        kept = bounded_points(pts)
        est = estimate(prepared, kept, hypotheses, self.config, query_from_cloud=query.scan is None)
        notes = {}
        if len(kept) < len(pts):
            notes["downsampled_query_points"] = [len(pts), len(kept)]
        if prepared.n_given_points > len(prepared.points_m):
            notes["downsampled_reference_points"] = [prepared.n_given_points, len(prepared.points_m)]
        return replace(est, diagnostics={**est.diagnostics, **notes}) if notes else est

"""Typed verdicts: checks compare with a stated tolerance, render one way, and round-trip through JSON."""

from __future__ import annotations

import math

import pytest

from factorloc import Estimate, InputError
from factorloc.verdicts import ROUNDING_TOLERANCE, Check, Comparison, SeedEvidence, Unit, render_check, render_checks


def test_a_check_at_its_limit_passes_within_the_tolerance_and_fails_beyond() -> None:
    assert Check.at_least("r.a", "strength", -1e-16, 0.0, tolerance=ROUNDING_TOLERANCE).passed
    assert not Check.at_least("r.a", "strength", -1e-6, 0.0, tolerance=ROUNDING_TOLERANCE).passed
    assert Check.at_most("r.b", "σ", 0.25 + 1e-12, 0.25, Unit.METRE, tolerance=ROUNDING_TOLERANCE).passed
    assert not Check.at_most("r.b", "σ", 0.26, 0.25, Unit.METRE).passed
    assert not Check.at_least("r.c", "fitness", math.nan, 0.25).passed  # NaN never passes


def test_checks_render_with_units_and_only_the_failed_ones_by_default() -> None:
    fit = Check.at_least("icp.fitness", "fitness", 0.2, 0.25)
    sig = Check.at_most("icp.sigma_heading", "σθ", math.radians(6.2), math.radians(5.0), Unit.RADIAN)
    share = Check.at_most("icp.violation", "share in seen-free space", 0.31, 0.12, Unit.FRACTION)
    ok = Check.at_least("icp.inliers", "correspondences", 40, 10, Unit.COUNT)
    assert render_check(fit) == "fitness 0.2 < 0.25"
    assert render_check(sig) == "σθ 6.2° > 5°"
    assert render_check(share) == "share in seen-free space 31 % > 12 %"
    assert render_checks([fit, ok, sig]) == "fitness 0.2 < 0.25; σθ 6.2° > 5°"
    assert render_checks([ok], only_failed=False) == "correspondences 40 ≥ 10"
    assert render_check(Check.flag("x.y", "a seed", False, note="none given")) == "not a seed (none given)"
    assert fit.waived("dominant global solution").passed and fit.waived("w").comparison is Comparison.AT_LEAST
    # a waived check keeps the true comparison of its numbers and says why it passed anyway
    assert render_check(fit.waived("dominant global solution")) == "fitness 0.2 < 0.25 (dominant global solution)"
    assert render_check(Check.at_least("a.b", "x", 1.0 - 1e-12, 1.0, tolerance=1e-9)) == "x 1 ≥ 1"


def test_an_estimate_renders_its_reason_from_its_checks_and_cannot_be_reliable_with_a_failed_one() -> None:
    fit = Check.at_least("icp.fitness", "fitness", 0.2, 0.25)
    est = Estimate.heading("icp", 0.1, 0.01, reliable=False, checks=(fit,))
    assert est.reason == "fitness 0.2 < 0.25"
    with pytest.raises(InputError, match="cannot be reliable with failed checks"):
        Estimate.heading("icp", 0.1, 0.01, checks=(fit,))
    with pytest.raises(InputError, match="checks must hold"):
        Estimate.heading("icp", 0.1, 0.01, checks=("fitness",))  # type: ignore[arg-type]


def test_checks_and_seed_evidence_round_trip_through_json() -> None:
    seed = SeedEvidence("odometry", "odometry", checks=(Check.at_most("icp.seed.free_space", "share", 0.3, 0.12, Unit.FRACTION),))
    est = Estimate.heading("icp", 0.1, 0.01, reliable=False, checks=(Check.flag("icp.x", "a flag", False),), seed=seed)
    back = Estimate.from_dict(est.to_dict())
    assert back == est and back.seed.contradicted and back.seed.reason == "share 30 % > 12 %"
    assert SeedEvidence().seeded is False and SeedEvidence(heading_step="compass").seeded


def test_render_rule_gives_the_range_of_one_rule_over_many_outcomes() -> None:
    from factorloc.verdicts import render_rule

    sigmas = [Check.at_most("odometry.sigma_heading", "σθ", math.radians(d), math.radians(20.0), Unit.RADIAN) for d in (26, 21)]
    assert render_rule(sigmas) == "σθ 21–26° > 20°"
    fits = [Check.at_least("icp.fitness", "fitness", f, 0.25) for f in (0.2, 0.2)]
    assert render_rule(fits) == "fitness 0.2 < 0.25"
    seeds = [
        Check.flag("gate.seed_audit", "seed confirmed by icp", False, note=n, failure="seed contradicted by icp") for n in "ab"
    ]
    assert render_rule(seeds) == "seed contradicted by icp"  # the notes differ: left out
    assert render_rule(seeds[:1]) == "seed contradicted by icp (a)"


def test_seed_source_names_each_seeding_step_once() -> None:
    assert SeedEvidence("odometry", "odometry").source == "seeded by odometry"
    assert SeedEvidence("odometry", "compass").source == "seeded by odometry (position) and compass (heading)"
    assert SeedEvidence("odometry", None).source == "seeded by odometry (position)"
    assert SeedEvidence(None, "compass").source == "seeded by compass (heading)"
    assert SeedEvidence().source == ""

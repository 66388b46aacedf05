"""Reliability and consistency gates."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc import Component, Estimate, Pose2, StepStatus
from factorloc.estimators.base import heading_seed_check
from factorloc.gating import (
    GatingConfig,
    StepRun,
    consistency_gate,
    gate,
    position_determined,
    seed_audit,
    sigma_checks,
)
from factorloc.stats import chi2_quantile
from factorloc.verdicts import Check, SeedEvidence, Unit, render_check


def test_sigma_checks_use_the_long_axis_of_the_position_covariance() -> None:
    corridor = Estimate.position("icp", 0.0, 0.0, covariance=np.diag([0.01**2, 0.30**2]))
    (check,) = sigma_checks(corridor, max_sigma_position_m=0.06)
    assert check.code == "icp.sigma_position" and not check.passed and check.value == pytest.approx(0.3)
    assert render_check(check) == "σ position 0.3 m > 0.06 m"
    rotated = Estimate.position("icp", 0.0, 0.0, covariance=np.array([[0.0451, 0.0449], [0.0449, 0.0451]]))
    assert sigma_checks(rotated, max_sigma_position_m=0.06)[0].value == pytest.approx(0.3)  # along the diagonal
    (ok,) = sigma_checks(Estimate.heading("compass", 0.0, math.radians(0.5)), max_sigma_heading_rad=math.radians(1.0))
    assert ok.passed and ok.code == "compass.sigma_heading"
    assert sigma_checks(Estimate.heading("compass", 0.0, 0.5), max_sigma_position_m=0.06) == ()  # measures no position


def test_the_heading_seed_check_measures_the_wrapped_gap_against_both_sigmas() -> None:
    # across ±π: 179° against a seed at -179° is 2° apart, within 3 σ of both (hypot(0.5°, 1°) · 3 = 3.35°)
    seed = (math.radians(-179.0), math.radians(1.0), "odometry")
    ok = heading_seed_check("compass", math.radians(179.0), math.radians(0.5), seed, 3.0)
    assert ok.code == "compass.seed_consistency" and ok.passed
    assert ok.value == pytest.approx(math.radians(2.0)) and ok.limit == pytest.approx(3.0 * math.radians(math.hypot(0.5, 1.0)))
    far = heading_seed_check("correlation", math.radians(175.0), math.radians(0.5), seed, 3.0)
    assert not far.passed and render_check(far) == "gap to the odometry seed 6° > 3.35° (3 σ of both)"
    assert heading_seed_check("compass", 0.0, 0.01, None, 3.0) is None  # no seed, no rule


def test_consistency_of_one_heading_against_another() -> None:
    a = Estimate.heading("compass", math.radians(10.0), math.radians(1.0))
    b = Estimate.heading("correlation", math.radians(13.0), math.radians(1.0))
    # d² = 3² / (1² + 1²) = 4.5 in degrees, the same for both
    verdicts = consistency_gate([a, b])
    assert [v.mahalanobis_sq["heading"] for v in verdicts] == pytest.approx([4.5, 4.5], rel=1e-9)
    (check,) = verdicts[0].checks
    assert check.code == "gate.consistency.heading" and check.passed and check.limit == chi2_quantile(0.999, 1)
    # across the ±π seam too
    c = Estimate.heading("x", math.radians(179.0), math.radians(1.0))
    d = Estimate.heading("y", math.radians(-178.0), math.radians(1.0))
    assert consistency_gate([c, d])[0].mahalanobis_sq["heading"] == pytest.approx(4.5, rel=1e-9)


def test_kidnapped_odometry_loses_its_heading_with_its_position() -> None:
    odo = Estimate.pose("odometry", Pose2(3.0, 0.5, math.radians(10.0)), 0.05, 0.05, math.radians(3.0))
    compass = Estimate.heading("compass", math.radians(12.0), math.radians(1.0))
    icp = Estimate.position("icp", 1.03, 0.48, 0.02, 0.02)
    verdicts = consistency_gate([odo, compass, icp], probability=0.999)
    assert verdicts[0].accepted == ()
    assert [(c.code, c.passed) for c in verdicts[0].checks] == [
        ("gate.consistency.position", False),
        ("gate.consistency.whole_pose", False),
    ]
    assert verdicts[0].reason.startswith("position d² against the other steps ")
    assert "heading dropped with its position (one measurement of the whole pose)" in verdicts[0].reason
    assert verdicts[0].mahalanobis_sq["position"] > chi2_quantile(0.999, 2)
    assert verdicts[1].fully_accepted and verdicts[2].fully_accepted
    assert verdicts[0].accepted_estimate() is None
    # tested per axis (the patent's view) the odometry keeps its consistent heading
    per_axis = consistency_gate([odo, compass, icp], probability=0.999, full_pose_whole=False)
    assert per_axis[0].accepted == (Component.THETA,)
    part = per_axis[0].accepted_estimate()
    assert part is not None and part.kind == "heading"


def test_a_kidnapped_odometry_and_the_compass_it_seeded_do_not_outvote_icp() -> None:
    # the held-out scenario's case: odometry and the compass seeded by it agree on a heading 14° off;
    # ICP's global solution has the right position and heading
    odo = Estimate.pose("odometry", Pose2(3.0, 0.5, math.radians(24.0)), 0.05, 0.05, math.radians(3.0))
    compass = Estimate.heading("compass", math.radians(24.5), math.radians(0.5))
    icp = Estimate.pose("icp", Pose2(1.0, 0.5, math.radians(10.0)), 0.01, 0.01, math.radians(0.5))
    verdicts = consistency_gate([odo, compass, icp], probability=0.999)
    assert verdicts[0].accepted == ()
    assert not verdicts[1].fully_accepted  # two headings left that disagree: the earlier step goes
    assert verdicts[2].fully_accepted
    # per axis, the two wrong headings outvote ICP's right one
    per_axis = consistency_gate([odo, compass, icp], probability=0.999, full_pose_whole=False)
    assert per_axis[2].accepted == (Component.X, Component.Y)
    assert per_axis[1].fully_accepted


def test_the_outlier_among_three_headings_is_rejected_not_the_good_ones() -> None:
    ests = [
        Estimate.heading("odometry", math.radians(10.0), math.radians(2.0)),
        Estimate.heading("compass", math.radians(40.0), math.radians(1.0)),  # a false match
        Estimate.heading("correlation", math.radians(10.5), math.radians(0.5)),
    ]
    verdicts = consistency_gate(ests)
    assert [v.fully_accepted for v in verdicts] == [True, False, True]


def test_consistent_estimates_all_pass() -> None:
    rng = np.random.default_rng(0)
    passed = 0
    for _ in range(200):
        truth = rng.normal(size=2)
        ests = [Estimate.position(f"e{i}", *(truth + rng.normal(scale=0.1, size=2)), 0.1, 0.1) for i in range(4)]
        passed += all(v.fully_accepted for v in consistency_gate(ests, 0.999))
    assert passed >= 195  # false rejections at the 0.1 % level per test, a few rounds


def _misfit(label: str) -> SeedEvidence:
    """Evidence of a step whose data contradict its odometry seed (one failed flag check named ``label``)."""
    return SeedEvidence("odometry", "odometry", checks=(Check.flag("icp.seed.test", label, False),))


def _icp_misfit(
    x: float, y: float, *, used_global: bool = True, reliable: bool = False, misfit: SeedEvidence | None = None
) -> Estimate:
    """An ICP estimate as the ICP step reports a seeded alignment that failed and a global search that found nothing sure.

    ``misfit``: the step's own seed evidence (None: the step did not check).
    """
    return Estimate.pose(
        "icp",
        Pose2(x, y, 0.3),
        0.005,
        0.005,
        0.003,
        reliable=reliable,
        reason="ambiguous: a distinct solution scores 0.39 vs 0.43 (global initialization, widened)",
        diagnostics={"used_global_init": used_global, "n_query_points": 360},
        seed=misfit,
    )


def test_seed_audit_rejects_the_position_seed_that_the_later_scan_contradicts() -> None:
    odo = Estimate.pose("odometry", Pose2(3.0, 0.5, 1.2), 0.06, 0.06, 0.05)
    compass = Estimate.heading("compass", 1.2, 0.1, reliable=False, reason="2 inlier pairs < 8")
    violated = Check.at_most("icp.seed.free_space", "share in seen-free space", 0.31, 0.12, Unit.FRACTION)
    evidence = SeedEvidence("odometry", "odometry", checks=(violated,))
    contradicted = seed_audit([odo, compass, _icp_misfit(1.3, 1.9, misfit=evidence)])
    assert list(contradicted) == [0] and contradicted[0].code == "gate.seed_audit" and not contradicted[0].passed
    assert render_check(contradicted[0]) == "seed contradicted by icp (share in seen-free space 31 % > 12 %)"
    # the step's own evidence is used as given
    told = Estimate.heading("icp", 0.0, 0.1, reliable=False, seed=_misfit("a fit near the seed"))
    assert render_check(seed_audit([odo, told])[0]) == "seed contradicted by icp (not a fit near the seed)"
    # a step that reports passed seed checks has checked its seed: its other figures are not second-guessed
    passed = SeedEvidence("odometry", "odometry", checks=(Check.flag("icp.seed.fits_near", "fits near", True),))
    checked = Estimate.pose(
        "icp", Pose2(1.3, 1.9, 0.3), 0.005, 0.005, 0.003, reliable=False,
        diagnostics={"used_global_init": True}, seed=passed,
    )  # fmt: skip
    assert seed_audit([odo, checked]) == {}
    # a reliable heading-only result (a wall fixes the heading, not the position) may still refute the position seed
    wall = Estimate.heading("icp", 0.3, 0.003, seed=_misfit("18 % of the scan outside seen-free space"))
    assert seed_audit([odo, wall])[0].note == "not 18 % of the scan outside seen-free space"


def test_seed_audit_leaves_degenerate_blind_and_confirmed_seeds_alone() -> None:
    odo = Estimate.pose("odometry", Pose2(3.0, 0.5, 1.2), 0.06, 0.06, 0.05)
    violated = _misfit("31 % of the scan outside seen-free space")
    # a seeded fit that failed and a global search that found nothing sure, but the step checked its seed and found
    # it free-space consistent (or did not check): nothing refutes the seed — no second guess from the diagnostics
    assert seed_audit([odo, _icp_misfit(1.3, 1.9, misfit=SeedEvidence("odometry", "odometry"))]) == {}
    assert seed_audit([odo, _icp_misfit(1.3, 1.9)]) == {}
    # a degenerate seeded fit does not search globally: it says nothing against the seed
    assert seed_audit([odo, _icp_misfit(3.0, 0.9, used_global=False)]) == {}
    # a reliable ICP is weighed against the seed by the consistency gate instead
    assert seed_audit([odo, _icp_misfit(1.3, 1.9, reliable=True, misfit=violated)]) == {}
    # no reliable position seed before it: nothing to contradict
    unreliable_odo = Estimate.pose("odometry", Pose2(3.0, 0.5, 1.2), 0.6, 0.6, 0.5, reliable=False)
    assert seed_audit([unreliable_odo, _icp_misfit(1.3, 1.9, misfit=violated)]) == {}


def _along_a_diagonal_wall(x: float, y: float, sigma_across_m: float = 0.01) -> Estimate:
    """A full pose unknown (30 m) along the wall y = x and known to ``sigma_across_m`` across it."""
    u, n = np.array([1.0, 1.0]) / math.sqrt(2.0), np.array([1.0, -1.0]) / math.sqrt(2.0)
    cov = np.zeros((3, 3))
    cov[:2, :2] = 30.0**2 * np.outer(u, u) + sigma_across_m**2 * np.outer(n, n)
    cov[2, 2] = 0.002**2
    return Estimate.pose("icp", Pose2(x, y, 0.5), covariance=cov)


def test_the_consistency_gate_tests_a_wall_estimate_only_across_the_wall() -> None:
    icp = _along_a_diagonal_wall(1.0, 0.0)
    # world σx = σy ≈ 21 m: a per-axis σ test would call it useless; the Mahalanobis distance sees the 1 cm
    assert icp.sigma("x") > 20.0 and icp.sigma("y") > 20.0
    far_along = Estimate.pose("odometry", Pose2(1.0 + 0.5, 0.0 + 0.5, 0.5), 0.05, 0.05, 0.05)  # 71 cm along the wall
    verdicts = consistency_gate([far_along, icp])
    assert all(v.fully_accepted for v in verdicts)
    assert verdicts[0].mahalanobis_sq["position"] < 0.01
    off_across = Estimate.pose("odometry", Pose2(1.0 + 0.1, 0.0 - 0.1, 0.5), 0.03, 0.03, 0.05)  # 14 cm across: 4.7σ
    verdicts = consistency_gate([off_across, icp])
    assert verdicts[0].mahalanobis_sq["position"] > chi2_quantile(0.999, 2)
    assert verdicts[0].accepted == ()  # the earlier step loses its position on the tie, and its heading with it
    assert verdicts[1].fully_accepted


def test_position_determined_fails_only_for_a_direction_nobody_measured() -> None:
    limit = GatingConfig().undetermined_sigma_m
    along = position_determined(_along_a_diagonal_wall(1.0, 0.0).covariance, limit)
    assert not along.passed and along.code == "gate.undetermined.position" and along.value == pytest.approx(30.0)
    assert position_determined(np.diag([0.3**2, 0.3**2, 0.01]), limit).passed
    assert not position_determined(np.diag([np.inf, np.inf, 0.01]), limit).passed


def test_seed_audit_drops_the_headings_searched_around_a_contradicted_seed() -> None:
    # held-out q0371 of --queries 1000 --seed 41: the audit rejected the odometry, and the correlation, whose
    # window the odometry's heading had centred, was fused alone 30° off
    odo = Estimate.pose("odometry", Pose2(1.49, 3.81, 0.13), 0.09, 0.21, 0.29)
    compass = Estimate.heading("compass", -0.30, 0.08, reliable=False, reason="2 inlier pairs < 8")
    windowed = SeedEvidence(heading_step="odometry", windowed=True)
    correlation = Estimate.heading("correlation", -0.37, 0.07, diagnostics={"window_rad": 0.86}, seed=windowed)
    violated = _misfit("27 % of the scan outside seen-free space")
    ests = [odo, compass, correlation, _icp_misfit(1.57, 3.95, misfit=violated)]
    contradicted = seed_audit(ests)
    assert set(contradicted) == {0, 2}  # the unreliable compass is not fused anyway
    assert contradicted[2].code == "gate.seed_audit.windowed" and contradicted[2].note == violated.reason
    assert render_check(contradicted[2]).startswith("searched around the odometry seed, contradicted by icp (")
    assert set(seed_audit(ests, drop_seeded=False)) == {0}
    # a heading found without a seed (the whole panorama searched) stands on its own
    blind = Estimate.heading("correlation", -0.37, 0.07, seed=SeedEvidence())
    assert set(seed_audit([odo, compass, blind, ests[3]])) == {0}


def test_the_gate_reports_every_step_with_the_checks_that_decided_it() -> None:
    odo = Estimate.pose("odometry", Pose2(3.0, 0.5, 0.2), 0.05, 0.05, 0.05)
    bad = Check.at_least("compass.inliers", "inlier pairs", 3, 8, Unit.COUNT)
    compass = Estimate.heading("compass", 0.2, 0.1, reliable=False, checks=(bad,))
    icp = Estimate.position("icp", 1.03, 0.48, 0.02, 0.02)
    correlation = Estimate.heading("correlation", 0.21, 0.02)
    failure = "InputError: all-black image"
    runs = [StepRun("odometry", odo, 0.001), StepRun("compass", compass), StepRun("correlation", correlation),
            StepRun("icp", icp), StepRun("panorama", None), StepRun("extra", None, 0.0, failure)]  # fmt: skip
    gated = gate(runs, GatingConfig())
    status = {r.name: r.status.value for r in gated.reports}
    assert status == {"odometry": "inconsistent", "compass": "unreliable", "correlation": "fused", "icp": "fused",
                      "panorama": "skipped", "extra": "failed"}  # fmt: skip
    assert gated.accepted == (correlation, icp)
    codes = {r.name: r.rule_codes for r in gated.reports}
    assert codes["odometry"] == ("gate.consistency.position", "gate.consistency.whole_pose")
    assert codes["compass"] == ("compass.inliers",) and gated.reports[1].reason == "inlier pairs 3 < 8"
    assert codes["panorama"] == ("panorama.skipped",) and codes["extra"] == ("extra.failed",)
    assert codes["icp"] == () and gated.reports[3].reason.startswith("consistency not tested")
    assert gated.reports[5].reason == "InputError: all-black image" and gated.reports[0].seconds == 0.001
    # the knobs: per axis, the odometry keeps its heading (partly fused); without the consistency gate it is fused whole
    per_axis = gate(runs, GatingConfig(full_pose_whole=False))
    assert per_axis.reports[0].status is StepStatus.FUSED and per_axis.reports[0].reason.startswith("partly fused: position d²")
    assert len(gate(runs, GatingConfig(consistency=False)).accepted) == 3


def test_every_gating_knob_is_a_config_field() -> None:
    from factorloc import Config

    cfg = Config.from_dict({"gating": {"full_pose_whole": False, "drop_seeded": False, "undetermined_sigma_m": 5.0}})
    assert (cfg.gating.full_pose_whole, cfg.gating.drop_seeded, cfg.gating.undetermined_sigma_m) == (False, False, 5.0)
    assert Config.from_dict(cfg.to_dict()) == cfg


def test_an_estimate_measures_a_position_only_where_the_undetermined_rule_accepts_it() -> None:
    from factorloc.gating import GatingConfig, fixes_full_pose, measures_position

    limit = GatingConfig().undetermined_sigma_m  # 15 m: half the σ an ICP estimate states along a corridor
    pose = Estimate.pose("icp", Pose2(1.0, 2.0, 0.1), 0.02, 0.03, 0.01)
    corridor = Estimate.pose("icp", Pose2(1.0, 2.0, 0.1), 30.0, 0.03, 0.01)  # unknown along x
    heading = Estimate.heading("compass", 0.1, 0.01)
    assert measures_position(pose, limit) and fixes_full_pose(pose, limit)
    assert not measures_position(corridor, limit) and not fixes_full_pose(corridor, limit)
    assert not measures_position(heading, limit) and not fixes_full_pose(heading, limit)
    assert measures_position(Estimate.position("icp", 1.0, 2.0, 0.02, 0.02), limit)
    assert not fixes_full_pose(Estimate.position("icp", 1.0, 2.0, 0.02, 0.02), limit)  # no heading
    unreliable = Estimate.pose("icp", Pose2(1.0, 2.0, 0.1), 0.02, 0.03, 0.01, reliable=False)
    assert measures_position(unreliable, limit) and not fixes_full_pose(unreliable, limit)

"""Reliability and consistency gates."""

from __future__ import annotations

import math

import numpy as np

from factorloc import Component, Estimate, Pose2
from factorloc.gating import chi2_threshold, consistency_gate, mahalanobis_sq, sigma_gate


def test_sigma_gate_uses_the_long_axis_of_the_position_covariance() -> None:
    corridor = Estimate.position("icp", 0.0, 0.0, covariance=np.diag([0.01**2, 0.30**2]))
    ok, reason = sigma_gate(corridor, max_sigma_position_m=0.06)
    assert not ok and "0.3 m > 0.06 m" in reason
    ok, _ = sigma_gate(Estimate.heading("compass", 0.0, math.radians(0.5)), max_sigma_heading_rad=math.radians(1.0))
    assert ok


def test_mahalanobis_of_one_heading_against_another() -> None:
    a = Estimate.heading("compass", math.radians(10.0), math.radians(1.0))
    b = Estimate.heading("correlation", math.radians(13.0), math.radians(1.0))
    # d² = 3² / (1² + 1²) = 4.5 in degrees
    assert math.isclose(mahalanobis_sq(a, [b]), 4.5, rel_tol=1e-9)
    # across the ±π seam too
    c = Estimate.heading("x", math.radians(179.0), math.radians(1.0))
    d = Estimate.heading("y", math.radians(-178.0), math.radians(1.0))
    assert math.isclose(mahalanobis_sq(c, [d]), 4.5, rel_tol=1e-9)


def test_kidnapped_odometry_loses_its_position_but_keeps_a_consistent_heading() -> None:
    odo = Estimate.pose("odometry", Pose2(3.0, 0.5, math.radians(10.0)), 0.05, 0.05, math.radians(3.0))
    compass = Estimate.heading("compass", math.radians(12.0), math.radians(1.0))
    icp = Estimate.position("icp", 1.03, 0.48, 0.02, 0.02)
    verdicts = consistency_gate([odo, compass, icp], probability=0.999)
    assert verdicts[0].accepted == (Component.THETA,) and "position inconsistent" in verdicts[0].reason
    assert verdicts[0].mahalanobis_sq["position"] > chi2_threshold(0.999, 2)
    assert verdicts[1].fully_accepted and verdicts[2].fully_accepted
    part = verdicts[0].accepted_estimate()
    assert part is not None and part.kind == "heading"


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

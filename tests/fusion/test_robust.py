"""Robust factor graph: with consistent estimates it is the Gaussian graph; with an outlier and
no consistency gate, Cauchy and GNC ignore it while plain least squares is pulled away."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc.errors import ConfigError
from factorloc.fusion import GraphFusion
from factorloc.fusion.robust import RobustGraphFusion
from factorloc.geometry import Pose2
from factorloc.types import Component, Estimate, Query, StepReport, StepStatus

TRUTH = Pose2(1.0, 2.0, 0.3)


def _consistent() -> list[Estimate]:
    return [
        Estimate.pose("odometry", Pose2(1.02, 1.97, 0.31), 0.05, 0.05, 0.03),
        Estimate.heading("compass", 0.302, 0.01),
        Estimate.position("icp", 1.001, 2.002, 0.01, 0.02),
    ]


@pytest.mark.parametrize("kernel", ["huber", "cauchy", "gnc"])
def test_consistent_estimates_give_the_gaussian_answer(kernel: str) -> None:
    ests = _consistent()
    g = GraphFusion().fuse(ests)
    r = RobustGraphFusion(kernel).fuse(ests)
    # all whitened residuals are < 1 σ here: Huber and GNC are exactly quadratic, Cauchy nearly
    tol = 1e-6 if kernel != "cauchy" else 2e-3
    assert np.allclose(r.pose.as_array(), g.pose.as_array(), atol=tol)
    assert np.allclose(np.sqrt(np.diag(r.covariance)), np.sqrt(np.diag(g.covariance)), rtol=0.1)


@pytest.mark.parametrize("kernel", ["cauchy", "gnc"])
def test_a_confident_outlier_is_ignored_by_redescending_kernels(kernel: str) -> None:
    ests = [*_consistent(), Estimate.heading("correlation", 0.3 + math.radians(20.0), 0.01)]
    plain = GraphFusion().fuse(ests)
    robust = RobustGraphFusion(kernel).fuse(ests)
    assert abs(plain.pose.theta - TRUTH.theta) > math.radians(5.0)
    assert abs(robust.pose.theta - TRUTH.theta) < math.radians(0.5)


def test_huber_bounds_the_outlier_pull() -> None:
    ests = [*_consistent(), Estimate.heading("correlation", 0.3 + math.radians(20.0), 0.01)]
    plain = GraphFusion().fuse(ests)
    huber = RobustGraphFusion("huber").fuse(ests)
    assert abs(huber.pose.theta - TRUTH.theta) < 0.5 * abs(plain.pose.theta - TRUTH.theta)


def test_update_fuses_every_reliable_estimate_even_the_gated_ones() -> None:
    ests = _consistent()
    outlier = Estimate.heading("correlation", 0.3 + math.radians(20.0), 0.01)
    reports = [
        StepReport("odometry", StepStatus.FUSED, ests[0]),
        StepReport("compass", StepStatus.FUSED, ests[1]),
        StepReport("correlation", StepStatus.INCONSISTENT, outlier, "heading inconsistent"),
        StepReport("icp", StepStatus.FUSED, ests[2]),
        StepReport("extra", StepStatus.UNRELIABLE, Estimate.heading("extra", 2.0, 0.01, reliable=False)),
    ]
    r = RobustGraphFusion("cauchy").update(Query(id="q"), reports)
    direct = RobustGraphFusion("cauchy").fuse([*ests, outlier])
    assert np.allclose(r.pose.as_array(), direct.pose.as_array(), atol=1e-9)


def test_heading_only_input_reports_position_undetermined() -> None:
    r = RobustGraphFusion("cauchy").fuse([Estimate.heading("compass", 0.5, 0.01)])
    assert r.undetermined == (Component.X, Component.Y)
    assert r.pose.theta == pytest.approx(0.5)
    assert math.isinf(r.covariance[0, 0])


def test_unknown_kernel_is_refused() -> None:
    with pytest.raises(ConfigError, match="kernel"):
        RobustGraphFusion("tukey")


def test_ignoring_verdicts_fuses_the_unreliable_estimates_too() -> None:
    good = Estimate.pose(
        "icp", Pose2(1.0, 2.0, 0.3), 0.01, 0.01, 0.005, reliable=False, reason="inconsistent with the odometry seed"
    )
    wrong_odometry = Estimate.pose("odometry", Pose2(2.0, 2.5, 0.8), 0.3, 0.3, 0.2)
    reports = [
        StepReport("odometry", StepStatus.FUSED, wrong_odometry),
        StepReport("icp", StepStatus.UNRELIABLE, good, good.reason),
    ]
    trusting = RobustGraphFusion("gnc").update(Query(id="q"), reports)
    listening = RobustGraphFusion("gnc", trust_verdicts=False).update(Query(id="q"), reports)
    assert RobustGraphFusion("gnc", trust_verdicts=False).name == "robust_gnc_all"
    assert math.hypot(trusting.pose.x - 2.0, trusting.pose.y - 2.5) < 1e-6  # only the odometry
    assert math.hypot(listening.pose.x - 1.0, listening.pose.y - 2.0) < 0.01  # the precise ICP dominates


def test_gaussian_kernel_is_plain_least_squares() -> None:
    ests = [*_consistent(), Estimate.heading("correlation", 0.3 + math.radians(20.0), 0.01)]
    plain = GraphFusion().fuse(ests)
    gaussian = RobustGraphFusion("gaussian").fuse(ests)
    assert RobustGraphFusion("gaussian").name == "ungated_gaussian"
    assert np.allclose(gaussian.pose.as_array(), plain.pose.as_array(), atol=1e-9)

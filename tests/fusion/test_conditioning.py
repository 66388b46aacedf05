"""Issue #21, reproducer 2: fusion checks the conditioning of what it inverts and never lets a GTSAM or numpy
error escape — a :class:`FusionError` naming the estimates instead."""

from __future__ import annotations

import math

import numpy as np
import pytest

import factorloc as fl
from factorloc.errors import FusionError, InputError
from factorloc.fusion import GraphFusion, ProductFusion, RobustGraphFusion
from factorloc.fusion.base import MAX_CONDITION, check_conditioning, fusion_errors, information


@pytest.mark.parametrize("strategy", [GraphFusion(), ProductFusion(), RobustGraphFusion()])
def test_an_ill_conditioned_position_is_a_fusion_error_naming_the_estimates(strategy):
    # σ 1e6 m along x, 1e-9 m along y: both in range, but the information's condition number is 1e30
    e = fl.Estimate.pose("odometry", fl.Pose2(1, 1, 1), 1e6, 1e-9, 1e-3)
    with pytest.raises(FusionError, match=r"\['odometry'\].*condition number 1e\+30"):
        strategy.fuse([e])
    with pytest.raises(FusionError, match="odometry"):
        fl.fuse([e], strategy=strategy)


def test_the_condition_bound_is_where_the_graph_keeps_its_digits():
    """MAX_CONDITION = 1e12: the graph's σ are still within 1e-5 relative (at 1e16 they were 80 % off)."""
    ratio = math.sqrt(MAX_CONDITION)
    sx, sy = ratio * 1e-3, 1e-3
    e = fl.Estimate.pose("a", fl.Pose2(1, 1, 1), sx, sy, 1e-3)
    assert check_conditioning([e]) == pytest.approx(MAX_CONDITION, rel=1e-9)
    fused = GraphFusion().fuse([e])
    assert np.sqrt(np.diag(fused.covariance)) == pytest.approx([sx, sy, 1e-3], rel=1e-5)
    worse = fl.Estimate.pose("a", fl.Pose2(1, 1, 1), sx * 1.01, sy, 1e-3)
    with pytest.raises(FusionError):
        GraphFusion().fuse([worse])


def test_wide_but_well_conditioned_sigmas_fuse_to_the_truth():
    # the σ range's two ends in different components: positions 1e-9 m, heading 1e6 rad (no rotation mixes them)
    e = fl.Estimate.pose("a", fl.Pose2(1, 1, 1), 1e-9, 1e-9, 1e6)
    f = ProductFusion().fuse([e])
    assert np.sqrt(np.diag(f.covariance)) == pytest.approx([1e-9, 1e-9, 1e6], rel=1e-9)


def test_gtsam_and_numpy_failures_become_fusion_errors():
    ests = [fl.Estimate.heading("compass", 0.0, 0.1)]
    for exc in (RuntimeError("Indeterminate linear system"), ValueError("constrained"), np.linalg.LinAlgError("x")):
        with pytest.raises(FusionError, match=r"graph fusion of estimates \['compass'\] failed: \w+"):
            with fusion_errors(ests, "graph"):
                raise exc
    with pytest.raises(InputError):  # the library's own errors pass unchanged
        with fusion_errors(ests, "graph"):
            raise InputError("x")


def test_information_is_exact_across_the_sigma_range():
    cov = np.diag([1e-18, 1e12])
    assert np.array_equal(information(cov), np.diag([1e18, 1e-12]))


def test_a_smoother_failure_in_gtsam_is_a_fusion_error(monkeypatch):
    from factorloc.fusion import TrajectorySmoother

    smoother = TrajectorySmoother()
    smoother.reset()
    est = fl.Estimate.pose("odometry", fl.Pose2(1, 1, 0.1), 0.1, 0.1, 0.05)
    reports = fl.fuse([est]).steps
    query = fl.Query(odometry=fl.Odometry(fl.Pose2(1, 1, 0.1), 0.1, 0.1, 0.05))

    def boom(*args, **kwargs):  # noqa: ANN002, ANN003, ANN202
        raise RuntimeError("Indeterminate linear system detected while working near variable 0")

    monkeypatch.setattr(smoother, "_solve", boom)
    with pytest.raises(FusionError, match=r"smoother fusion of estimates \['odometry'\] failed: RuntimeError"):
        smoother.update(query, reports)

"""Trajectory smoother (iSAM2) and its fixed-lag variant against ground truth: odometry between
consecutive queries carries the position through a stretch of heading-only queries, the offline
smoothed trajectory is better still, a rejected prediction (kidnapping) starts a new chain."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc.baselines import MotionModel
from factorloc.errors import InputError
from factorloc.fusion import ProductFusion
from factorloc.fusion.smoother import FixedLagSmoother, TrajectorySmoother
from factorloc.geometry import Pose2
from factorloc.types import Estimate, Odometry, Query, StepReport, StepStatus


def _straight_line(n: int, heading_only: range, kidnap_at: int | None = None, seed: int = 0):
    """Robot drives +x at 0.5 m per query; ICP full pose except in ``heading_only``; compass always."""
    rng = np.random.default_rng(seed)
    motion = MotionModel()
    truths, queries, reports = [], [], []
    odo = Pose2(0.0, 0.0, 0.0)
    for k in range(n):
        truth = Pose2(0.5 * k + (1.0 if kidnap_at is not None and k >= kidnap_at else 0.0), 0.0, 0.0)
        if k:
            d = Pose2(0.5, 0.0, 0.0)
            s = motion.sigmas(d)
            odo = odo.compose(Pose2(0.5 + rng.normal(0, s[0]), rng.normal(0, s[1]), rng.normal(0, s[2])))
        sig = 0.3
        odometry = Odometry(odo, sig, sig, 0.2)
        reps = [
            StepReport("odometry", StepStatus.FUSED, Estimate.pose("odometry", odo, sig, sig, 0.2)),
            StepReport("compass", StepStatus.FUSED, Estimate.heading("compass", rng.normal(0, 0.005), 0.005)),
        ]
        if k not in heading_only:
            p = Pose2(truth.x + rng.normal(0, 0.01), rng.normal(0, 0.01), rng.normal(0, 0.005))
            reps.append(StepReport("icp", StepStatus.FUSED, Estimate.pose("icp", p, 0.01, 0.01, 0.005)))
        truths.append(truth)
        queries.append(Query(odometry=odometry, id=f"q{k}"))
        reports.append(tuple(reps))
    return truths, queries, reports


def _errors(strategy, truths, queries, reports) -> np.ndarray:
    strategy.reset()
    out = [strategy.update(q, r) for q, r in zip(queries, reports, strict=True)]
    return np.array([math.hypot(f.pose.x - t.x, f.pose.y - t.y) for f, t in zip(out, truths, strict=True)])


def _product_errors(truths, reports) -> np.ndarray:
    out = [ProductFusion().fuse([r.estimate for r in reps]) for reps in reports]
    return np.array([math.hypot(f.pose.x - t.x, f.pose.y - t.y) for f, t in zip(out, truths, strict=True)])


def test_odometry_links_carry_position_through_heading_only_queries() -> None:
    truths, queries, reports = _straight_line(20, range(8, 14))
    smoother = _errors(TrajectorySmoother(), truths, queries, reports)
    product = _product_errors(truths, reports)
    stretch = list(range(8, 14))
    assert np.sqrt(np.mean(smoother[stretch] ** 2)) < 0.5 * np.sqrt(np.mean(product[stretch] ** 2))
    assert smoother.max() < 0.1


def test_offline_trajectory_is_better_than_online_in_the_stretch() -> None:
    stretch = list(range(8, 14))
    mse_online, mse_offline = [], []
    for seed in range(12):  # the gain is in expectation: average over drift realizations
        truths, queries, reports = _straight_line(20, range(8, 14), seed=seed)
        sm = TrajectorySmoother()
        online = _errors(sm, truths, queries, reports)
        offline = np.array([math.hypot(p.x - t.x, p.y - t.y) for (p, _), t in zip(sm.smoothed(), truths, strict=True)])
        mse_online.append(np.mean(online[stretch] ** 2))
        mse_offline.append(np.mean(offline[stretch] ** 2))
        assert len(sm.update_seconds) == 20
    assert np.sqrt(np.mean(mse_offline)) < 0.8 * np.sqrt(np.mean(mse_online))


def test_fixed_lag_equals_full_smoother_online_and_forgets_old_poses() -> None:
    truths, queries, reports = _straight_line(15, range(5, 9), seed=2)
    full = _errors(TrajectorySmoother(), truths, queries, reports)
    lag = FixedLagSmoother(lag=3)
    fixed = _errors(lag, truths, queries, reports)
    assert np.allclose(full, fixed, atol=1e-3)
    assert len(lag.trajectory()) <= 5
    with pytest.raises(InputError, match="marginalized"):
        lag.smoothed()


def test_a_kidnapping_starts_a_new_chain() -> None:
    truths, queries, reports = _straight_line(12, range(0), kidnap_at=6, seed=3)
    sm = TrajectorySmoother()
    err = _errors(sm, truths, queries, reports)
    assert sm.chains == 2
    assert err.max() < 0.05


def test_independent_queries_are_not_linked() -> None:
    truths, queries, reports = _straight_line(6, range(2, 4), seed=4)
    sm = TrajectorySmoother(continuous=False)
    _errors(sm, truths, queries, reports)
    assert sm.chains == 6


def test_bad_lag_is_refused() -> None:
    with pytest.raises(InputError, match="lag"):
        FixedLagSmoother(lag=0)


def test_a_chain_started_from_a_heading_only_survives_cm_level_odometry_links() -> None:
    # Regression (notebook 04 in CI): a new chain whose first pose has only a heading gets a
    # placeholder prior on its position; with σ = 1e3 m GTSAM's Cholesky then declared the
    # system indeterminate as soon as a 2.7 cm odometry link arrived.
    import gtsam

    from factorloc.fusion.smoother import PLACEHOLDER_SIGMA

    isam = gtsam.ISAM2()
    graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
    graph.add(gtsam.PoseRotationPrior2D(0, gtsam.Rot2(1.0), gtsam.noiseModel.Diagonal.Sigmas(np.array([0.06]))))
    graph.add(
        gtsam.PoseTranslationPrior2D(0, np.array([0.2, 0.5]), gtsam.noiseModel.Diagonal.Sigmas(np.full(2, PLACEHOLDER_SIGMA)))
    )
    values.insert(0, gtsam.Pose2(0.2, 0.5, 1.0))
    isam.update(graph, values)
    for k in range(1, 4):
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        odo = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.027, 0.027, 0.011]))
        graph.add(gtsam.BetweenFactorPose2(k - 1, k, gtsam.Pose2(0.3, 0.0, 0.1), odo))
        if k == 3:  # then ICP fixes the position to the millimetre
            icp = gtsam.noiseModel.Diagonal.Sigmas(np.array([0.001, 0.003]))
            graph.add(gtsam.PoseTranslationPrior2D(k, np.array([0.9, 0.7]), icp))
        values.insert(k, gtsam.Pose2(0.2 + 0.3 * k, 0.5, 1.0 + 0.1 * k))
        isam.update(graph, values)
        cov = np.asarray(isam.marginalCovariance(k))
    assert cov[0, 0] < 1e-5 and cov[1, 1] < 1e-4  # determined by the ICP prior, not the placeholder

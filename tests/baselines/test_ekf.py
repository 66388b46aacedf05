"""The EKF against ground truth on synthetic trajectories: it carries position through a stretch
without ICP better than per-query fusion, re-initializes on a kidnapping, and is the
linear-Gaussian twin of the iSAM2 smoother's online answer."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic_trajectories import position_errors

from factorloc.baselines import ExtendedKalmanFilter
from factorloc.errors import InputError
from factorloc.evaluation import evaluate
from factorloc.fusion import ProductFusion
from factorloc.fusion.sequential import MotionModel, compose_with_covariance
from factorloc.fusion.smoother import TrajectorySmoother
from factorloc.geometry import Pose2


def _run(strategy, syn):
    strategy.reset()
    return [strategy.update(q, r) for q, r in zip(syn.queries, syn.reports, strict=True)]


def test_ekf_beats_per_query_fusion_where_icp_is_missing(synthetic) -> None:
    syn = synthetic(30, seed=1, no_icp=(10, 18))
    run = syn.run()
    ekf = evaluate(run, ExtendedKalmanFilter()).to_json()
    product = evaluate(run, ProductFusion()).to_json()
    stretch = product["by_fault"]["no_depth"]["position_rmse_m"]
    assert ekf["by_fault"]["no_depth"]["position_rmse_m"] < 0.7 * stretch
    assert ekf["position_rmse_m"] < 0.05
    assert 1.0 < ekf["nees_mean"] < 6.0


def test_ekf_reinitializes_after_a_kidnapping(synthetic) -> None:
    syn = synthetic(30, seed=2, kidnap_at=15)
    ekf = ExtendedKalmanFilter()
    fused = _run(ekf, syn)
    err = position_errors([f.pose for f in fused], syn.truths)
    assert ekf.reinitialized >= 1
    assert err[15] < 0.05  # the very query of the kidnapping
    assert err.max() < 0.05


def test_ekf_online_answer_equals_the_isam2_smoothers(synthetic) -> None:
    syn = synthetic(20, seed=3, no_icp=(5, 12))
    a = _run(ExtendedKalmanFilter(), syn)
    b = _run(TrajectorySmoother(), syn)
    pa = np.array([f.pose.as_array() for f in a])
    pb = np.array([f.pose.as_array() for f in b])
    assert np.max(np.abs(pa - pb)[:, :2]) < 2e-3
    assert (
        np.max(
            np.abs(
                np.sqrt(np.diagonal([f.covariance for f in a], axis1=1, axis2=2))
                - np.sqrt(np.diagonal([f.covariance for f in b], axis1=1, axis2=2))
            )
        )
        < 2e-3
    )


def test_prediction_covariance_matches_monte_carlo() -> None:
    pose, P = Pose2(1.0, 2.0, 0.7), np.diag([0.01**2, 0.02**2, 0.05**2])
    delta = Pose2(0.5, 0.1, 0.2)
    Q = MotionModel().covariance(delta)
    _, P1 = compose_with_covariance(pose, P, delta, Q)
    rng = np.random.default_rng(0)
    a = rng.multivariate_normal(pose.as_array(), P, 20000)
    d = rng.multivariate_normal(delta.as_array(), Q, 20000)
    out = np.array([Pose2.from_array(x).compose(Pose2.from_array(y)).as_array() for x, y in zip(a, d, strict=True)])
    mc = np.cov(out.T)
    assert np.allclose(np.sqrt(np.diag(P1)), np.sqrt(np.diag(mc)), rtol=0.05)


def test_bad_motion_model_is_refused() -> None:
    with pytest.raises(InputError, match="motion"):
        ExtendedKalmanFilter(motion="5%")  # type: ignore[arg-type]

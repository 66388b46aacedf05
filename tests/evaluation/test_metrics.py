"""Metrics against hand computations and against calibrated / mis-calibrated Gaussian samples."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc import Estimate, InputError, Pose2
from factorloc.evaluation import metrics


def _random_spd(rng: np.random.Generator, n: int) -> np.ndarray:
    """N random 3×3 covariances with cm / degree scales and correlations."""
    a = rng.normal(size=(n, 3, 3)) * np.array([0.02, 0.02, 0.01])[:, None]
    return a @ np.transpose(a, (0, 2, 1)) + np.diag([1e-4, 1e-4, 1e-5])


def _gaussian_errors(rng: np.random.Generator, cov: np.ndarray) -> np.ndarray:
    chol = np.linalg.cholesky(cov)
    return np.einsum("nij,nj->ni", chol, rng.normal(size=(cov.shape[0], 3)))


def test_heading_error_is_wrapped_across_pi() -> None:
    err = metrics.pose_errors([Pose2(1.0, 2.0, math.pi - 0.01)], [Pose2(0.7, 2.4, -math.pi + 0.01)])
    np.testing.assert_allclose(err, [[0.3, -0.4, -0.02]], atol=1e-12)
    assert metrics.position_error_m(err)[0] == pytest.approx(0.5)
    assert metrics.heading_error_rad(err)[0] == pytest.approx(0.02)


def test_summary_matches_hand_computation_and_ignores_nan() -> None:
    s = metrics.summarize(np.array([3.0, -4.0, np.nan]))
    assert s.rmse == pytest.approx(math.sqrt(12.5))
    assert s.median == pytest.approx(3.5)
    assert s.p95 == pytest.approx(3.95)  # linear interpolation between 3 and 4
    assert s.max == 4.0 and s.count == 2
    empty = metrics.summarize(np.array([np.nan]))
    assert empty.count == 0 and math.isnan(empty.rmse)
    assert s.scaled(10.0).rmse == pytest.approx(10 * math.sqrt(12.5))


def test_nees_hand_computed_with_correlation_and_undetermined_components() -> None:
    cov_full = np.array([[0.04, 0.01, 0.0], [0.01, 0.02, 0.0], [0.0, 0.0, 0.01]])
    e_full = np.array([0.1, -0.1, 0.05])
    expected_full = float(e_full @ np.linalg.solve(cov_full, e_full))
    cov_heading = np.diag([np.inf, np.inf, 0.0004])
    e_heading = np.array([np.nan, np.nan, 0.04])  # position undetermined: ε = 0.04² / 0.0004 = 4
    values, dof = metrics.nees(np.array([e_full, e_heading]), np.array([cov_full, cov_heading]))
    assert values[0] == pytest.approx(expected_full) and dof[0] == 3
    assert values[1] == pytest.approx(4.0) and dof[1] == 1
    assert metrics.nees_mean(values, dof) == pytest.approx(expected_full)  # only the 3-dof result
    assert metrics.normalized_nees_mean(values, dof) == pytest.approx((expected_full / 3 + 4.0) / 2)


def test_a_calibrated_estimator_scores_nees_3_and_one_percent_outside_99() -> None:
    rng = np.random.default_rng(1)
    cov = _random_spd(rng, 20000)
    err = _gaussian_errors(rng, cov)
    values, dof = metrics.nees(err, cov)
    assert metrics.nees_mean(values, dof) == pytest.approx(3.0, abs=0.08)
    assert metrics.outside_ellipse(values, dof, 0.99).mean() == pytest.approx(0.01, abs=0.002)
    # diagonal covariances: P(any |e_i| > 3σ_i) = 1 − 0.9973³ ≈ 0.0081
    diag = np.zeros_like(cov)
    diag[:, [0, 1, 2], [0, 1, 2]] = np.diagonal(cov, axis1=1, axis2=2)
    err_d = _gaussian_errors(rng, diag)
    expected = 1 - (1 - 2 * 0.0013498980316301) ** 3
    assert metrics.confidently_wrong(err_d, diag).mean() == pytest.approx(expected, abs=0.002)


def test_an_overconfident_estimator_is_caught() -> None:
    rng = np.random.default_rng(2)
    cov = _random_spd(rng, 5000)
    err = 2.0 * _gaussian_errors(rng, cov)  # true errors twice the claimed σ
    values, dof = metrics.nees(err, cov)
    assert metrics.nees_mean(values, dof) == pytest.approx(12.0, rel=0.05)  # 4 × 3
    assert metrics.outside_ellipse(values, dof, 0.99).mean() > 0.2
    assert metrics.confidently_wrong(err, cov).mean() > 0.2


def test_confidently_wrong_needs_reliability_and_one_component_beyond_3_sigma() -> None:
    cov = np.array([np.diag([0.01, 0.01, 0.0001])] * 3)
    err = np.array([[0.29, 0.29, 0.029], [0.0, 0.0, 0.031], [0.0, 0.0, 0.031]])  # 2.9σ everywhere / 3.1σ in θ
    flags = metrics.confidently_wrong(err, cov, reliable=np.array([True, True, False]))
    assert flags.tolist() == [False, True, False]
    # default reliability: all three components determined
    cov_h = np.diag([np.inf, np.inf, 0.0001])[None]
    assert metrics.confidently_wrong(np.array([[np.nan, np.nan, 0.05]]), cov_h).tolist() == [False]


def test_estimate_embedding_marks_unmeasured_components() -> None:
    e = Estimate.position("icp", 1.0, 2.0, 0.1, 0.2)
    np.testing.assert_array_equal(np.isnan(metrics.values_of_estimate(e)), [False, False, True])
    cov = metrics.covariance_of_estimate(e)
    assert np.isinf(cov[2, 2]) and cov[1, 1] == pytest.approx(0.04)
    assert metrics.determined_mask(cov).tolist() == [[True, True, False]]


def test_bad_shapes_raise_input_errors() -> None:
    with pytest.raises(InputError, match="N×3"):
        metrics.pose_errors(np.zeros((2, 2)), np.zeros((2, 2)))
    with pytest.raises(InputError, match="N×3×3"):
        metrics.nees(np.zeros((2, 3)), np.zeros((3, 3, 3)))
    with pytest.raises(InputError, match="probability"):
        metrics.outside_ellipse(np.zeros(1), np.ones(1, dtype=int), 1.5)


def test_overlap_fraction_counts_query_points_near_reference_surfaces_in_the_plane() -> None:
    from factorloc.evaluation.metrics import overlap_fraction

    wall = np.column_stack([np.linspace(0.0, 4.0, 401), np.zeros(401), np.full(401, 1.0)])  # 1 cm spacing, z = 1 m
    # 30 points on the wall (other heights, 2 cm off it) and 10 on a wall the reference never saw
    seen = np.column_stack([np.linspace(0.5, 3.5, 30), np.full(30, 0.02), np.linspace(0.1, 2.0, 30)])
    unseen = np.column_stack([np.full(10, 6.0), np.linspace(0.0, 1.0, 10)])
    query = np.vstack([seen[:, :2], unseen])
    assert overlap_fraction(query, wall) == pytest.approx(0.75)
    assert overlap_fraction(query, wall, radius_m=0.01) == 0.0  # 2 cm off the wall: outside a 1 cm radius
    assert np.isnan(overlap_fraction(np.zeros((0, 2)), wall))
    with pytest.raises(InputError, match="radius_m"):
        overlap_fraction(query, wall, radius_m=0.0)

"""2D resection against exact synthetic ground truth: minimal solver, Gauss–Newton, RANSAC, NEES."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.vision import resection as rs


def _scene(rng, n, truth, spread_rad=2 * math.pi, r_range=(1.0, 5.0)):
    """``n`` points around ``truth`` within ``spread_rad`` of its heading, and their exact robot-frame bearings."""
    az = rng.uniform(-spread_rad / 2, spread_rad / 2, n)
    r = rng.uniform(*r_range, n)
    world = truth.theta + az
    pts = np.column_stack([truth.x + r * np.cos(world), truth.y + r * np.sin(world)])
    return pts, az


def _err(pose, truth):
    return np.array([pose.x - truth.x, pose.y - truth.y, math.remainder(pose.theta - truth.theta, 2 * math.pi)])


def test_minimal_solver_finds_the_exact_pose_among_its_candidates() -> None:
    rng = np.random.default_rng(1)
    for _ in range(200):
        truth = Pose2(rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-math.pi, math.pi))
        pts, b = _scene(rng, 3, truth)
        cand = rs.solve_minimal(pts, b)
        cand = cand[np.all(np.isfinite(cand), axis=1)]
        errs = [np.max(np.abs(_err(Pose2(*c), truth))) for c in cand]
        assert min(errs) < 1e-7
        for c in cand:  # every candidate fits the three bearings exactly
            assert np.max(np.abs(rs.bearing_residuals(pts, b, Pose2(*c)))) < 1e-7


def test_refine_is_exact_on_noise_free_bearings() -> None:
    rng = np.random.default_rng(2)
    for spread in (2 * math.pi, math.radians(57.0)):  # all round, and one 57° camera view
        truth = Pose2(1.3, -0.7, 2.4)
        pts, b = _scene(rng, 40, truth, spread)
        fit = rs.refine(pts, b, Pose2(truth.x + 0.3, truth.y - 0.2, truth.theta + 0.1))
        assert np.max(np.abs(_err(fit.pose, truth))) < 1e-9
        assert fit.residual_sigma_rad < 1e-9 and fit.n_inliers == 40


def test_ransac_is_exact_with_half_the_matches_false() -> None:
    rng = np.random.default_rng(3)
    truth = Pose2(-2.0, 0.5, -1.0)
    pts, b = _scene(rng, 60, truth, math.radians(90.0))
    b[:30] = rng.uniform(-math.pi, math.pi, 30)  # false matches
    fit = rs.ransac(pts, b, math.radians(0.5))
    assert np.max(np.abs(_err(fit.pose, truth))) < 1e-9
    assert fit.inliers[30:].all() and fit.inliers[:30].sum() <= 1  # a false bearing may fall within 0.5° by chance


@pytest.mark.parametrize("spread_deg", [360.0, 57.0])
def test_covariance_is_consistent_nees_about_3(spread_deg) -> None:
    """Bearings with Gaussian noise (0.3°): the residual-variance covariance gives NEES ≈ 3 (3 dof) over 400 draws."""
    rng = np.random.default_rng(4)
    nees = []
    for _ in range(400):
        truth = Pose2(rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-math.pi, math.pi))
        pts, b = _scene(rng, 30, truth, math.radians(spread_deg))
        noisy = b + rng.normal(0.0, math.radians(0.3), len(b))
        fit = rs.ransac(pts, noisy, math.radians(1.5))
        e = _err(fit.pose, truth)
        nees.append(float(e @ np.linalg.solve(fit.covariance, e)))
    mean = float(np.mean(nees))
    # χ²(3) has mean 3; the estimated σ̂² (27 dof) makes it a scaled F: mean 3·27/25 ≈ 3.24; 400 draws: ±0.3
    assert 2.6 < mean < 3.7, f"NEES {mean:.2f}"
    assert np.mean(np.array(nees) > 7.81) < 0.1  # χ²(3) 95 % quantile


def test_narrow_view_is_worse_conditioned_and_less_certain_than_all_round() -> None:
    rng = np.random.default_rng(5)
    truth = Pose2(0.0, 0.0, 0.0)
    out = {}
    for spread in (2 * math.pi, math.radians(30.0)):
        pts, b = _scene(rng, 40, truth, spread)
        noisy = b + rng.normal(0.0, math.radians(0.2), len(b))
        out[spread] = rs.refine(pts, noisy, truth)
    wide, narrow = out[2 * math.pi], out[math.radians(30.0)]
    assert narrow.condition > 10 * wide.condition
    assert narrow.sigma_position_m > 3 * wide.sigma_position_m


def test_a_mirror_pose_is_reported_as_runner_up_support() -> None:
    """Two disjoint point sets consistent with two different poses: the weaker one's support is the runner-up."""
    rng = np.random.default_rng(6)
    a, b_pose = Pose2(0.0, 0.0, 0.0), Pose2(1.0, 0.5, 0.3)
    pa, ba = _scene(rng, 30, a)
    pb, bb = _scene(rng, 18, b_pose)
    fit = rs.ransac(np.vstack([pa, pb]), np.concatenate([ba, bb]), math.radians(0.3), hypotheses=512, sigma_floor_rad=1e-4)
    assert np.max(np.abs(_err(fit.pose, a))) < 1e-9
    assert 17 <= fit.runner_up <= 20


def test_heading_given_position_from_two_bearings() -> None:
    pts = np.array([[3.0, 1.0], [-1.0, 2.0]])
    p, theta = (0.5, -0.5), 0.7
    b = np.arctan2(pts[:, 1] - p[1], pts[:, 0] - p[0]) - theta
    th, sigma = rs.heading_given_position(pts, b, p)
    assert abs(math.remainder(th - theta, 2 * math.pi)) < 1e-12 and sigma < 1e-12
    with pytest.raises(InputError, match="2 bearings"):
        rs.heading_given_position(pts[:1], b[:1], p)


def test_bad_inputs_raise_typed_errors() -> None:
    with pytest.raises(InputError, match="N×2"):
        rs.refine(np.zeros((4, 3)), np.zeros(4), Pose2(0, 0, 0))
    with pytest.raises(InputError, match="one bearing per point"):
        rs.ransac(np.zeros((4, 2)), np.zeros(3), 0.01)
    assert rs.ransac(np.ones((2, 2)), np.zeros(2), 0.01) is None  # too few bearings: no pose


def test_an_undetermined_pose_is_refused_not_returned() -> None:
    """All points on one ray from the robot: the position along it is not determined — no pose, no crash."""
    pts = np.column_stack([np.linspace(1.0, 5.0, 10), np.zeros(10)])
    b = np.zeros(10)
    assert rs.refine(pts, b, Pose2(0.0, 0.0, 0.0), jackknife=True) is None
    assert rs.ransac(pts, b, 0.01) is None


def test_bearings_without_any_consensus_draw_every_hypothesis_and_give_no_confident_pose() -> None:
    rng = np.random.default_rng(8)
    pts = rng.uniform(-5.0, 5.0, (200, 2))
    b = rng.uniform(-math.pi, math.pi, 200)
    fit = rs.ransac(pts, b, 1e-4, min_inliers=12)  # 12 random bearings never agree within 0.006°
    assert fit is None


def _outlier_scene(rng, n, outlier_share, noise_rad=0.002):
    truth = Pose2(rng.uniform(-3, 3), rng.uniform(-3, 3), rng.uniform(-math.pi, math.pi))
    pts, b = _scene(rng, n, truth, math.radians(rng.uniform(40.0, 360.0)), (0.5, 6.0))
    b = b + rng.normal(0.0, noise_rad, n)
    out = rng.random(n) < outlier_share
    b[out] = rng.uniform(-math.pi, math.pi, int(out.sum()))
    return truth, pts, b, out


def test_compiled_ransac_agrees_with_the_numpy_reference() -> None:
    """The compiled RANSAC (closed-form cubic, written-out 3×3 LU, sums in index order) and the NumPy reference
    draw the same minimal sets: on 150 noisy scenes with 0–60 % false bearings the same inliers, the same rival
    support, the same refusals, and poses, covariances and condition numbers within 1e-9 (relative to the
    largest entry) — they differ in rounding only."""
    rng = np.random.default_rng(11)
    fits = 0
    for _ in range(150):
        _, pts, b, _ = _outlier_scene(rng, int(rng.integers(6, 120)), rng.uniform(0.0, 0.6))
        ref = rs.ransac(pts, b, 0.015, compiled=False)
        got = rs.ransac(pts, b, 0.015)
        assert (ref is None) == (got is None)
        if ref is None:
            continue
        fits += 1
        assert np.array_equal(ref.inliers, got.inliers)
        assert ref.runner_up == got.runner_up
        assert np.max(np.abs(_err(ref.pose, got.pose))) < 1e-9
        scale = np.max(np.abs(ref.covariance))
        assert np.max(np.abs(ref.covariance - got.covariance)) <= 1e-9 * scale
        assert abs(ref.condition - got.condition) <= 1e-9 * ref.condition
        assert abs(ref.residual_sigma_rad - got.residual_sigma_rad) <= 1e-9 * ref.residual_sigma_rad
    assert fits >= 120


def test_compiled_ransac_finds_the_truth_with_false_bearings() -> None:
    """Noise 0.1° and 40 % false bearings: the compiled RANSAC's pose is within 5 σ of the truth, keeps the true
    bearings (≥ 95 %) and at most a few false ones that fall within the threshold by chance."""
    rng = np.random.default_rng(12)
    for _ in range(40):
        truth, pts, b, out = _outlier_scene(rng, 80, 0.4)
        fit = rs.ransac(pts, b, 0.015)
        e = _err(fit.pose, truth)
        assert float(e @ np.linalg.solve(fit.covariance, e)) < 25.0
        assert fit.inliers[~out].mean() >= 0.95
        assert fit.inliers[out].sum() <= 3


def test_compiled_refine_agrees_with_the_numpy_reference_with_weights_and_jackknife() -> None:
    rng = np.random.default_rng(13)
    for _ in range(50):
        truth, pts, b, _ = _outlier_scene(rng, 40, 0.0, noise_rad=0.003)
        w = rng.uniform(0.2, 1.0, 40)
        groups = rng.integers(0, 8, 40)
        start = Pose2(truth.x + 0.1, truth.y - 0.1, truth.theta + 0.05)
        kw = dict(weights=w, sigma_floor_rad=1e-3, jackknife=True, groups=groups)
        ref = rs.refine(pts, b, start, compiled=False, **kw)
        got = rs.refine(pts, b, start, **kw)
        assert np.max(np.abs(_err(ref.pose, got.pose))) < 1e-12
        assert np.max(np.abs(ref.covariance - got.covariance)) <= 1e-9 * np.max(np.abs(ref.covariance))
        assert abs(ref.condition - got.condition) <= 1e-9 * ref.condition


def test_compiled_minimal_cubic_finds_every_exact_pose() -> None:
    """The compiled batch's candidates include the truth (to 1e-7) for exact bearings, as the reference's do."""
    from factorloc.vision._kernels import resection_hypotheses

    rng = np.random.default_rng(14)
    for _ in range(200):
        truth = Pose2(rng.uniform(-5, 5), rng.uniform(-5, 5), rng.uniform(-math.pi, math.pi))
        pts, b = _scene(rng, 3, truth)
        cand, cost, count, special = resection_hypotheses(pts, b, np.array([[0, 1, 2]]), 1e-6)
        if special[0]:
            continue
        assert min(np.max(np.abs(_err(Pose2(*c), truth))) for c in cand) < 1e-7
        assert count == 3 and np.all(cost < 1e-12)


def test_compiled_ransac_hands_the_sets_with_theta_a_right_angle_to_the_reference_solver() -> None:
    """A heading of exactly π/2 makes the cubic's t³ term vanish (tan θ = ∞): those sets are solved by the
    reference solver; both paths still find the exact pose and agree."""
    from factorloc.vision._kernels import resection_hypotheses

    rng = np.random.default_rng(15)
    truth = Pose2(0.5, -0.3, math.pi / 2)
    pts, b = _scene(rng, 20, truth, math.radians(120.0))
    assert resection_hypotheses(pts, b, np.array([[0, 1, 2], [3, 4, 5]]), 0.01)[3].all()
    ref, got = rs.ransac(pts, b, 0.01, compiled=False), rs.ransac(pts, b, 0.01)
    assert np.max(np.abs(_err(got.pose, truth))) < 1e-9
    assert np.array_equal(ref.inliers, got.inliers) and got.n_inliers == 20
    assert np.max(np.abs(_err(ref.pose, got.pose))) < 1e-12

"""Issue #21, reproducers 1–4, 7 and 9: σ within the documented range, fields of view away from 0 and π,
θ strictly in [-π, π), strings are not numbers, ``reliable`` a JSON boolean — each a typed error naming the field."""

from __future__ import annotations

import math

import numpy as np
import pytest

import factorloc as fl
from factorloc._validate import MAX_COORDINATE_M, SIGMA_MAX, SIGMA_MIN, number_problem
from factorloc.errors import InputError
from factorloc.geometry import wrap_angle


def test_tiny_sigma_is_rejected_naming_the_field():  # reproducer 1
    with pytest.raises(InputError, match=r"sigma_theta_rad must be a standard deviation in \[1e-09, 1e\+06\]"):
        fl.Estimate.pose("a", fl.Pose2(-7.49, -1, 0), 0.1, 1e-6, 1e-160)


@pytest.mark.parametrize("sigmas", [(1e9, 1e150, 10.0), (1e150, 1e-18, 1e-3)])
def test_sigmas_outside_the_range_are_rejected(sigmas):  # reproducer 2's inputs
    with pytest.raises(InputError, match="sigma_x_m"):
        fl.Estimate.pose("a", fl.Pose2(1, 1, 1), *sigmas)


def test_sigma_range_bounds_are_inclusive():
    e = fl.Estimate.pose("a", fl.Pose2(1, 1, 1), SIGMA_MIN, SIGMA_MAX, 1.0)
    assert e.sigmas.tolist() == [SIGMA_MIN, SIGMA_MAX, 1.0]
    with pytest.raises(InputError):
        fl.Estimate.heading("a", 0.0, np.nextafter(SIGMA_MIN, 0.0))


def test_huge_sigma_gives_an_error_not_an_infinite_covariance():  # reproducer 3
    with pytest.raises(InputError, match="sigma_theta_rad"):
        fl.Estimate.heading("a", 0, 1e154)
    with pytest.raises(InputError, match=r"covariance\[0\]\[0\]"):
        fl.Estimate("a", ("theta",), [0.0], [[1e308]])
    with pytest.raises(InputError, match="Odometry.sigma_x_m"):
        fl.Odometry(fl.Pose2(), 1e154, 0.1, 0.1)


def test_covariance_with_a_correlation_of_one_is_rejected():
    c = np.array([[1.0, 1.0 - 1e-15], [1.0 - 1e-15, 1.0]])
    with pytest.raises(InputError, match="too close to singular"):
        fl.Estimate.position("icp", 0.0, 0.0, covariance=c)
    ok = fl.Estimate.position("icp", 0.0, 0.0, covariance=[[1.0, 0.9], [0.9, 1.0]])
    assert ok.covariance[0, 1] == 0.9


def test_correlation_check_agrees_with_the_eigenvalue_on_near_singular_covariances():
    """The check skips ``eigvalsh`` when the pivots bound the correlation's smallest eigenvalue far above the limit:
    on 3×3 covariances from well correlated to singular, it rejects exactly those whose correlation matrix has an
    eigenvalue below MIN_CORRELATION_EIGENVALUE (away from the limit: either answer is right within rounding)."""
    from factorloc._validate import MIN_CORRELATION_EIGENVALUE

    rng = np.random.default_rng(5)
    rejected = accepted = 0
    for gap in np.geomspace(1e-16, 0.5, 400):
        a = rng.normal(size=(3, 3))
        u, _, vt = np.linalg.svd(a)
        cov = (u * np.array([1.0, 0.5, gap])) @ u.T * rng.uniform(1e-6, 1e2)
        cov = 0.5 * (cov + cov.T)
        s = 1.0 / np.sqrt(np.diag(cov))
        lam = float(np.linalg.eigvalsh(cov * np.outer(s, s))[0])
        if abs(lam - MIN_CORRELATION_EIGENVALUE) < 1e-13 or lam <= 1e-14:
            continue  # at the limit or numerically singular (the positive-definite test may answer first)
        try:
            fl.Estimate("icp", ("x", "y", "theta"), [0.0, 0.0, 0.0], cov)
            assert lam >= MIN_CORRELATION_EIGENVALUE
            accepted += 1
        except InputError as exc:
            assert lam < MIN_CORRELATION_EIGENVALUE, exc
            rejected += 1
    assert rejected >= 10 and accepted >= 300


@pytest.mark.parametrize("hfov", [5e-324, 1e-6, math.pi - 1e-6, math.pi])
def test_camera_hfov_is_bounded_away_from_zero_and_pi(hfov):  # reproducer 4
    with pytest.raises(InputError, match="CameraImage.hfov_rad"):
        fl.CameraImage(np.zeros((8, 8, 3), np.uint8), hfov_rad=hfov)


def test_panorama_fov_is_bounded_away_from_zero():
    with pytest.raises(InputError, match="Panorama.fov_v_rad"):
        fl.Panorama(np.zeros((8, 16, 3), np.uint8), fov_v_rad=1e-300)


def test_theta_is_wrapped_strictly_below_pi():  # reproducer 9
    just_below = np.nextafter(-math.pi, -4.0)
    assert fl.Pose2(0, 0, just_below).theta == -math.pi
    assert wrap_angle(just_below) == -math.pi
    arr = wrap_angle(np.array([just_below, math.pi, -math.pi, 3 * math.pi]))
    assert np.all(arr >= -math.pi) and np.all(arr < math.pi)
    assert fl.Pose2(0, 0, 0.5).theta == 0.5


def test_pose_from_array_rejects_strings_like_the_constructor():  # reproducer 9
    with pytest.raises(InputError):
        fl.Pose2("1.0")  # type: ignore[arg-type]
    with pytest.raises(InputError, match="Pose2.from_array"):
        fl.Pose2.from_array(["1", "2", "3"])
    with pytest.raises(InputError, match="Pose2.from_array"):
        fl.Pose2.from_array([True, False, True])
    assert fl.Pose2.from_array(np.array([1, 2, 0])).as_array().tolist() == [1.0, 2.0, 0.0]


@pytest.mark.parametrize("value", ["false", "true", 0, 1, None])
def test_reliable_must_be_a_json_boolean(value):  # reproducer 7
    d = {"step": "a", "components": ["theta"], "values": [0.0], "sigmas": [0.1], "reliable": value}
    with pytest.raises(InputError, match=r"Estimate\(a\).reliable must be a JSON boolean"):
        fl.Estimate.from_dict(d)
    d["reliable"] = False
    assert fl.Estimate.from_dict(d).reliable is False


def test_huge_integers_are_a_problem_not_an_overflow():
    assert "finite" in number_problem(10**400)
    assert len(number_problem(10**400)) < 200  # the value is shortened in the message


def test_position_estimates_stay_within_the_documented_coordinate_range():
    # at 1e16 m the spacing of doubles is 2 m: a σ of 1 m there was reported as if it held
    with pytest.raises(InputError, match=r"beyond the documented coordinate range ±1e\+09 m"):
        fl.Estimate.position("a", 1e16, 0.0, 1.0, 1.0)
    with pytest.raises(InputError, match="coordinate range"):
        fl.Estimate.pose("a", fl.Pose2(0.0, -1e300, 0.0), 1.0, 1.0, 1.0)
    assert fl.Estimate.position("a", MAX_COORDINATE_M, -MAX_COORDINATE_M, 1.0, 1.0).values.tolist() == [1e9, -1e9]

"""SE(2) maths against GTSAM's Pose2, and angle wrapping."""

from __future__ import annotations

import math

import gtsam
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from factorloc import InputError, Pose2, wrap_angle
from factorloc.geometry import rotate_covariance

coord = st.floats(min_value=-100, max_value=100)
angle = st.floats(min_value=-10, max_value=10)
poses = st.builds(Pose2, coord, coord, angle)


@given(st.floats(min_value=-1e6, max_value=1e6))
def test_wrap_angle_lands_in_half_open_interval_and_keeps_the_direction(a: float) -> None:
    w = wrap_angle(a)
    assert -math.pi <= w < math.pi
    assert math.isclose(math.cos(w), math.cos(a), abs_tol=1e-9) and math.isclose(math.sin(w), math.sin(a), abs_tol=1e-9)


def test_wrap_angle_of_pi_is_minus_pi_and_arrays_work() -> None:
    assert wrap_angle(math.pi) == -math.pi
    assert np.allclose(wrap_angle(np.array([0.0, 2 * math.pi + 0.1, -3 * math.pi])), [0.0, 0.1, -math.pi])


@given(poses, poses)
def test_compose_inverse_between_match_gtsam(a: Pose2, b: Pose2) -> None:
    ga, gb = a.to_gtsam(), b.to_gtsam()
    for ours, theirs in ((a * b, ga.compose(gb)), (a.inverse(), ga.inverse()), (a.between(b), ga.between(gb))):
        assert np.allclose([ours.x, ours.y], [theirs.x(), theirs.y()], atol=1e-9)
        assert abs(wrap_angle(ours.theta - theirs.theta())) < 1e-9


@given(poses)
def test_gtsam_round_trip_and_point_transform(p: Pose2) -> None:
    assert Pose2.from_gtsam(p.to_gtsam()) == p
    pts = np.array([[1.0, 2.0], [-3.0, 0.5]])
    expected = np.array([p.to_gtsam().transformFrom(gtsam.Point2(*pt)) for pt in pts])
    assert np.allclose(p.transform_points(pts), expected, atol=1e-9)


def test_rotate_covariance_round_trip() -> None:
    cov = np.array([[4.0, 1.0, 0.1], [1.0, 2.0, -0.2], [0.1, -0.2, 0.5]])
    back = rotate_covariance(rotate_covariance(cov, 0.7), -0.7)
    assert np.allclose(back, cov, atol=1e-12)


@pytest.mark.parametrize("field,value", [("x", float("nan")), ("y", float("inf")), ("theta", "1.0"), ("x", None)])
def test_pose2_rejects_non_finite_or_non_numeric(field: str, value: object) -> None:
    kwargs = {"x": 0.0, "y": 0.0, "theta": 0.0, field: value}
    with pytest.raises(InputError, match=f"Pose2.{field}"):
        Pose2(**kwargs)

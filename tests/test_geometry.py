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


def test_rotate_covariance_is_the_matrix_product_and_exactly_symmetric() -> None:
    # against R Σ Rᵀ by numpy (BLAS) on random covariances of every scale: the same to rounding, symmetric bit for
    # bit, and a turn by 0 returns the (symmetric) input unchanged
    rng = np.random.default_rng(9)
    for _ in range(500):
        J = rng.normal(size=(6, 3)) * 10.0 ** rng.uniform(-4, 1, size=3)
        cov, theta = J.T @ J, float(rng.uniform(-4.0, 4.0))
        c, s = math.cos(theta), math.sin(theta)
        r = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        expected = r @ cov @ r.T
        got = rotate_covariance(cov, theta)
        scale = np.sqrt(np.outer(np.diag(expected), np.diag(expected)))
        assert np.max(np.abs(got - expected) / scale) < 1e-13
        assert np.array_equal(got, got.T)
    sym = 0.5 * (cov + cov.T)
    assert np.array_equal(rotate_covariance(sym, 0.0), sym)


@pytest.mark.parametrize("field,value", [("x", float("nan")), ("y", float("inf")), ("theta", "1.0"), ("x", None)])
def test_pose2_rejects_non_finite_or_non_numeric(field: str, value: object) -> None:
    kwargs = {"x": 0.0, "y": 0.0, "theta": 0.0, field: value}
    with pytest.raises(InputError, match=f"Pose2.{field}"):
        Pose2(**kwargs)


def test_scalar_wrap_is_bit_for_bit_the_array_form() -> None:
    """The scalar case (plain floats) gives the bits of the numpy form, at the edges too (±π, 2π, tiny, huge)."""
    rng = np.random.default_rng(7)
    edges = np.array([math.pi, -math.pi, 2 * math.pi, -2 * math.pi, 3 * math.pi, 0.0, -0.0, 1e-300, -1e-300, 1e300, -1e300])
    values = np.concatenate(
        [
            rng.uniform(-10, 10, 20000),
            rng.uniform(-1e6, 1e6, 2000),
            edges,
            np.nextafter(edges, np.inf),
            np.nextafter(edges, -np.inf),
        ]
    )
    scalar = [wrap_angle(float(v)) for v in values]
    array = wrap_angle(values)
    assert all(isinstance(s, float) for s in scalar)
    assert np.array_equal(np.array(scalar), array)
    assert [math.copysign(1.0, s) for s in scalar] == np.copysign(1.0, array).tolist()


def test_pose2_fast_path_is_the_validated_one() -> None:
    """Finite floats take the short path (θ wrapped only); other numbers the checked one: the same pose."""
    p = Pose2(1.5, -2.0, 4.0)
    q = Pose2(np.float64(1.5), 2 - 4, np.float64(4.0))  # numpy scalars and an int: converted by the checks
    assert (p.x, p.theta) == (q.x, q.theta) and q.y == -2.0 and type(q.y) is float and type(q.x) is float
    assert p.theta == wrap_angle(4.0)
    with pytest.raises(InputError, match="Pose2.y"):
        Pose2(0.0, math.inf, 0.0)
    with pytest.raises(InputError, match="Pose2.x"):
        Pose2(math.nan, 0.0, 0.0)
    big = Pose2(1e308, 1e308, 0.0)  # the sum overflows: the checked path, which accepts it
    assert big.x == 1e308

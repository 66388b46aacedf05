"""Fuzz: the public constructors take any value and either build an honest object or raise naming the field."""

from __future__ import annotations

import math

import numpy as np
from fuzzkit import SilentResultError, assert_no_defect, classify, fuzz_settings
from hypothesis import given
from hypothesis import strategies as st

import factorloc as fl
from factorloc._validate import SIGMA_MAX, SIGMA_MIN

#: Anything a caller might pass where a number is expected.
ANY_NUMBER = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-1e6, max_value=1e6),
    st.floats(min_value=1e-12, max_value=1e8).map(lambda v: v),
    st.integers(min_value=-(10**400), max_value=10**400),
    st.sampled_from([0, 1, -1, 5e-324, 1e-160, 1e154, 1e308, math.pi, -math.pi, np.nextafter(-math.pi, -4.0)]),
    st.text(max_size=5),
    st.booleans(),
    st.none(),
    st.just(np.float32(0.25)),
    st.lists(st.floats(), max_size=2),
)


def _finite_pose(p: fl.Pose2) -> None:
    if not all(math.isfinite(v) for v in (p.x, p.y, p.theta)) or not -math.pi <= p.theta < math.pi:
        raise SilentResultError(f"pose {p!r} not finite or θ outside [-π, π)")


def _honest_estimate(e: fl.Estimate) -> None:
    s = e.sigmas
    if not (np.isfinite(e.values).all() and np.all(s >= SIGMA_MIN * (1 - 1e-12)) and np.all(s <= SIGMA_MAX * (1 + 1e-12))):
        raise SilentResultError(f"estimate values {e.values} σ {s}")


@fuzz_settings(default=60, fuzz=2500)
@given(x=ANY_NUMBER, y=ANY_NUMBER, t=ANY_NUMBER)
def test_pose2(x, y, t):
    outcome = classify("constructors.Pose2", ("Pose2",), lambda: fl.Pose2(x, y, t), _finite_pose)
    assert_no_defect(outcome, f"Pose2({x!r}, {y!r}, {t!r})")
    outcome = classify("constructors.Pose2", ("Pose2",), lambda: fl.Pose2.from_array([x, y, t]), _finite_pose)
    assert_no_defect(outcome, f"Pose2.from_array([{x!r}, {y!r}, {t!r}])")


@fuzz_settings(default=60, fuzz=2500)
@given(kind=st.sampled_from(["heading", "position", "pose"]), a=ANY_NUMBER, b=ANY_NUMBER, c=ANY_NUMBER, v=ANY_NUMBER)
def test_estimate_builders(kind, a, b, c, v):
    def build() -> fl.Estimate:
        if kind == "heading":
            return fl.Estimate.heading("s", v, a)
        if kind == "position":
            return fl.Estimate.position("s", v, 0.0, a, b)
        return fl.Estimate.pose("s", fl.Pose2(0.0, 0.0, 0.0), a, b, c)

    outcome = classify("constructors.Estimate", ("Estimate(s)",), build, _honest_estimate)
    assert_no_defect(outcome, f"Estimate.{kind}(v={v!r}, σ={a!r}, {b!r}, {c!r})")


@fuzz_settings(default=40, fuzz=1500)
@given(
    cov=st.lists(st.lists(st.floats(allow_nan=True, allow_infinity=True), min_size=2, max_size=2), min_size=2, max_size=2),
    reliable=st.one_of(st.booleans(), st.text(max_size=5), st.integers(0, 1), st.none()),
)
def test_estimate_from_dict(cov, reliable):
    data = {"step": "s", "components": ["x", "y"], "values": [0.0, 0.0], "covariance": cov, "reliable": reliable}
    outcome = classify("constructors.Estimate.from_dict", ("Estimate(s)",), lambda: fl.Estimate.from_dict(data), _honest_estimate)
    assert_no_defect(outcome, f"Estimate.from_dict({data!r})")


@fuzz_settings(default=40, fuzz=1500)
@given(sx=ANY_NUMBER, st_=ANY_NUMBER, hfov=ANY_NUMBER, n=st.integers(0, 6), scale=st.sampled_from([1.0, 1e9, 1e200, np.nan]))
def test_sensors(sx, st_, hfov, n, scale):
    outcome = classify("constructors.Odometry", ("Odometry",), lambda: fl.Odometry(fl.Pose2(), sx, 0.1, st_))
    assert_no_defect(outcome, f"Odometry σ {sx!r}, {st_!r}")
    img = np.zeros((8, 8, 3), np.uint8)
    outcome = classify("constructors.CameraImage", ("CameraImage",), lambda: fl.CameraImage(img, hfov_rad=hfov))
    assert_no_defect(outcome, f"CameraImage(hfov_rad={hfov!r})")
    pts = np.arange(2.0 * n).reshape(n, 2) * scale
    outcome = classify("constructors.Scan", ("Scan",), lambda: fl.Scan(pts))
    assert_no_defect(outcome, f"Scan of {n} points × {scale}")

"""Fuzz: ``fuse`` of valid estimates whose σ span the whole documented range never lets an exception escape and
never returns a σ smaller than the inputs support (or NaN)."""

from __future__ import annotations

import math

import numpy as np
from fuzzkit import SilentResultError, assert_no_defect, classify, fuzz_settings
from hypothesis import given
from hypothesis import strategies as st

import factorloc as fl
from factorloc._validate import SIGMA_MAX, SIGMA_MIN
from factorloc.fusion import ProductFusion

SIGMA = st.floats(min_value=math.log10(SIGMA_MIN), max_value=math.log10(SIGMA_MAX)).map(lambda e: 10.0**e)
VALUE = st.one_of(st.floats(min_value=-1e6, max_value=1e6), st.sampled_from([0.0, math.pi, -math.pi, 1e6]))


@st.composite
def estimates(draw):  # noqa: ANN001, ANN201
    out = []
    for i in range(draw(st.integers(1, 6))):
        kind = draw(st.sampled_from(["heading", "position", "pose", "correlated"]))
        step = f"e{i}"
        if kind == "heading":
            out.append(fl.Estimate.heading(step, draw(VALUE), draw(SIGMA)))
        elif kind == "position":
            out.append(fl.Estimate.position(step, draw(VALUE), draw(VALUE), draw(SIGMA), draw(SIGMA)))
        elif kind == "pose":
            out.append(
                fl.Estimate.pose(step, fl.Pose2(draw(VALUE), draw(VALUE), draw(VALUE)), draw(SIGMA), draw(SIGMA), draw(SIGMA))
            )
        else:
            sx, sy, rho = draw(SIGMA), draw(SIGMA), draw(st.floats(-0.99, 0.99))
            cov = [[sx * sx, rho * sx * sy], [rho * sx * sy, sy * sy]]
            out.append(fl.Estimate.position(step, draw(VALUE), draw(VALUE), covariance=cov))
    return out


def _honest(inputs: list[fl.Estimate]):  # noqa: ANN202
    def check(loc: fl.Localization) -> None:
        cov = loc.covariance
        if not all(math.isfinite(v) for v in loc.pose.as_array()):
            raise SilentResultError(f"fused pose {loc.pose!r}")
        diag = np.diag(cov)
        if np.isnan(cov).any() or np.any(diag <= 0.0):
            raise SilentResultError(f"fused covariance diagonal {diag}")
        # the fused information of a component never exceeds the sum of its inputs' (the diagonal of Σ Λᵢ, an
        # upper bound whatever the gate drops): so its variance is at least 1 / that, to 1e-4 relative
        info = np.zeros(3)
        for e in inputs:
            idx = [("x", "y", "theta").index(c.value) for c in e.components]
            info[idx] += np.diag(np.linalg.inv(e.covariance))
        for i, comp in enumerate(("x", "y", "theta")):
            if info[i] > 0.0 and math.isfinite(diag[i]) and diag[i] < (1.0 - 1e-4) / info[i]:
                raise SilentResultError(
                    f"σ{comp} {math.sqrt(diag[i]):.3g} below what its inputs support {1 / math.sqrt(info[i]):.3g}"
                )

    return check


@fuzz_settings(default=60, fuzz=2500)
@given(ests=estimates(), product=st.booleans())
def test_fuse(ests, product):
    strategy = ProductFusion() if product else None
    names = tuple(e.step for e in ests)
    outcome = classify("fuse", names, lambda: fl.fuse(ests, strategy=strategy), _honest(ests))
    assert_no_defect(outcome, f"fuse({[(e.step, e.kind, e.values.tolist(), e.sigmas.tolist()) for e in ests]})")

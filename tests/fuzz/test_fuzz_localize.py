"""Fuzz: ``localize`` on degenerate geometry — collinear, co-located, round, sparse, far-away or huge scans, with
odometry — never lets an exception escape and never returns NaN or a zero σ."""

from __future__ import annotations

import math

import numpy as np
from fuzzkit import SilentResultError, assert_no_defect, classify, fuzz_settings
from hypothesis import given
from hypothesis import strategies as st

import factorloc as fl

SHAPES = ("line", "point", "circle", "random", "two_points", "room")


def _scan(shape: str, n: int, scale: float, offset: float, rng: np.random.Generator) -> np.ndarray:
    t = np.linspace(0.0, 1.0, n)
    if shape == "line":
        pts = np.stack([t - 0.5, np.zeros(n)], axis=1)
    elif shape == "point":
        pts = np.zeros((n, 2))
    elif shape == "circle":
        a = 2.0 * math.pi * t
        pts = np.stack([np.cos(a), np.sin(a)], axis=1)
    elif shape == "two_points":
        pts = np.repeat([[0.0, 0.0], [1.0, 0.0]], (n + 1) // 2, axis=0)[:n]
    elif shape == "room":
        k = max(n // 3, 1)
        u = np.linspace(0.0, 1.0, k)
        pts = np.concatenate([np.stack([u, 0 * u], 1), np.stack([0 * u + 1, u], 1), np.stack([u, 0 * u + 1], 1)])[:n]
    else:
        pts = rng.uniform(-1.0, 1.0, (n, 2))
    return pts * scale + offset + rng.normal(0.0, 1e-3, pts.shape)


def _honest(loc: fl.Localization) -> None:
    cov = loc.covariance
    if not all(math.isfinite(v) for v in loc.pose.as_array()) or np.isnan(cov).any() or np.any(np.diag(cov) <= 0.0):
        raise SilentResultError(f"pose {loc.pose!r} covariance diagonal {np.diag(cov)}")
    for r in loc.steps:
        if r.status is fl.StepStatus.SKIPPED and r.reason == "inputs absent" and r.name == "icp":
            raise SilentResultError("icp skipped as 'inputs absent' though both scans were given")


@fuzz_settings(default=12, fuzz=600)
@given(
    ref_shape=st.sampled_from(SHAPES),
    q_shape=st.sampled_from(SHAPES),
    n=st.sampled_from([1, 3, 5, 40, 200]),
    scale=st.sampled_from([1e-6, 1.0, 5.0, 1e3]),
    offset=st.sampled_from([0.0, 3.0, 1e5, 2e9]),
    odo=st.tuples(st.floats(-1e6, 1e6), st.floats(-10, 10), st.floats(-4, 4)),
    seed=st.integers(0, 2**16),
)
def test_localize_on_degenerate_scans(ref_shape, q_shape, n, scale, offset, odo, seed):
    rng = np.random.default_rng(seed)

    def run() -> fl.Localization:
        ref = fl.Reference(scan=fl.Scan(_scan(ref_shape, max(n, 3), scale, offset, rng)))
        q = fl.Query(scan=fl.Scan(_scan(q_shape, n, scale, 0.0, rng)), odometry=fl.Odometry(fl.Pose2(*odo), 0.2, 0.2, 0.1))
        return fl.localize(ref, q)

    outcome = classify("localize.degenerate", ("Scan", "Reference", "Query", "icp"), run, _honest)
    assert_no_defect(outcome, f"{ref_shape} vs {q_shape}, n={n}, scale={scale}, offset={offset}, odometry={odo}")

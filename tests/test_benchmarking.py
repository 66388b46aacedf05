"""Smoke test of the benchmarks on a tiny synthetic room (scans + odometry): they run and their numbers make sense."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from factorloc import Estimate, Odometry, Pose2, Query, Reference, Scan
from factorloc.benchmarking import BenchSettings, fit_exponent, run_bench, scaled_set
from factorloc.estimators.base import Hypotheses
from factorloc.evaluation import Case, EvaluationSet

_SEGMENTS = [
    ((0, 0), (5, 0)),
    ((5, 0), (5, 4)),
    ((5, 4), (0, 4)),
    ((0, 4), (0, 0)),
    ((2, 1.5), (3, 1.5)),
    ((3, 1.5), (3, 2.2)),
    ((3, 2.2), (2, 2.2)),
    ((2, 2.2), (2, 1.5)),
]


def _room(rng: np.random.Generator, per_m: int = 30) -> np.ndarray:
    """Points sampled on the walls of a 5×4 m room with a box (world frame, m)."""
    pts = []
    for a, b in _SEGMENTS:
        a, b = np.array(a, float), np.array(b, float)
        t = rng.uniform(0, 1, int(np.linalg.norm(b - a) * per_m))[:, None]
        pts.append(a + t * (b - a))
    return np.vstack(pts)


@pytest.fixture(scope="module")
def room() -> EvaluationSet:
    rng = np.random.default_rng(3)
    T_ref = Pose2(1.0, 1.0, 0.3)
    ref = Reference(scan=Scan(T_ref.inverse().transform_points(_room(rng))), T_world_reference=T_ref)
    cases = []
    for i in range(3):
        T = Pose2(rng.uniform(0.6, 1.4), rng.uniform(0.6, 3.4), rng.uniform(-3, 3))
        odo = Odometry(Pose2(T.x + 0.04, T.y - 0.03, T.theta + 0.02), 0.05, 0.05, 0.03)
        cases.append(Case(Query(scan=Scan(T.inverse().transform_points(_room(rng))), odometry=odo, id=f"q{i}"), T))
    return EvaluationSet(ref, tuple(cases), name="room")


def test_bench_runs_end_to_end_and_reports_every_section(room: EvaluationSet) -> None:
    out = run_bench(room, settings=BenchSettings(repeats=1, fusion_repeats=2, cost_factors=(0.5, 1.0), cost_queries=2))
    json.dumps(out, allow_nan=False)
    assert out["queries"] == 3 and out["localize"]["median_ms"] > 0
    assert out["localize"]["steps"]["compass"]["median_ms"] is None  # skipped everywhere: no images
    h = out["hierarchy"]
    assert h["time_ratio"] > 0 and h["seeded"]["queries_with_truth"] == 3
    assert h["seeded"]["steps_reliable_rate"]["icp"] == 1.0 and h["seeded"]["position_rmse_m"] < 0.02
    icp = out["icp_vs_open3d"]
    assert icp["pairs"] == 3 and icp["ours_median_error_m"] < 0.02 and icp["open3d_median_error_m"] < 0.05
    f = out["fusion"]
    assert f["queries"] == 3 and f["queries_with_cross_covariance"] == 3  # ICP's covariance couples x, y, θ
    assert f["max_position_diff_m_cross_covariance"] < 1e-3
    cc = out["cost_curve"]
    m = len(room.reference_of(room.cases[0]).scan)
    assert [p["reference_scan_points"] for p in cc["points"]] == [round(m / 2), m]
    assert math.isfinite(cc["exponent"])


def test_scaled_set_doubles_scans_and_keeps_their_geometry(room: EvaluationSet) -> None:
    big = scaled_set(room, 2.0)
    small = scaled_set(room, 0.5, queries=2)
    n = len(room.cases[0].query.scan)
    assert len(big.cases[0].query.scan) == 2 * n and len(small.cases) == 2
    assert len(small.cases[0].query.scan) == round(n / 2)
    # the added points are jittered copies (1 mm) of existing ones
    orig = room.cases[0].query.scan.points_m
    extra = big.cases[0].query.scan.points_m[n:]
    d = np.min(np.linalg.norm(extra[:, None, :] - orig[None, :, :], axis=2), axis=1)
    assert np.median(d) < 0.003


def test_fit_exponent_recovers_a_power_law() -> None:
    s = np.array([0.5, 1.0, 2.0, 4.0])
    assert fit_exponent(s, 3.0 * s**1.5) == pytest.approx(1.5)
    assert math.isnan(fit_exponent([1.0], [2.0]))


class _SeedHungryStep:
    """A heading step that is right when seeded and confidently 20° wrong when blind (what seeding is for)."""

    name = "compass"

    def __init__(self, truth: dict[str, Pose2]) -> None:
        self.truth = truth

    def prepare(self, reference: Reference) -> None:
        return None

    def estimate(self, prepared: None, query: Query, hypotheses: Hypotheses) -> Estimate:
        blind = hypotheses.heading() is None
        return Estimate.heading(self.name, self.truth[query.id].theta + (math.radians(20.0) if blind else 0.0), 0.01)


def test_hierarchy_ablation_counts_false_positives_of_the_seeded_steps_only(room: EvaluationSet) -> None:
    from factorloc.benchmarking import bench_hierarchy
    from factorloc.estimators.odometry import OdometryStep
    from factorloc.evaluation import run_hierarchy

    truth = {c.query.id: c.truth for c in room.cases}
    steps = [OdometryStep(), _SeedHungryStep(truth)]
    seeded = run_hierarchy(room, steps=steps)
    blind = run_hierarchy(room, steps=steps, seeded=False)
    h = bench_hierarchy([seeded], [blind])
    assert h["seeded"]["false_positive_count"] == 0 and h["blind"]["false_positive_count"] == 3
    assert h["blind"]["steps_false_positive_count"] == {"odometry": 0, "compass": 3}
    assert h["false_positive_ratio"] == 3.0 and h["false_positive_ratio_is_lower_bound"] is True
    assert h["time_ratio"] > 0
    # the counts come with what they are counted among, and the fused outcome of each mode
    assert h["blind"]["steps_reliable_count"] == {"odometry": 3, "compass": 3}
    assert h["blind"]["steps_false_positive_per_reliable"]["compass"] == 1.0
    assert h["seeded"]["steps_false_positive_per_reliable"]["compass"] == 0.0
    # blind, the 20°-wrong compass (σ 0.6°) and the odometry's heading (σ 1.7°, 1.1° off) disagree and the
    # consistency gate drops the earlier of the two: every fused heading is 20° off at σ 0.6°; seeded, none is
    assert h["blind"]["confidently_wrong_count"] == 3 and h["seeded"]["confidently_wrong_count"] == 0
    assert h["confidently_wrong_ratio"] == 3.0 and h["confidently_wrong_ratio_is_lower_bound"] is True
    assert h["blind"]["determined_rate"] == h["seeded"]["determined_rate"] == 1.0


def test_hierarchy_ablation_claims_no_ratio_when_neither_mode_has_a_false_positive(room: EvaluationSet) -> None:
    from factorloc.benchmarking import bench_hierarchy
    from factorloc.estimators.odometry import OdometryStep
    from factorloc.evaluation import run_hierarchy

    steps = [OdometryStep()]
    h = bench_hierarchy([run_hierarchy(room, steps=steps)], [run_hierarchy(room, steps=steps, seeded=False)])
    assert h["seeded"]["false_positive_count"] == h["blind"]["false_positive_count"] == 0
    assert math.isnan(h["false_positive_ratio"]) and h["false_positive_ratio_is_lower_bound"] is False
    assert math.isnan(h["confidently_wrong_ratio"]) and h["confidently_wrong_ratio_is_lower_bound"] is False

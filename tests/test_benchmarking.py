"""Smoke test of the benchmarks on a tiny synthetic room (scans + odometry): they run and their numbers make sense."""

from __future__ import annotations

import json
import math
from collections.abc import Callable

import numpy as np
import pytest

from factorloc import Estimate, Pose2, Query, Reference
from factorloc.benchmarking import BenchSettings, fit_exponent, run_bench, scaled_set
from factorloc.datasets import Scenario
from factorloc.errors import InputError
from factorloc.estimators.base import Hypotheses
from factorloc.evaluation import EvaluationSet, evaluation_set


@pytest.fixture(scope="module")
def room(make_room_scenario: Callable[[int, int], Scenario]) -> EvaluationSet:
    """Three scan-only queries in the shared test room (``tests/conftest.py``)."""
    return evaluation_set(make_room_scenario(3, 3))


def test_bench_runs_end_to_end_and_reports_every_section(room: EvaluationSet) -> None:
    out = run_bench(room, settings=BenchSettings(repeats=1, fusion_repeats=2, cost_factors=(0.5, 1.0), cost_queries=2))
    text = json.dumps(out.to_json(), allow_nan=False)
    assert json.loads(text)["localize"]["steps"]["compass"]["median_ms"] is None  # NaN as null
    assert out.queries == 3 and out.localize.median_ms > 0
    assert math.isnan(out.localize.steps["compass"].median_ms)  # skipped everywhere: no images
    h = out.hierarchy
    assert h.time_ratio > 0 and h.seeded.queries_with_truth == 3
    assert h.seeded.steps_reliable_rate["icp"] == 1.0 and h.seeded.position_rmse_m < 0.02
    icp = out.icp_vs_open3d
    assert icp.pairs == 3 and icp.ours_median_error_m < 0.02 and icp.open3d_median_error_m < 0.05
    f = out.fusion
    assert f.queries == 3 and f.queries_with_cross_covariance == 3  # ICP's covariance couples x, y, θ
    assert f.max_position_diff_m_cross_covariance < 1e-3
    cc = out.cost_curve
    m = len(room.reference_of(room.cases[0]).scan)
    assert [p.reference_scan_points for p in cc.points] == [round(m / 2), m]
    assert math.isfinite(cc.exponent)


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
    assert h.seeded.false_positive_count == 0 and h.blind.false_positive_count == 3
    assert h.blind.steps_false_positive_count == {"odometry": 0, "compass": 3}
    assert h.false_positive_ratio == 3.0 and h.false_positive_ratio_is_lower_bound is True
    assert h.time_ratio > 0
    # the counts come with what they are counted among, and the fused outcome of each mode
    assert h.blind.steps_reliable_count == {"odometry": 3, "compass": 3}
    assert h.blind.steps_false_positive_per_reliable["compass"] == 1.0
    assert h.seeded.steps_false_positive_per_reliable["compass"] == 0.0
    # blind, the 20°-wrong compass (σ 0.6°) and the odometry's heading (σ 1.7°, 1.1° off) disagree and the
    # consistency gate drops the earlier of the two: every fused heading is 20° off at σ 0.6°; seeded, none is
    assert h.blind.confidently_wrong_count == 3 and h.seeded.confidently_wrong_count == 0
    assert h.confidently_wrong_ratio == 3.0 and h.confidently_wrong_ratio_is_lower_bound is True
    assert h.blind.determined_rate == h.seeded.determined_rate == 1.0


def test_hierarchy_ablation_claims_no_ratio_when_neither_mode_has_a_false_positive(room: EvaluationSet) -> None:
    from factorloc.benchmarking import bench_hierarchy
    from factorloc.estimators.odometry import OdometryStep
    from factorloc.evaluation import run_hierarchy

    steps = [OdometryStep()]
    h = bench_hierarchy([run_hierarchy(room, steps=steps)], [run_hierarchy(room, steps=steps, seeded=False)])
    assert h.seeded.false_positive_count == h.blind.false_positive_count == 0
    assert math.isnan(h.false_positive_ratio) and h.false_positive_ratio_is_lower_bound is False
    assert math.isnan(h.confidently_wrong_ratio) and h.confidently_wrong_ratio_is_lower_bound is False


def test_clopper_pearson_matches_scipys_exact_interval_and_the_closed_forms() -> None:
    from scipy.stats import binomtest

    from factorloc.benchmarking import clopper_pearson

    for k, n in ((0, 300), (2, 300), (7, 40), (40, 40)):
        ci = binomtest(k, n).proportion_ci(confidence_level=0.95, method="exact")
        assert clopper_pearson(k, n) == pytest.approx((ci.low, ci.high), abs=1e-12)
    # k = 0: the upper end solves (1 − p)^n = α/2 ("rule of three" ≈ 3.7/n)
    assert clopper_pearson(0, 300)[1] == pytest.approx(1.0 - 0.025 ** (1 / 300), rel=1e-9)
    assert clopper_pearson(40, 40)[0] == pytest.approx(0.025 ** (1 / 40), rel=1e-9)
    assert all(math.isnan(v) for v in clopper_pearson(0, 0))
    with pytest.raises(InputError, match="count"):
        clopper_pearson(5, 3)


def test_rate_ratio_interval_conditional_on_the_total_count() -> None:
    from factorloc.benchmarking import rate_ratio_interval

    # 2 blind vs 0 seeded of 300 each: given 2 events, both blind has probability π² ≥ 0.05 for π ≥ √0.05
    lo, hi = rate_ratio_interval(2, 300, 0, 300, one_sided=True)
    assert lo == pytest.approx(math.sqrt(0.05) / (1 - math.sqrt(0.05)), rel=1e-9) and hi == math.inf
    assert lo < 0.3  # two events cannot show a ratio of even 1
    # swapping the two rates inverts the two-sided interval; unequal sample sizes scale it
    a, b = rate_ratio_interval(12, 300, 3, 300), rate_ratio_interval(3, 300, 12, 300)
    assert a[0] == pytest.approx(1 / b[1]) and a[1] == pytest.approx(1 / b[0]) and a[0] < 4.0 < a[1]
    c = rate_ratio_interval(12, 600, 3, 300)
    assert c[0] == pytest.approx(a[0] / 2) and c[1] == pytest.approx(a[1] / 2)
    assert all(math.isnan(v) for v in rate_ratio_interval(0, 300, 0, 300))


def test_queries_to_show_a_ratio_needs_17_blind_events_when_seeded_has_none() -> None:
    from factorloc.benchmarking import queries_to_show_ratio, rate_ratio_interval

    events = math.log(0.05) / math.log(5 / 6)  # 16.43: (5/6)^k ≤ α
    assert queries_to_show_ratio(0.01, 0.0) == math.ceil(events / 0.01)
    n = queries_to_show_ratio(0.10, 0.01)
    assert n is not None
    assert rate_ratio_interval(0.10 * n, n, 0.01 * n, n, one_sided=True)[0] >= 5.0
    assert rate_ratio_interval(0.10 * (n - 1), n - 1, 0.01 * (n - 1), n - 1, one_sided=True)[0] < 5.0
    assert queries_to_show_ratio(0.10, 0.02) is None  # the rates' ratio is 5: no sample shows more
    assert queries_to_show_ratio(0.0, 0.0) is None


def test_beyond_tolerance_judges_only_what_the_estimate_determines() -> None:
    from factorloc.benchmarking import beyond_tolerance

    tol_m, tol_rad = 0.10, math.radians(5.0)
    heading_only = np.diag([np.inf, np.inf, math.radians(2.0) ** 2])
    assert beyond_tolerance(np.array([np.nan, np.nan, math.radians(6.0)]), heading_only, tol_m, tol_rad)
    assert not beyond_tolerance(np.array([np.nan, np.nan, math.radians(4.0)]), heading_only, tol_m, tol_rad)
    # an ICP estimate along a wall (y = const): σ 30 m along x, 1 cm across; 2 m off along the wall is no claim
    along = np.diag([30.0**2, 0.01**2, 1e-4])
    assert not beyond_tolerance(np.array([2.0, 0.05, 0.0]), along, tol_m, tol_rad)
    assert beyond_tolerance(np.array([2.0, 0.20, 0.0]), along, tol_m, tol_rad)
    full = np.diag([0.02**2, 0.02**2, 1e-4])
    assert beyond_tolerance(np.array([0.08, 0.08, 0.0]), full, tol_m, tol_rad)  # 11.3 cm
    assert not beyond_tolerance(np.array([0.06, 0.06, 0.0]), full, tol_m, tol_rad)  # 8.5 cm


def test_hierarchy_ablation_reports_exact_intervals_and_the_sample_a_5x_claim_needs(room: EvaluationSet) -> None:
    from factorloc.benchmarking import bench_hierarchy
    from factorloc.estimators.odometry import OdometryStep
    from factorloc.evaluation import run_hierarchy

    truth = {c.query.id: c.truth for c in room.cases}
    steps = [OdometryStep(), _SeedHungryStep(truth)]
    fp = bench_hierarchy([run_hierarchy(room, steps=steps)], [run_hierarchy(room, steps=steps, seeded=False)]).false_positives
    assert fp.headline == "sigma3" and fp.queries == 3 and fp.target_ratio == 5.0
    for definition in ("sigma3", "tolerance"):  # 20° off at σ 0.6°: beyond 3σ and beyond 5°
        c = fp.steps_after_first[definition]
        assert c.seeded.count == 0 and c.blind.count == 3
        assert c.blind.rate_ci[0] == pytest.approx(0.025 ** (1 / 3)) and c.blind.rate_ci[1] == 1.0
        assert c.ratio == math.inf and c.shows_target is False
        # 3 of 3 vs 0 of 3: the one-sided bound of π is 0.05^(1/3), ρ = π / (1 − π)
        assert c.ratio_lower_bound == pytest.approx(0.05 ** (1 / 3) / (1 - 0.05 ** (1 / 3)))
        # at a blind rate of 1 and a seeded rate of 0, 17 queries give the 16.4 blind events 5× needs
        assert c.queries_needed == 17
        assert fp.fused[definition].blind.count == 3 and fp.fused[definition].seeded.count == 0
    compass = fp.steps["compass"]["sigma3"]
    assert compass.blind.reliable == compass.seeded.reliable == 3
    assert compass.blind.per_reliable == 1.0
    assert compass.seeded.per_reliable_ci[1] == pytest.approx(1 - 0.025 ** (1 / 3))
    odo = fp.steps["odometry"]["sigma3"]
    assert odo.seeded.count == odo.blind.count == 0 and math.isnan(odo.ratio)


def test_power_to_show_a_ratio_is_the_chance_of_enough_blind_events() -> None:
    from scipy.stats import binom

    from factorloc.benchmarking import power_to_show_ratio, queries_to_show_ratio

    # seeded rate 0: 5x is shown exactly when blind has >= 17 events (16.4 needed)
    assert power_to_show_ratio(3049, 2 / 300, 0.0) == pytest.approx(binom.sf(16, 3049, 2 / 300), rel=1e-9)
    assert power_to_show_ratio(16, 1.0, 0.0) == 0.0 and power_to_show_ratio(17, 1.0, 0.0) == 1.0
    n80 = queries_to_show_ratio(2 / 300, 0.0, power=0.8)
    assert power_to_show_ratio(n80, 2 / 300, 0.0) >= 0.8 > power_to_show_ratio(n80 - 40, 2 / 300, 0.0)
    assert n80 > queries_to_show_ratio(2 / 300, 0.0)  # an even chance needs fewer

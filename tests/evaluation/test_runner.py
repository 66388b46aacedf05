"""The runner on synthetic steps with known noise: metrics, JSON keys, strategies, availability."""

from __future__ import annotations

import json
import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pytest

from factorloc import Estimate, InputError, Pose2, ProductFusion, Query, Reference, Scan, StepReport
from factorloc.estimators.base import Hypotheses
from factorloc.evaluation import Case, EvaluationSet, evaluate, run_hierarchy
from factorloc.fusion.base import Fused
from factorloc.types import Component
from factorloc.verdicts import Check, Unit

STABLE_KEYS = (
    "position_rmse_m",
    "position_median_m",
    "heading_rmse_deg",
    "heading_median_deg",
    "nees_mean",
    "outside_99_rate",
    "confidently_wrong_rate",
    "latency_median_ms",
    "latency_p95_ms",
)


class NoisyPoseStep:
    """A full-pose step: truth + N(0, σ²·scale²) noise, claims σ; unreliable on queries tagged ``blind_tag``."""

    def __init__(
        self,
        name: str,
        truth: dict[str, Pose2],
        sigmas: Sequence[float],
        seed: int,
        *,
        error_scale: float = 1.0,
        blind_tag: str = "",
        tags: dict[str, tuple[str, ...]] | None = None,
    ) -> None:
        self.name = name
        self.truth, self.sigmas = truth, np.asarray(sigmas)
        self.rng = np.random.default_rng(seed)
        self.error_scale, self.blind_tag, self.tags = error_scale, blind_tag, tags or {}

    def prepare(self, reference: Reference) -> Any:
        return None

    def estimate(self, prepared: Any, query: Query, hypotheses: Hypotheses) -> Estimate | None:
        t = self.truth[query.id].as_array()
        v = t + self.error_scale * self.sigmas * self.rng.normal(size=3)
        reliable = self.blind_tag not in self.tags.get(query.id, ())
        matches = Check.at_least(
            f"{self.name}.matches", "matches", 10 if reliable else int(self.rng.integers(3, 9)), 10, Unit.COUNT
        )
        return Estimate.pose(self.name, Pose2.from_array(v), *self.sigmas, reliable=reliable, checks=(matches,))


class HeadingStep:
    """A heading-only step: truth + N(0, σ²) noise."""

    name = "compass"

    def __init__(self, truth: dict[str, Pose2], sigma_rad: float, seed: int) -> None:
        self.truth, self.sigma, self.rng = truth, sigma_rad, np.random.default_rng(seed)

    def prepare(self, reference: Reference) -> Any:
        return None

    def estimate(self, prepared: Any, query: Query, hypotheses: Hypotheses) -> Estimate | None:
        return Estimate.heading(self.name, self.truth[query.id].theta + self.sigma * self.rng.normal(), self.sigma)


def _dataset(n: int, faulty_every: int = 0, seed: int = 0) -> tuple[EvaluationSet, dict[str, Pose2], dict[str, tuple[str, ...]]]:
    rng = np.random.default_rng(seed)
    truth, tags, cases = {}, {}, []
    for i in range(n):
        qid = f"q{i:03d}"
        truth[qid] = Pose2(rng.uniform(0, 5), rng.uniform(0, 4), rng.uniform(-math.pi, math.pi))
        tags[qid] = ("occlusion",) if faulty_every and i % faulty_every == 0 else ()
        cases.append(Case(Query(id=qid), truth[qid], tags[qid]))
    ref = Reference(scan=Scan(np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]])), T_world_reference=Pose2(1.0, 1.0, 0.0))
    return EvaluationSet(ref, tuple(cases), name="synthetic"), truth, tags


def test_a_calibrated_hierarchy_scores_its_expected_accuracy_and_nees() -> None:
    data, truth, _ = _dataset(300)
    steps = [NoisyPoseStep("odometry", truth, [0.05, 0.05, 0.02], 1), NoisyPoseStep("icp", truth, [0.02, 0.02, 0.01], 2)]
    report = evaluate(data, ProductFusion(), steps=steps)
    out = report.to_json()
    # fused σ per axis: 1/√(1/5² + 1/2²) cm = 1.857 cm; position RMSE = √2 · that
    s_xy = 1 / math.sqrt(1 / 0.05**2 + 1 / 0.02**2)
    s_th = 1 / math.sqrt(1 / 0.02**2 + 1 / 0.01**2)
    assert out["position_rmse_m"] == pytest.approx(math.sqrt(2) * s_xy, rel=0.1)
    assert out["heading_rmse_deg"] == pytest.approx(math.degrees(s_th), rel=0.1)
    assert out["nees_mean"] == pytest.approx(3.0, abs=0.4)
    assert out["nees_median"] == pytest.approx(2.366, abs=0.4)
    assert out["confidently_wrong_rate"] < 0.03 and out["outside_99_rate"] < 0.03
    assert out["queries"] == 300 and out["nees_count"] == 300
    assert out["steps"]["icp"]["reliable_rate"] == 1.0 and out["steps"]["icp"]["fused_rate"] == 1.0
    assert out["steps"]["icp"]["position_rmse_m"] == pytest.approx(math.sqrt(2) * 0.02, rel=0.1)
    # each step's own NEES, per part: position χ²(2) (mean 2, median 1.386), heading χ²(1) (mean 1, median 0.455)
    for name in ("odometry", "icp"):
        st = out["steps"][name]
        assert st["position_nees_mean"] == pytest.approx(2.0, abs=0.3)
        assert st["position_nees_median"] == pytest.approx(1.386, abs=0.3)
        assert st["heading_nees_mean"] == pytest.approx(1.0, abs=0.2)
        assert st["heading_nees_median"] == pytest.approx(0.455, abs=0.15)


def test_overconfident_step_shows_in_nees_and_in_its_own_false_positives() -> None:
    data, truth, _ = _dataset(200)
    steps = [NoisyPoseStep("icp", truth, [0.01, 0.01, 0.01], 3, error_scale=3.0)]  # errors 3× the claimed σ
    out = evaluate(data, ProductFusion(), steps=steps).to_json()
    assert out["nees_mean"] == pytest.approx(27.0, rel=0.2)
    assert out["steps"]["icp"]["position_nees_mean"] == pytest.approx(18.0, rel=0.2)
    assert out["steps"]["icp"]["heading_nees_mean"] == pytest.approx(9.0, rel=0.25)
    assert out["confidently_wrong_rate"] > 0.4
    assert out["steps"]["icp"]["false_positive_rate"] == pytest.approx(out["confidently_wrong_rate"])
    assert out["steps"]["icp"]["confidently_wrong_blame"] == out["confidently_wrong_count"]


def test_json_has_the_stable_keys_per_fault_and_per_step_and_is_strict_json() -> None:
    data, truth, tags = _dataset(12, faulty_every=3)
    steps = [
        NoisyPoseStep("odometry", truth, [0.05, 0.05, 0.02], 1),
        NoisyPoseStep("icp", truth, [0.02, 0.02, 0.01], 2, blind_tag="occlusion", tags=tags),
    ]
    out = evaluate(data, steps=steps).to_json()
    text = json.dumps(out, allow_nan=False)  # no NaN/inf leak into the JSON
    assert json.loads(text)["schema_version"] == 1
    for scope in (out, out["by_fault"]["occlusion"], out["by_fault"]["none"]):
        for key in STABLE_KEYS:
            assert key in scope, key
        for step in ("odometry", "icp"):
            assert {"reliable_rate", "latency_median_ms", "gate_reasons"} <= set(scope["steps"][step])
    assert out["by_fault"]["occlusion"]["queries"] == 4 and out["by_fault"]["none"]["queries"] == 8
    icp = out["steps"]["icp"]
    assert icp["reliable_rate"] == pytest.approx(8 / 12)
    assert out["by_fault"]["occlusion"]["steps"]["icp"]["reliable_rate"] == 0.0
    # reasons are counted by rule code, so 4 different match counts are one cause, and the range of the counts is kept
    assert icp["gate_reasons"] == {"unreliable: icp.matches": 4}
    (rule,) = icp["gate_rules"]
    assert (
        rule["count"] == 4 and rule["limit_min"] == rule["limit_max"] == 10 and 3 <= rule["value_min"] <= rule["value_max"] <= 8
    )
    assert rule["text"] == f"matches {rule['value_min']:.0f}–{rule['value_max']:.0f} < 10"
    assert icp["status_rates"]["unreliable"] == pytest.approx(4 / 12)
    assert out["strategy"] == "graph" and out["scenario"] == "synthetic"


def test_heading_only_results_count_as_heading_but_not_position() -> None:
    data, truth, _ = _dataset(20)
    out = evaluate(data, ProductFusion(), steps=[HeadingStep(truth, 0.01, 4)]).to_json()
    assert out["position_determined_rate"] == 0.0 and out["heading_determined_rate"] == 1.0
    assert out["position_rmse_m"] is None and out["position_count"] == 0
    assert out["heading_count"] == 20 and out["heading_rmse_deg"] == pytest.approx(math.degrees(0.01), rel=0.35)
    assert out["nees_mean"] is None  # no fully determined result
    assert out["nees_normalized_mean"] == pytest.approx(1.0, abs=0.6)
    assert out["confidently_wrong_rate"] == 0.0  # never reliable: position undetermined


def test_one_hierarchy_run_serves_several_strategies_with_identical_gating() -> None:
    data, truth, _ = _dataset(15)
    steps = [NoisyPoseStep("odometry", truth, [0.05, 0.05, 0.02], 1), HeadingStep(truth, 0.005, 2)]
    run = run_hierarchy(data, steps=steps)
    graph = evaluate(run)
    product = evaluate(run, ProductFusion())
    assert graph.strategy == "graph" and product.strategy == "product"
    np.testing.assert_allclose(graph.errors, product.errors, atol=1e-9)
    # the fused result of the default strategy is the one Localizer.localize returned
    for res, qr in zip(graph.results, run.runs, strict=True):
        np.testing.assert_allclose(res.pose.as_array(), qr.localization.pose.as_array(), atol=1e-12)
        assert [r.status for r in res.reports] == [r.status for r in qr.reports]
        assert res.latency_s >= qr.steps_seconds
    with pytest.raises(InputError, match="seeded"):
        evaluate(run, seeded=False)


class LastPoseMemory:
    """A toy sequential strategy: the latest reliable full pose seen so far (σ inflated by 1 cm per query)."""

    name = "memory"

    def __init__(self) -> None:
        self.calls: list[str] = []
        self.resets = 0

    def reset(self) -> None:
        self.resets += 1
        self.last: Estimate | None = None
        self.age = 0

    def update(self, query: Query, reports: Sequence[StepReport]) -> Fused:
        self.calls.append(query.id)
        fresh = [r.estimate for r in reports if r.fused and r.estimate is not None and r.estimate.kind == "full"]
        if fresh:
            self.last, self.age = fresh[-1], 0
        else:
            self.age += 1
        if self.last is None:
            return Fused(Pose2(), np.diag([math.inf] * 3), (Component.X, Component.Y, Component.THETA))
        cov = self.last.covariance + np.diag([0.01**2, 0.01**2, 0.0]) * self.age
        return Fused(Pose2.from_array(self.last.values), cov)


def test_a_sequential_strategy_is_reset_once_and_fed_in_scenario_order() -> None:
    data, truth, tags = _dataset(9, faulty_every=2)
    steps = [NoisyPoseStep("icp", truth, [0.02, 0.02, 0.01], 5, blind_tag="occlusion", tags=tags)]
    strat = LastPoseMemory()
    report = evaluate(data, strat, steps=steps)
    assert strat.resets == 1 and strat.calls == [c.query.id for c in data.cases]
    out = report.to_json()
    assert out["strategy"] == "memory"
    # q000 is occluded and first: nothing known yet → undetermined; q002… reuse the previous pose (wrong)
    assert out["determined_rate"] == pytest.approx(8 / 9)
    assert out["by_fault"]["none"]["position_rmse_m"] == pytest.approx(math.sqrt(2) * 0.02, rel=0.8)
    assert out["by_fault"]["occlusion"]["position_rmse_m"] > 0.5  # a stale pose of another random place


def test_distance_from_reference_uses_the_reference_pose() -> None:
    data, truth, _ = _dataset(3)
    report = evaluate(data, ProductFusion(), steps=[NoisyPoseStep("icp", truth, [0.02, 0.02, 0.01], 5)])
    for res in report.results:
        assert res.distance_to_reference_m == pytest.approx(math.hypot(res.truth.x - 1.0, res.truth.y - 1.0))


def test_rejects_what_is_not_a_strategy_or_a_scenario() -> None:
    data, truth, _ = _dataset(2)
    with pytest.raises(InputError, match="strategy must implement"):
        evaluate(data, object(), steps=[HeadingStep(truth, 0.01, 0)])
    with pytest.raises(InputError, match="scenario must be"):
        evaluate([1, 2, 3])
    with pytest.raises(InputError, match="Case.truth"):
        Case(Query(id="a"), truth=(1.0, 2.0, 0.0))  # type: ignore[arg-type]


class ReferenceEcho:
    """Returns the truth and records, in its diagnostics, the reference it was prepared with."""

    name = "echo"

    def __init__(self, truth: dict[str, Pose2]) -> None:
        self.truth = truth
        self.prepared: list[str] = []

    def prepare(self, reference: Reference) -> Any:
        self.prepared.append(reference.name)
        return reference.name

    def estimate(self, prepared: Any, query: Query, hypotheses: Hypotheses) -> Estimate | None:
        return Estimate.pose(self.name, self.truth[query.id], 0.01, 0.01, 0.01, diagnostics={"reference": prepared})


def test_a_scenario_with_two_references_localizes_each_query_against_its_own() -> None:
    from factorloc.datasets import Scenario, ScenarioQuery, ScenarioReference

    scan = Scan(np.array([[1.0, 0.0], [0.0, 1.0], [1.0, 1.0]]))
    refs = (
        ScenarioReference("hall", Reference(scan=scan, T_world_reference=Pose2(0.0, 0.0, 0.0), name="hall")),
        ScenarioReference("kitchen", Reference(scan=scan, T_world_reference=Pose2(6.0, 0.0, 0.0), name="kitchen")),
    )
    truth = {f"q{i}": Pose2(1.0 + i, 0.0, 0.0) for i in range(4)}
    queries = tuple(
        ScenarioQuery(
            Query(id=k),
            timestamp_s=float(i),
            truth=v,
            faults=("blur",) if i == 3 else (),
            reference_id="hall" if i < 2 else "kitchen",
            distance_from_reference_m=None if i else 7.5,
        )
        for i, (k, v) in enumerate(truth.items())
    )
    step = ReferenceEcho(truth)
    report = evaluate(Scenario("two-rooms", refs, queries), ProductFusion(), steps=[step])
    assert step.prepared == ["hall", "kitchen"]  # each reference prepared once
    assert [r.reports[0].estimate.diagnostics["reference"] for r in report.results] == ["hall", "hall", "kitchen", "kitchen"]
    # the scenario's own distance wins; otherwise it is measured from the query's reference
    assert [r.distance_to_reference_m for r in report.results] == pytest.approx([7.5, 2.0, 3.0, 2.0])
    out = report.to_json()
    assert out["scenario"] == "two-rooms" and out["by_fault"]["blur"]["queries"] == 1
    assert out["position_rmse_m"] == pytest.approx(0.0, abs=1e-12)


def test_overlapping_scope_holds_the_queries_whose_scan_saw_the_reference_surfaces() -> None:
    """A reference that saw one wall (y = 0, x in [0, 4]); queries whose scan sees that wall overlap, a query
    whose scan sees only a wall 10 m away does not, a query without range data has an unknown overlap."""
    wall_world = np.column_stack([np.linspace(0.0, 4.0, 401), np.zeros(401)])
    T_ref = Pose2(2.0, 1.0, 0.5)
    ref = Reference(scan=Scan(T_ref.inverse().transform_points(wall_world)), T_world_reference=T_ref)
    cases, truth = [], {}
    for qid, pose, seen in [
        ("q0", Pose2(1.0, 1.5, 0.3), wall_world[100:300]),
        ("q1", Pose2(3.0, 2.0, -1.0), np.vstack([wall_world[::4], [[3.0, 5.0]] * 20])),  # 101 of 121 points on it
        ("q2", Pose2(2.0, 1.0, 2.0), np.column_stack([np.linspace(0, 4, 50), np.full(50, 10.0)])),
    ]:
        truth[qid] = pose
        cases.append(Case(Query(scan=Scan(pose.inverse().transform_points(seen)), id=qid), pose))
    truth["q3"] = Pose2(1.0, 1.0, 0.0)
    cases.append(Case(Query(id="q3"), truth["q3"]))
    data = EvaluationSet(ref, tuple(cases), name="walls")
    report = evaluate(data, ProductFusion(), steps=[NoisyPoseStep("icp", truth, [0.02, 0.02, 0.01], 3)])
    overlaps = [r.view_overlap for r in report.results]
    assert overlaps[0] == pytest.approx(1.0) and overlaps[1] == pytest.approx(101 / 121) and overlaps[2] == 0.0
    assert math.isnan(overlaps[3])
    out = report.to_json()
    assert out["overlapping"]["queries"] == 2 and out["overlapping_rate"] == pytest.approx(2 / 3)
    expected = math.sqrt(np.mean([float(np.hypot(*report.errors[i, :2])) ** 2 for i in (0, 1)]))
    assert out["overlapping"]["position_rmse_m"] == pytest.approx(expected)

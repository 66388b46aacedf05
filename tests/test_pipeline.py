"""The hierarchy: order, seeding with reliable hypotheses only, skipping, failures, fusion."""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pytest

from factorloc import (
    Component,
    Config,
    Estimate,
    InputError,
    Localizer,
    Odometry,
    Pose2,
    ProductFusion,
    Query,
    Reference,
    Scan,
    StepStatus,
    fuse,
    localize,
)
from factorloc.estimators.base import Hypotheses, Step
from factorloc.pipeline import default_steps

REF = Reference(scan=Scan(np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])))


class Recorder:
    """A step that records the hypotheses it was given and returns a fixed estimate."""

    def __init__(self, name: str, estimate: Estimate | None, fail: bool = False) -> None:
        self.name = name
        self._estimate = estimate
        self.fail = fail
        self.seen: list[Hypotheses] = []
        self.prepared_with: Reference | None = None

    def prepare(self, reference: Reference) -> Any:
        self.prepared_with = reference
        return "prepared"

    def estimate(self, prepared: Any, query: Query, hypotheses: Hypotheses) -> Estimate | None:
        assert prepared == "prepared"
        self.seen.append(hypotheses)
        if self.fail:
            raise InputError("all-black image")
        return self._estimate


def test_steps_run_in_order_and_receive_only_reliable_hypotheses() -> None:
    good = Recorder("a", Estimate.heading("a", 0.10, 0.01))
    bad = Recorder("b", Estimate.heading("b", 2.0, 0.01, reliable=False, reason="peak 0.3 < Ct"))
    last = Recorder("c", Estimate.position("c", 1.0, 2.0, 0.02, 0.02))
    loc = localize(REF, Query(id="q"), steps=[good, bad, last])
    assert [r.name for r in loc.steps] == ["a", "b", "c"]
    assert last.seen[0].heading() == (pytest.approx(0.10), pytest.approx(0.01), "a")  # b was not passed on
    assert loc.step("b").status is StepStatus.UNRELIABLE and "Ct" in loc.step("b").reason
    assert loc.step("a").fused and loc.step("c").fused
    assert np.allclose(loc.pose.as_array(), [1.0, 2.0, 0.10], atol=1e-9)
    assert all(r.seconds >= 0.0 for r in loc.steps)


def test_blind_mode_gives_no_hypotheses() -> None:
    a = Recorder("a", Estimate.heading("a", 0.1, 0.01))
    b = Recorder("b", Estimate.heading("b", 0.1, 0.01))
    Localizer(REF, steps=[a, b]).localize(Query(), seeded=False)
    assert b.seen[0].heading() is None


def test_absent_inputs_skip_a_step_and_a_failing_step_is_reported_not_fused() -> None:
    skip = Recorder("camera", None)
    broken = Recorder("broken", None, fail=True)
    odo = Recorder("odo", Estimate.pose("odo", Pose2(1, 2, 0.3), 0.05, 0.05, 0.02))
    loc = localize(REF, Query(), steps=[odo, skip, broken])
    assert loc.step("camera").status is StepStatus.SKIPPED
    assert loc.step("broken").status is StepStatus.FAILED and "all-black" in loc.step("broken").reason
    assert loc.determined


def test_odometry_only_query_returns_the_odometry_pose_and_sigmas() -> None:
    odo = Odometry.from_distance(Pose2(1.0, 2.0, 0.3), distance_m=1.0, rotation_rad=0.5)
    loc = localize(REF, Query(odometry=odo))
    assert np.allclose(loc.pose.as_array(), [1.0, 2.0, 0.3])
    assert np.allclose(loc.sigmas, [odo.sigma_x_m, odo.sigma_y_m, odo.sigma_theta_rad])
    assert loc.fused_with == "graph" and loc.config == Config()


def test_a_heading_only_result_is_under_determined_in_position_not_a_crash() -> None:
    loc = localize(REF, Query(), steps=[Recorder("compass", Estimate.heading("compass", 1.0, 0.01))])
    assert {c.value for c in loc.undetermined} == {"x", "y"}
    assert math.isinf(loc.sigmas[0]) and math.isclose(loc.sigmas[2], 0.01)
    assert not loc.determined and loc.certainty(1.0, 1.0) == 0.0


def test_nothing_reliable_gives_a_fully_undetermined_result() -> None:
    loc = localize(REF, Query(), steps=[Recorder("compass", Estimate.heading("compass", 1.0, 0.01, reliable=False))])
    assert len(loc.undetermined) == 3 and np.all(np.isinf(loc.sigmas))


def test_unreliable_odometry_by_sigma_threshold() -> None:
    odo = Odometry(Pose2(), 1.0, 1.0, 0.1)
    loc = localize(REF, Query(odometry=odo), Config.from_dict({"odometry": {"max_sigma_position_m": 0.06}}))
    assert loc.step("odometry").status is StepStatus.UNRELIABLE
    assert loc.step("odometry").reason == "σ position 1 m > 0.06 m"
    assert loc.step("odometry").rule_codes == ("odometry.sigma_position",)


def test_strategy_object_overrides_config_and_bad_arguments_raise() -> None:
    loc = localize(REF, Query(odometry=Odometry(Pose2(), 0.1, 0.1, 0.1)), strategy=ProductFusion())
    assert loc.fused_with == "product"
    with pytest.raises(InputError, match="reference"):
        localize("ref", Query())  # type: ignore[arg-type]
    with pytest.raises(InputError, match="query"):
        localize(REF, None)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="Step protocol"):
        Localizer(REF, steps=[object()])  # type: ignore[list-item]


def test_default_steps_follow_the_patent_order_and_implement_the_protocol() -> None:
    steps = default_steps(Config())
    names = [s.name for s in steps]
    order = ["odometry", "compass", "correlation", "icp"]
    assert names == [n for n in order if n in names] and names[0] == "odometry"
    assert all(isinstance(s, Step) for s in steps)
    assert default_steps(Config.from_dict({"odometry": {"enabled": False}}))[:1] != steps[:1]


def test_fuse_reports_verdicts_for_each_estimate() -> None:
    ests = [
        Estimate.pose("odometry", Pose2(3.0, 0.5, 0.17), 0.05, 0.05, 0.05),
        Estimate.position("icp", 1.03, 0.48, 0.02, 0.02),
        Estimate.heading("compass", 0.2, 0.02, reliable=False, reason="2 inliers"),
    ]
    loc = fuse(ests)
    assert [r.status for r in loc.steps] == [StepStatus.FUSED, StepStatus.FUSED, StepStatus.UNRELIABLE]
    assert "partly fused" in loc.steps[0].reason  # its position disagreed with ICP's, its heading was kept
    assert np.allclose([loc.pose.x, loc.pose.y, loc.pose.theta], [1.03, 0.48, 0.17], atol=1e-9)
    with pytest.raises(InputError, match=r"estimates\[0\]"):
        fuse([{"step": "a"}])  # type: ignore[list-item]


def test_kidnapped_robot_whose_scan_fits_nowhere_near_its_odometry_is_not_localized_confidently() -> None:
    """q0044, q0086, q0228, q0291 of ``simulate --world apartment --queries 300 --seed 7``: kidnapped 0.7–2 m, the
    odometry reliable (σ ≤ 27 cm) but 0.6–1.7 m off, every visual step unreliable. Fused as reliable, the odometry
    was confidently wrong (1.3 % of the scenario). Now the odometry is never fused: the ICP's solution refutes it
    (consistency gate) or the seeded ICP's misfit does (seed audit) and the result is then undetermined — and an
    audited odometry, fused without the audit, is indeed wrong by > 3σ. q0017 (fault-free, ICP degenerate along
    one wall, odometry 1 cm off) keeps its odometry."""
    from factorloc.evaluation import metrics
    from factorloc.sim import generate_scenario

    scenario = generate_scenario("apartment", 300, 7, only_queries=[17, 44, 86, 228, 291])
    localizer = Localizer(scenario.references[0].reference)
    no_audit = Config.from_dict({"gating": {"seed_audit": False}}).gating
    audited = 0
    for sq in scenario.queries:
        loc = localizer.localize(sq.query)
        odo = loc.step("odometry")
        odo_error_m = math.hypot(odo.estimate.values[0] - sq.truth.x, odo.estimate.values[1] - sq.truth.y)
        assert odo.estimate.reliable
        err = metrics.pose_errors(loc.pose.as_array()[None], sq.truth.as_array()[None])
        if "kidnapped" in sq.faults:
            assert odo_error_m > 0.6 and max(odo.estimate.sigma("x"), odo.estimate.sigma("y")) < 0.3
            assert odo.status is StepStatus.INCONSISTENT
            assert not metrics.confidently_wrong(err, loc.covariance[None])[0]
            if "seed contradicted by icp" in odo.reason:
                audited += 1
                assert not loc.determined and np.isinf(np.diag(loc.covariance)).all()
                unaudited = fuse([s.estimate for s in loc.steps if s.estimate is not None], gating=no_audit)
                e = metrics.pose_errors(unaudited.pose.as_array()[None], sq.truth.as_array()[None])
                assert metrics.confidently_wrong(e, unaudited.covariance[None])[0]
        else:
            assert sq.faults == () and odo_error_m < 0.05
            assert odo.status is StepStatus.FUSED and loc.determined
    assert audited >= 2  # the corridor ones at least: their scans fit the reference nowhere


def _single_wall_case(noise_seed: int = 3) -> tuple[Reference, Query, Pose2, Estimate, np.ndarray]:
    """One 8 m wall along the world diagonal y = x (both world σx, σy of "along it" are large), seen by the
    reference and by the query; an odometry 20 cm off along the wall and 10 cm off across it."""
    rng = np.random.default_rng(noise_seed)
    t = np.linspace(-4.0, 4.0, 400)
    wall = np.column_stack([t, t])
    along = np.array([1.0, 1.0]) / math.sqrt(2.0)
    T_ref = Pose2(1.0, 0.0, 0.3)
    truth = Pose2(1.5, 0.2, 1.0)
    ref = Reference(scan=Scan(T_ref.inverse().transform_points(wall)), T_world_reference=T_ref)
    query = Query(scan=Scan(truth.inverse().transform_points(wall) + rng.normal(0.0, 0.003, wall.shape)))
    across = np.array([along[1], -along[0]])
    p = truth.translation + 0.2 * along + 0.1 * across
    odo = Estimate.pose("odometry", Pose2(p[0], p[1], truth.theta + math.radians(2.0)), 0.3, 0.3, math.radians(3.0))
    return ref, query, truth, odo, along


# the smallest eigenvalue of one wall's normal scatter is 0 in theory and ±1e-16 after rounding: before it was
# compared with a tolerance, 12 of these 24 noise seeds flipped the verdict (issue 13)
NOISE_SEEDS = range(24)


@pytest.mark.parametrize("noise_seed", NOISE_SEEDS)
def test_a_single_wall_pins_the_position_across_it_and_the_odometry_gives_it_along(noise_seed: int) -> None:
    from factorloc.estimators.icp import IcpStep

    ref, query, truth, odo, along = _single_wall_case(noise_seed)
    loc = localize(ref, query, steps=[Recorder("odometry", odo), IcpStep()])
    icp = loc.step("icp")
    assert icp.status == StepStatus.FUSED and icp.estimate.kind == "full"
    assert icp.estimate.reason.startswith("across the walls and heading only")
    assert loc.determined
    e = loc.pose.translation - truth.translation
    across = np.array([along[1], -along[0]])
    assert abs(float(e @ across)) < 0.01  # the odometry was 10 cm off across the wall
    assert abs(math.remainder(loc.pose.theta - truth.theta, 2 * math.pi)) < math.radians(0.2)  # odometry: 2°
    # along the wall the fused position is the odometry's (20 cm off), honestly covered by the fused σ
    sigma_along = math.sqrt(float(along @ loc.covariance[:2, :2] @ along))
    assert 0.25 < sigma_along < 0.35 and abs(float(e @ along)) < 3.0 * sigma_along
    sigma_across = math.sqrt(float(across @ loc.covariance[:2, :2] @ across))
    assert sigma_across < 0.03 and abs(float(e @ across)) < 3.0 * sigma_across


@pytest.mark.parametrize("noise_seed", NOISE_SEEDS)
def test_a_single_wall_alone_leaves_the_position_undetermined(noise_seed: int) -> None:
    from factorloc.estimators.icp import IcpStep

    ref, query, truth, odo, _ = _single_wall_case(noise_seed)
    loc = localize(ref, query, steps=[Recorder("odometry", odo), IcpStep()])
    # the ICP estimate without its seed: it knows the heading and the offset across the wall only
    alone = fuse([loc.step("icp").estimate])
    assert set(alone.undetermined) == {Component.X, Component.Y}
    assert np.isinf(alone.sigmas[:2]).all()
    assert abs(math.remainder(alone.pose.theta - truth.theta, 2 * math.pi)) < math.radians(0.2)


def test_kidnapped_robot_whose_seeded_icp_fits_elsewhere_is_not_localized_confidently() -> None:
    """q0406 of ``simulate --world apartment --queries 1000 --seed 43`` (held out): kidnapped, the odometry reliable
    (σ ≤ 25 cm) but 1.1 m off. Once its odometry was fused alone, confidently wrong. With the simulated lidar's
    sensor-pose error (issue 14) the alignment seeded by the odometry puts half of the scan into space the reference
    saw empty: the seed is refuted, the global initialization finds the true pose and the odometry is dropped. (The
    unconfirmed-seed case, ``icp.seed.stays_near``, is tested in ``tests/estimators/test_icp.py``.)"""
    from factorloc.evaluation import metrics
    from factorloc.sim import generate_scenario

    scenario = generate_scenario("apartment", 1000, 43, only_queries=[406])
    sq = scenario.queries[0]
    assert "kidnapped" in sq.faults
    loc = Localizer(scenario.references[0].reference).localize(sq.query)
    odo, icp = loc.step("odometry"), loc.step("icp")
    assert odo.estimate.reliable and math.hypot(odo.estimate.values[0] - sq.truth.x, odo.estimate.values[1] - sq.truth.y) > 1.0
    assert [c.code for c in icp.estimate.seed.checks if not c.passed] == ["icp.seed.free_space"]
    assert odo.status is StepStatus.INCONSISTENT
    err = metrics.pose_errors(loc.pose.as_array()[None], sq.truth.as_array()[None])
    assert math.hypot(err[0, 0], err[0, 1]) < 0.1 and not metrics.confidently_wrong(err, loc.covariance[None])[0]


def test_with_config_shares_the_prepared_references_and_needs_the_same_steps() -> None:
    """A second configuration on one reference's work (the tracker's runs without ICP's widened search): the same
    prepared objects, the new configuration's steps, the same estimates where the two configurations agree."""
    ref = Reference(scan=Scan(np.column_stack([np.linspace(-2.0, 2.0, 41), np.full(41, 1.5)])))
    base = Localizer(ref)
    narrow = Config.from_dict({"icp": {"global_init": {"widen": False}}})
    other = base.with_config(narrow)
    assert other._prepared is base._prepared and other.prepare_seconds is base.prepare_seconds
    assert other.config is narrow and not other.steps[-1].config.global_init.widen and base.steps[-1].config.global_init.widen
    q = Query(scan=Scan(ref.scan.points_m - [0.05, 0.0]), odometry=Odometry(Pose2(0.05, 0.0, 0.0), 0.1, 0.1, 0.05))
    a, b = base.localize(q), other.localize(q)
    assert np.array_equal(a.pose.as_array(), b.pose.as_array())
    with pytest.raises(InputError, match="same steps"):
        base.with_config(Config.from_dict({"compass": {"enabled": False}}))
    with pytest.raises(InputError, match="Config"):
        base.with_config({"icp": {}})

"""The ICP step on the simulated apartment: accuracy with a reliable seed, global initialization of a kidnapped
robot, covariance calibration, corridor degeneracy, and the Step protocol."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
import pytest
from scipy.spatial import cKDTree

from factorloc import localize
from factorloc.config import Config
from factorloc.errors import ConfigError, InputError
from factorloc.estimators.base import Hypotheses, Step
from factorloc.estimators.icp import (
    AlignmentConfig,
    CovarianceConfig,
    GlobalInitConfig,
    IcpConfig,
    IcpStep,
    ReliabilityConfig,
    estimate,
    prepare_reference,
    query_points,
)
from factorloc.estimators.odometry import OdometryStep
from factorloc.gating import seed_audit
from factorloc.geometry import Pose2
from factorloc.sim import DepthCamera, apartment, render_cloud, render_cloud_360
from factorloc.types import Estimate, Odometry, Query, Reference, Scan, StepStatus
from factorloc.verdicts import render_check, render_checks


@dataclass
class Case:
    reference: Reference
    query: Query
    truth: Pose2
    overlap: float


def _cov(cfg: IcpConfig, **kwargs: float) -> IcpConfig:
    """``cfg`` with its covariance group's fields replaced."""
    return replace(cfg, covariance=replace(cfg.covariance, **kwargs))


def _free_pose(world, rng: np.random.Generator, clearance: float = 0.4) -> Pose2:
    x0, y0, x1, y1 = world.bounds_xy
    while True:
        p = rng.uniform([x0, y0], [x1, y1])
        if world.is_free(p[None, :], clearance)[0]:
            return Pose2(p[0], p[1], rng.uniform(-math.pi, math.pi))


def _pose_within_2m(world, T_ref: Pose2, rng: np.random.Generator) -> Pose2:  # noqa: ANN001 - a sim World
    """A pose uniform over the free disc of radius 2 m around ``T_ref`` (clearance 0.3 m), any heading."""
    while True:
        r, a = 2.0 * math.sqrt(rng.uniform()), rng.uniform(-math.pi, math.pi)
        p = np.array([T_ref.x + r * math.cos(a), T_ref.y + r * math.sin(a)])
        if world.is_free(p[None, :], 0.3)[0]:
            return Pose2(p[0], p[1], rng.uniform(-math.pi, math.pi))


def _cases(n: int, seed: int, query_360: bool) -> list[Case]:
    """Reference = 360° cloud; query within 2 m of it, a single depth view (or a 360° one)."""
    world = apartment()
    rng = np.random.default_rng(seed)
    cfg = IcpConfig()
    out: list[Case] = []
    while len(out) < n:
        T_ref = _free_pose(world, rng)
        truth = _pose_within_2m(world, T_ref, rng)
        try:
            ref = Reference(cloud=render_cloud_360(world, T_ref, DepthCamera(stride_px=4), rng), T_world_reference=T_ref)
            cloud = (
                render_cloud_360(world, truth, DepthCamera(stride_px=4), rng)
                if query_360
                else render_cloud(world, truth, DepthCamera(stride_px=2), rng)
            )
            q = Query(cloud=cloud)
            pts = query_points(q, cfg)
        except InputError:
            continue  # the camera faces a wall too closely to see anything in the band
        if len(pts) < cfg.reliability.min_inliers:
            continue
        prep = prepare_reference(ref, cfg)
        d, _ = cKDTree(prep.points_m).query(T_ref.between(truth).transform_points(pts))
        out.append(Case(ref, q, truth, float(np.mean(d < 0.1))))
    return out


@pytest.fixture(scope="module")
def seeded_results() -> list[tuple[Case, Estimate]]:
    rng = np.random.default_rng(7)
    out = []
    for case in _cases(24, 11, query_360=False):
        t = case.truth
        seed = Pose2(t.x + rng.normal(0, 0.05), t.y + rng.normal(0, 0.05), t.theta + rng.normal(0, math.radians(2)))
        hyp = Hypotheses((Estimate.pose("odometry", seed, 0.05, 0.05, math.radians(2)),))
        prep = prepare_reference(case.reference)
        out.append((case, estimate(prep, query_points(case.query, prep.config), hyp, query_from_cloud=True)))
    return out


def _errors(case: Case, est: Estimate) -> tuple[float, float, float]:
    e = np.array([est.values[0] - case.truth.x, est.values[1] - case.truth.y])
    nees = float(e @ np.linalg.solve(est.covariance[:2, :2], e))
    return float(np.hypot(*e)), abs(math.remainder(est.values[2] - case.truth.theta, 2 * math.pi)), nees


def _failed(est: Estimate) -> list[str]:
    """The codes of the estimate's failed checks, in order."""
    return [c.code for c in est.checks if not c.passed]


def _degenerate(est: Estimate) -> bool:
    """A degenerate view's estimate: reliable across the walls and in heading, unknown along them."""
    return est.reason.startswith("across the walls and heading only")


def _full(seeded_results) -> list:
    """The reliable full-pose estimates (those of degenerate views, unknown along the walls, are tested on their own)."""
    return [(c, e) for c, e in seeded_results if e.reliable and e.kind == "full" and not _degenerate(e)]


def test_seeded_icp_is_accurate_within_2_m_of_the_reference(seeded_results) -> None:
    errs = np.array([_errors(c, e) for c, e in _full(seeded_results)])
    assert len(errs) >= 0.3 * len(seeded_results)  # single 58° views often see one wall only: honestly unreliable
    assert np.median(errs[:, 0]) < 0.02
    assert np.median(np.degrees(errs[:, 1])) < 0.5


def test_seeded_covariance_is_calibrated_and_never_confidently_wrong(seeded_results) -> None:
    nees = np.array([_errors(c, e)[2] for c, e in _full(seeded_results)])
    assert 0.5 < nees.mean() < 3.5  # χ² with 2 dof has mean 2
    assert np.all(nees < 13.8)  # nothing beyond the 99.9 % ellipse


def test_degenerate_views_are_accurate_across_the_walls_and_in_heading_unknown_along(seeded_results) -> None:
    degenerate = [(c, e) for c, e in seeded_results if _degenerate(e)]
    assert len(degenerate) >= 2  # single 58° views of one wall: the position slides along it, not across, nor the heading
    for case, est in degenerate:
        assert est.reliable and est.kind == "full"
        assert "degenerate geometry" in est.reason
        err = abs(math.remainder(est.values[2] - case.truth.theta, 2 * math.pi))
        assert err < 3.0 * est.sigma("theta") and err < math.radians(1.0)
        lam, vec = np.linalg.eigh(est.covariance[:2, :2])
        assert math.sqrt(lam[1]) > 20.0  # along the wall: unknown (UNCONSTRAINED_SIGMA_M = 30 m)
        assert math.sqrt(lam[0]) < 0.03  # across: ICP's own σ
        across = float(vec[:, 0] @ np.array([est.values[0] - case.truth.x, est.values[1] - case.truth.y]))
        assert abs(across) < 3.0 * math.sqrt(lam[0]) and abs(across) < 0.03


def test_a_distant_global_solution_does_not_overturn_a_free_space_consistent_seed(seeded_results) -> None:
    # single 58° views whose seeded alignment found nothing (the reference never saw what the query sees) but put
    # no point into seen-free space: the better-fitting place the global search finds elsewhere is not the truth
    blocked = [(c, e) for c, e in seeded_results if "icp.global.seed_refuted" in _failed(e)]
    assert len(blocked) >= 2
    for case, est in blocked:
        assert not est.reliable
        assert est.diagnostics["used_global_init"]
        assert est.diagnostics["seeded_violation"] <= 0.12
        assert _errors(case, est)[0] > 0.3  # the global solution was wrong
        # not refuted, but not confirmed either: the step itself reports it, and the pipeline's seed audit reads
        # exactly that (one source) — neither the seed nor the global solution is fused
        assert est.seed.contradicted and [c.code for c in est.seed.checks if not c.passed] == ["icp.seed.fits_near"]
        odo = Estimate.pose("odometry", case.truth, 0.05, 0.05, math.radians(2))
        audit = seed_audit([odo, est])
        assert list(audit) == [0] and audit[0].code == "gate.seed_audit" and audit[0].note == est.seed.reason


def test_a_seeded_icp_reports_its_seed_audit_verdict_itself(seeded_results) -> None:
    # the seed audit's one source: every seeded estimate carries typed seed evidence, contradicted only when its scan
    # refutes the seed
    for _, est in seeded_results:
        assert est.seed is not None and est.seed.position_step == "odometry"
        refuted = est.diagnostics["seeded_violation"] > 0.12 or (est.diagnostics["used_global_init"] and not est.reliable)
        assert est.seed.contradicted == refuted
    assert sum(not e.seed.contradicted for _, e in seeded_results) >= 0.5 * len(seeded_results)


def test_unreliable_estimates_say_why_from_their_failed_checks(seeded_results) -> None:
    for _, est in seeded_results:
        assert est.reason
        if not est.reliable:
            failed = [c for c in est.checks if not c.passed]
            assert failed and all(c.code.startswith("icp.") for c in failed)
            assert est.reason.startswith(render_checks(failed))  # the reason is rendered from them (and the origin)
        else:
            assert all(c.passed for c in est.checks)


@pytest.mark.slow
def test_global_initialization_recovers_kidnapped_robots_where_views_overlap() -> None:
    results = []
    for case in _cases(12, 5, query_360=True):
        prep = prepare_reference(case.reference)
        est = estimate(prep, query_points(case.query, prep.config), Hypotheses())  # no hypothesis at all
        err, herr, _ = _errors(case, est)
        assert est.diagnostics["used_global_init"]
        results.append((case.overlap, err < 0.1 and herr < math.radians(1.0), est.reliable))
    overlapping = [r for r in results if r[0] > 0.5]
    assert len(overlapping) >= 8
    assert np.mean([ok for _, ok, _ in overlapping]) >= 0.9
    assert sum(1 for _, ok, rel in results if rel and not ok) <= 1  # reliable but wrong


def test_a_corridor_is_flagged_degenerate_with_a_long_sigma_along_it() -> None:
    y = np.concatenate([np.full(300, -0.75), np.full(300, 0.75)])
    x = np.tile(np.linspace(-6, 6, 300), 2)
    walls = np.column_stack([x, y])
    prep = prepare_reference(Reference(scan=Scan(walls), T_world_reference=Pose2(1.0, 2.0, math.pi / 2)))
    hyp = Hypotheses((Estimate.pose("odometry", Pose2(1.0, 2.3, math.pi / 2), 0.05, 0.05, 0.02),))
    query = walls[::2] + np.array([0.3, 0.0])
    # the walls fix the heading and the position across them (the reference is turned by 90°, the query by 0): a
    # reliable full pose, unknown along the corridor (world y), ~1 cm across it (world x; the query is shifted along
    # the corridor only, so the true x is the reference's, 1.0, while the seed says nothing wrong across it)
    est = estimate(prep, query, hyp)
    assert est.kind == "full" and est.reliable
    assert abs(math.remainder(est.values[2] - math.pi / 2, 2 * math.pi)) < 1e-3
    assert abs(est.values[0] - 1.0) < 0.005
    assert est.sigma("x") < 0.03 and est.sigma("y") > 20.0
    # the full pose is unreliable, with its long axis along the corridor
    est = estimate(prep, query, hyp, replace(prep.config, seed=replace(prep.config.seed, across_walls=False)))
    assert not est.reliable
    assert _failed(est)[0] == "icp.constraint" and "degenerate" in est.reason
    lam, vec = np.linalg.eigh(est.covariance[:2, :2])
    assert abs(vec[1, 1]) > 0.99  # world y is along the corridor (reference turned by 90°)
    assert math.sqrt(lam[1]) > 10 * math.sqrt(lam[0])


def test_a_seeded_alignment_that_leaves_its_seed_for_a_fit_of_its_own_leaves_the_seed_unconfirmed() -> None:
    # a room; the odometry seed is 4 cm off at σ 1 cm. With a seed-consistency test that accepts no correction at
    # all (χ² at probability 0.01, applied to every geometry), the seeded ICP, right and well fitting, is
    # inconsistent with its seed: it refuses itself, and since the scan fits on its own criteria away from the seed,
    # it does not confirm the seed either (icp.seed.stays_near), so the pipeline's seed audit drops the odometry too
    room = np.array(
        [[3.0, y] for y in np.linspace(-2, 2, 80)]
        + [[x, 2.0] for x in np.linspace(-1, 3, 80)]
        + [[x, -2.0] for x in np.linspace(-1, 3, 80)]
        + [[-1.0, y] for y in np.linspace(-2, 2, 80)]
    )
    truth = Pose2(0.4, -0.2, 0.1)
    seed = Estimate.pose("odometry", Pose2(0.44, -0.2, 0.1), 0.01, 0.01, 0.01)
    cfg = IcpConfig()
    strict = replace(cfg, seed=replace(cfg.seed, consistency_probability=0.01, check_max_constraint=0.5))
    prep = prepare_reference(Reference(scan=Scan(room)), strict)
    est = estimate(prep, truth.inverse().transform_points(room), Hypotheses((seed,)), strict)
    assert not est.reliable and _failed(est) == ["icp.seed.consistency"]
    assert math.hypot(est.values[0] - truth.x, est.values[1] - truth.y) < 0.005
    assert [c.code for c in est.seed.checks if not c.passed] == ["icp.seed.stays_near"]
    audit = seed_audit([seed, est])
    assert list(audit) == [0] and audit[0].code == "gate.seed_audit" and not audit[0].passed
    assert render_check(audit[0]) == f"seed contradicted by icp ({est.seed.reason})"
    # with the default test, the same correction (4σ of the seed, in a room that constrains every direction) stands
    ok = estimate(prepare_reference(Reference(scan=Scan(room))), truth.inverse().transform_points(room), Hypotheses((seed,)))
    assert ok.reliable and not ok.seed.contradicted


def test_step_protocol_skips_without_scans_and_plugs_into_localize() -> None:
    step = IcpStep()
    assert isinstance(step, Step)
    room = np.array(
        [[3.0, y] for y in np.linspace(-2, 2, 80)]
        + [[x, 2.0] for x in np.linspace(-1, 3, 80)]
        + [[x, -2.0] for x in np.linspace(-1, 3, 80)]
    )
    ref = Reference(scan=Scan(room))
    prepared = step.prepare(ref)
    assert step.estimate(prepared, Query(), Hypotheses()) is None
    truth = Pose2(0.4, -0.2, 0.1)
    query = Query(
        scan=Scan(truth.inverse().transform_points(room)), odometry=Odometry(Pose2(0.45, -0.25, 0.12), 0.05, 0.05, 0.03)
    )
    loc = localize(ref, query, Config(), steps=[OdometryStep(), step])
    assert loc.step("icp").status is StepStatus.FUSED
    assert loc.step("icp").estimate.kind == "full"
    assert math.hypot(loc.pose.x - truth.x, loc.pose.y - truth.y) < 0.005
    assert abs(loc.pose.theta - truth.theta) < math.radians(0.2)


def test_the_correlated_error_ratio_follows_the_query_source() -> None:
    # a laser scan gets bias_rmse_ratio (real lidars: per-surface offsets), a depth-cloud cut bias_rmse_ratio_cloud
    case = _cases(1, 5, query_360=True)[0]
    step = IcpStep()
    cfg = step.config
    assert (cfg.covariance.bias_rmse_ratio, cfg.covariance.bias_rmse_ratio_cloud) == (0.75, 0.2)
    prep = step.prepare(case.reference)
    t = case.truth
    hyp = Hypotheses((Estimate.pose("odometry", Pose2(t.x + 0.02, t.y - 0.02, t.theta + 0.01), 0.05, 0.05, 0.03),))
    pts = query_points(case.query, cfg)
    from_cloud = step.estimate(prep, case.query, hyp)
    as_scan = step.estimate(prep, Query(scan=Scan(pts)), hyp)
    assert np.allclose(from_cloud.values, as_scan.values)  # same alignment, different covariance
    assert np.allclose(from_cloud.covariance, estimate(prep, pts, hyp, _cov(cfg, bias_rmse_ratio=0.2)).covariance)
    assert np.allclose(as_scan.covariance, estimate(prep, pts, hyp, cfg).covariance)
    assert np.trace(as_scan.covariance[:2, :2]) > 3.0 * np.trace(from_cloud.covariance[:2, :2])


def test_config_rejects_bad_values() -> None:
    with pytest.raises(ConfigError, match=r"icp\.covariance\.bias_rmse_ratio_cloud"):
        CovarianceConfig(bias_rmse_ratio_cloud=-0.1)
    with pytest.raises(ConfigError, match=r"icp\.covariance\.model"):
        CovarianceConfig(model="magic")
    with pytest.raises(ConfigError, match=r"icp\.alignment\.kernel"):
        AlignmentConfig(kernel="nope")
    with pytest.raises(ConfigError, match=r"icp\.global_init\.refine"):
        GlobalInitConfig(refine=0)
    with pytest.raises(ConfigError, match=r"icp\.reliability"):
        IcpConfig(reliability=ReliabilityConfig(min_fitness=1.5))
    with pytest.raises(ConfigError, match="unknown key"):
        Config.from_dict({"icp": {"min_fitness": 0.5}})  # the groups are nested


def test_config_loads_nested_groups_from_yaml(tmp_path) -> None:
    path = tmp_path / "config.yaml"
    path.write_text(
        "icp:\n  reliability: {min_fitness: 0.5}\n  alignment:\n    icp: {max_iterations: 10}\n  global_init: {enabled: false}\n"
    )
    cfg = Config.from_yaml(path).icp
    assert cfg.reliability.min_fitness == 0.5 and cfg.alignment.icp.max_iterations == 10 and not cfg.global_init.enabled
    assert cfg.alignment.icp.min_correspondence_m == IcpConfig().alignment.icp.min_correspondence_m  # the rest kept
    assert Config.from_dict(Config(icp=cfg).to_dict()).icp == cfg


# (seed, query index) of kidnapped queries of generate_scenario('apartment', 30, seed, faults=('kidnapped',)) whose
# odometry is reliable (σ of a few cm) but 1–2 m off, and where global initialization finds the true pose ((3, 22) only
# in the widened window: the seeds bound the first one away from the truth; (2, 11) after a seeded ICP that barely
# overlaps and looks degenerate)
_KIDNAPPED = ((1, 11), (1, 18), (2, 7), (3, 22), (2, 11))
_WIDENED = {(3, 22)}


@pytest.mark.parametrize(("seed", "index"), _KIDNAPPED)
def test_kidnapped_robot_recovered_through_the_pipeline_odometry_position_gated_out(seed: int, index: int) -> None:
    from factorloc import Localizer
    from factorloc.sim import generate_scenario

    scenario = generate_scenario("apartment", 30, seed, faults=("kidnapped",), only_queries=[index])
    sq = scenario.queries[0]
    assert "kidnapped" in sq.faults
    loc = Localizer(scenario.references[0].reference).localize(sq.query)
    truth = sq.truth
    odo, icp = loc.step("odometry"), loc.step("icp")
    # the odometry claims to be reliable but is off by metres: only the consistency gate can drop it
    assert odo.status is not StepStatus.UNRELIABLE
    assert math.hypot(odo.estimate.values[0] - truth.x, odo.estimate.values[1] - truth.y) > 0.5
    assert odo.status is StepStatus.INCONSISTENT or ("partly fused" in odo.reason and "position inconsistent" in odo.reason)
    # the ICP step's global solution is reliable although it disagrees with the odometry seed
    assert icp.status is StepStatus.FUSED
    assert icp.estimate.diagnostics["used_global_init"]
    if (seed, index) in _WIDENED:
        assert "widened" in icp.reason
    # recovered: within 10 cm and 1° (the simulated lidar errs by ~2 cm per scan pair, like the real logs) and within
    # the fused covariance's 3σ ellipse
    e = np.array([loc.pose.x - truth.x, loc.pose.y - truth.y])
    assert math.hypot(*e) < 0.1 and float(e @ np.linalg.solve(loc.covariance[:2, :2], e)) < 11.83
    assert abs(math.remainder(loc.pose.theta - truth.theta, 2 * math.pi)) < math.radians(1.0)


# --------------------------------------------------------------------------
# the σ model: correlated-error term's heading scale and fitness factor, calibration on simulated and real scans
# --------------------------------------------------------------------------
def _laser_pair(seed: int) -> tuple[Reference, np.ndarray, Pose2, Hypotheses]:
    """A reference and a query 360° LMS200-model laser scan ≤ 2 m apart, and an odometry seed 5 cm / 2° off the truth."""
    from factorloc.sim import render_scan

    world = apartment()
    rng = np.random.default_rng(seed)
    T_ref = _free_pose(world, rng)
    truth = _pose_within_2m(world, T_ref, rng)
    ref = Reference(scan=render_scan(world, T_ref, rng=rng), T_world_reference=T_ref)
    pts = render_scan(world, truth, rng=rng).points_m
    seed_pose = Pose2(truth.x + rng.normal(0, 0.05), truth.y + rng.normal(0, 0.05), truth.theta + rng.normal(0, 0.035))
    return ref, pts, truth, Hypotheses((Estimate.pose("odometry", seed_pose, 0.05, 0.05, 0.035),))


def test_correlated_term_heading_scale_shrinks_only_its_heading_sigma() -> None:
    ref, pts, _, hyp = _laser_pair(3)
    cfg = _cov(IcpConfig(), sigma_floor_m=0.0, sigma_floor_rad=0.0)  # the term alone, without the floors
    prep = prepare_reference(ref, cfg)
    full = estimate(prep, pts, hyp, _cov(cfg, bias_heading_scale=1.0)).covariance
    scaled = estimate(prep, pts, hyp, cfg).covariance  # default 0.85
    white = estimate(prep, pts, hyp, _cov(cfg, bias_rmse_ratio=0.0)).covariance
    np.testing.assert_allclose(scaled[:2, :2], full[:2, :2], rtol=1e-9)
    # heading variance: white + k²·bias; the position–heading covariances: white + k·bias
    assert scaled[2, 2] - white[2, 2] == pytest.approx(0.85**2 * (full[2, 2] - white[2, 2]), rel=1e-6)
    assert scaled[0, 2] - white[0, 2] == pytest.approx(0.85 * (full[0, 2] - white[0, 2]), rel=1e-6, abs=1e-15)
    assert math.sqrt(scaled[2, 2]) < 0.87 * math.sqrt(full[2, 2])  # the bias term dominates the heading σ


def test_correlated_error_grows_as_the_fitness_falls() -> None:
    ref, pts, _, hyp = _laser_pair(3)
    cfg = _cov(IcpConfig(), bias_fitness_ref=0.9)  # off (0) by default
    prep = prepare_reference(ref, cfg)
    est = estimate(prep, pts, hyp, cfg)
    plain = estimate(prep, pts, hyp, _cov(cfg, bias_fitness_ref=0.0)).covariance
    np.testing.assert_array_equal(plain, estimate(prep, pts, hyp, IcpConfig()).covariance)
    white = estimate(prep, pts, hyp, _cov(cfg, bias_rmse_ratio=0.0)).covariance
    fit = est.diagnostics["fitness"]
    assert 0.25 < fit < 0.9
    # σ_b = ratio·rmse·max(1, 0.9 / fitness): the bias term's variances scale by (0.9 / fitness)²
    np.testing.assert_allclose(est.covariance - white, (0.9 / fit) ** 2 * (plain - white), rtol=1e-6, atol=1e-15)
    # ... and a fit above the reference fitness is not made more confident
    high = estimate(prep, pts, hyp, _cov(cfg, bias_fitness_ref=0.5 * fit)).covariance
    np.testing.assert_allclose(high, plain, rtol=1e-12, atol=1e-18)
    with pytest.raises(ConfigError, match="bias_heading_scale"):
        CovarianceConfig(bias_heading_scale=0.0)
    with pytest.raises(ConfigError, match="bias_fitness_ref"):
        CovarianceConfig(bias_fitness_ref=-1.0)


def test_simulated_laser_scans_are_about_as_well_calibrated_as_the_real_logs() -> None:
    # the simulated lidar reproduces the real logs' errors (its sensor-pose error, heavy-tailed like theirs), so the σ
    # set on the real logs fits it as it fits them: ICP position NEES between Intel's 0.49 and MIT CSAIL's 1.69 on
    # all their local relations. Measured on these pairs: position NEES 2.15 (one of 26 beyond 3σ), heading 0.33
    pos, head = [], []
    for seed in range(30):
        ref, pts, truth, hyp = _laser_pair(100 + seed)
        est = estimate(prepare_reference(ref), pts, hyp)
        if not est.reliable or _degenerate(est):
            continue
        e = np.array([est.values[0] - truth.x, est.values[1] - truth.y])
        pos.append(float(e @ np.linalg.solve(est.covariance[:2, :2], e)))
        head.append(math.remainder(est.values[2] - truth.theta, 2 * math.pi) ** 2 / est.covariance[2, 2])
    pos, head = np.array(pos), np.array(head)
    assert len(pos) >= 20
    assert 0.5 < pos.mean() < 3.5 and np.sum(pos > 11.83) <= 1  # 2 dof: mean 2; 3σ ↔ χ² 11.83
    assert 0.05 < head.mean() < 1.5 and np.all(head < 9.0)  # 1 dof: mean 1


@pytest.fixture(scope="module", params=["intel", "aces"])
def real_local_nees(request, shared_data) -> tuple[str, np.ndarray, np.ndarray]:
    """Position and heading NEES of the reliable full-pose ICP estimates on every 20th local relation (path < 5 m)
    of a real laser log, seeded 5 cm / 2° off the ground truth (as ``benchmarks/bench_lidar_model.py``)."""
    from factorloc.datasets.rosbag import read_laser_log
    from factorloc.evaluation.relations import read_relations

    laser = shared_data / "laser"
    log = read_laser_log(laser / f"{request.param}.sort.bag")
    rel = read_relations(laser / f"{request.param}.relations").subset(20)
    rng = np.random.default_rng(0)
    pos, head = [], []
    for t1, t2, T in zip(rel.t1_s, rel.t2_s, rel.poses, strict=True):
        if log.odometry.distance_between(t1, t2)[0] >= 5.0:
            continue
        truth = Pose2.from_array(T)
        seed = Pose2(truth.x + rng.normal(0, 0.05), truth.y + rng.normal(0, 0.05), truth.theta + rng.normal(0, 0.035))
        hyp = Hypotheses((Estimate.pose("odometry", seed, 0.05, 0.05, 0.035),))
        ref = Reference(scan=log.scans.at(t1, 2e-3), T_world_reference=Pose2())
        est = estimate(prepare_reference(ref), log.scans.at(t2, 2e-3).points_m, hyp)
        if not est.reliable or _degenerate(est):
            continue
        e = np.array([est.values[0] - truth.x, est.values[1] - truth.y])
        pos.append(float(e @ np.linalg.solve(est.covariance[:2, :2], e)))
        head.append(math.remainder(est.values[2] - truth.theta, 2 * math.pi) ** 2 / est.covariance[2, 2])
    return request.param, np.array(pos), np.array(head)


def test_real_laser_logs_heading_and_position_sigma_are_honest_in_bulk_and_tail(real_local_nees) -> None:
    name, pos, head = real_local_nees
    assert len(pos) > 45
    # 2 dof / 1 dof: a calibrated σ has means 2 / 1; the real errors are heavy-tailed, so the σ is set by the tail.
    # Measured (Intel 88 / ACES 57 estimates): position NEES 0.69 / 0.94, heading 0.38 / 0.64, none beyond 3σ; one
    # outlier is tolerated (on every local relation the shares beyond 3σ are ≤ 0.2 %, see the IcpConfig docstring).
    assert 0.4 < pos.mean() < 2.0 and np.sum(pos > 11.83) <= 1
    assert 0.25 < head.mean() < 1.0 and np.sum(head > 9.0) <= 1


# --------------------------------------------------------------------------
# weak priors: an earlier step's estimate too broad to seed (global_init.weak_prior)
# --------------------------------------------------------------------------
def _too_broad_odometry(pose: Pose2, sigma_m: float, sigma_rad: float) -> Estimate:
    """An odometry estimate unreliable only by the odometry step's σ rule (limits 0.5 m, 0.55 rad)."""
    from factorloc.estimators.base import sigma_checks

    est = Estimate.pose("odometry", pose, sigma_m, sigma_m, sigma_rad)
    checks = sigma_checks(est, 0.5, 0.55)
    return est.with_verdict(all(c.passed for c in checks), render_checks(checks, only_failed=True), checks)


def _weak_prior(cfg: IcpConfig, contest: bool = True) -> IcpConfig:
    """``cfg`` with the weak prior on (``contest=False``: its window and rivals only, not its free-space contest)."""
    on = replace(cfg, global_init=replace(cfg.global_init, weak_prior=True))
    return on if contest else replace(on, ablate=(*on.ablate, "icp.global.seed_refuted.weak"))


def test_hypotheses_keep_only_estimates_unreliable_by_the_sigma_rule_as_weak_priors() -> None:
    broad = _too_broad_odometry(Pose2(1.0, 2.0, 0.3), 0.6, 0.1)
    refuted = Estimate.pose("compass", Pose2(), 0.6, 0.6, 0.1, reliable=False, reason="peak < Ct")
    hyp = Hypotheses().plus(broad).plus(refuted)
    assert not broad.reliable and hyp.position() is None and hyp.heading() is None
    (x, y, sx, sy, step), heading = hyp.weak_pose()
    assert (x, y, sx, sy, step) == (pytest.approx(1.0), pytest.approx(2.0), pytest.approx(0.6), pytest.approx(0.6), "odometry")
    assert heading == (pytest.approx(0.3), pytest.approx(0.1), "odometry")
    assert Hypotheses().plus(refuted).weak_pose() is None  # refuted by its own tests, not merely broad
    assert Hypotheses.of([broad, refuted]).weak == (broad,)


def test_a_weak_prior_contests_a_global_solution_outside_its_region_as_a_seed_does() -> None:
    from factorloc.estimators.icp.rules import Contest, Evidence, seed_refuted

    cfg = _weak_prior(IcpConfig())
    consistent = Evidence(0.5, 0.2, 0.01, contest=Contest(0.5, 0.1, "odometry", (0.3, 0.02), weak=True))
    c = seed_refuted(consistent, cfg)
    assert not c.passed
    assert render_check(c).startswith("not free to overturn the odometry prior (it contradicts the odometry prior, whose own")
    refuted = Evidence(0.5, 0.2, 0.01, contest=Contest(0.5, 0.1, "odometry", (0.1, 0.3), weak=True))
    assert seed_refuted(refuted, cfg).passed  # the scan puts 30 % of the prior's alignment into seen-free space
    assert seed_refuted(consistent, _weak_prior(IcpConfig(), contest=False)) is None


def test_a_weak_prior_leaves_a_kidnapped_robots_global_solution_reliable_without_its_contest() -> None:
    # a sim apartment laser pair (seed 1); the odometry is 4 m off the truth and turned by 1 rad, at σ 0.6 m (too
    # broad to seed). The best alignment in the prior's own window fits poorly (0.21) but is free-space consistent,
    # so with the free-space contest the right global solution may not overturn the prior; with the window and
    # rivals only, it is reliable and right, as without the weak prior
    from factorloc.sim import render_scan

    world = apartment()
    rng = np.random.default_rng(1)
    T_ref = _free_pose(world, rng)
    truth = _pose_within_2m(world, T_ref, rng)
    ref = Reference(scan=render_scan(world, T_ref, rng=rng), T_world_reference=T_ref)
    pts = render_scan(world, truth, rng=rng).points_m
    a = rng.uniform(-math.pi, math.pi)
    prior = _too_broad_odometry(Pose2(truth.x + 4.0 * math.cos(a), truth.y + 4.0 * math.sin(a), truth.theta + 1.0), 0.6, 0.3)
    hyp = Hypotheses().plus(prior)
    prep = prepare_reference(ref)
    for cfg in (IcpConfig(), _weak_prior(IcpConfig(), contest=False)):
        est = estimate(prep, pts, hyp, cfg)
        assert est.reliable and math.hypot(est.values[0] - truth.x, est.values[1] - truth.y) < 0.1
        assert est.seed is None  # a weak prior is never a seed the audit reads
    blocked = estimate(prep, pts, hyp, _weak_prior(IcpConfig()))
    assert not blocked.reliable and _failed(blocked) == ["icp.global.seed_refuted"]
    assert "contradicts the odometry prior" in blocked.reason


def test_a_weak_odometry_prior_keeps_a_corridor_view_from_a_confidently_wrong_global_solution() -> None:
    # data/sample q0022: a corridor view 6 m from the reference, odometry 0.59 m off at σ (0.27, 0.51) m, unreliable
    # by 7 mm. Without the weak prior ICP's global search accepts a solution 9.2 m off at σ of a few cm; with it, the
    # best alignment in the odometry's window is free-space consistent, so that solution may not overturn the prior
    from pathlib import Path

    from factorloc import Localizer
    from factorloc.datasets import load_scenario
    from factorloc.evaluation import metrics

    scen = load_scenario(Path(__file__).resolve().parents[2] / "data" / "sample")
    case = scen.query_by_id("q0022")
    base = Config()
    for weak_prior, wrong in ((False, True), (True, False)):
        icp = replace(base.icp, global_init=replace(base.icp.global_init, weak_prior=weak_prior))
        loc = Localizer(scen.reference_of(case), replace(base, icp=icp)).localize(case.query)
        assert loc.step("odometry").status is StepStatus.UNRELIABLE
        assert (loc.step("icp").status is StepStatus.FUSED) is wrong
        assert ("icp.global.seed_refuted" in loc.step("icp").rule_codes) is not wrong
        err = metrics.pose_errors(loc.pose.as_array()[None], case.truth.as_array()[None])
        assert bool(metrics.confidently_wrong(err, loc.covariance[None])[0]) is wrong


def test_near_seed_is_the_seed_fit_and_last_stage_by_replace():
    """:func:`near_seed` (direct construction) gives the solution ``dataclasses.replace`` would: evidence with the
    seed fit, checks judged after the first stages, the rest kept."""
    from factorloc.estimators.icp.candidates import QueryScan, Seeds, near_seed, seed_fit, seeded_attempt
    from factorloc.estimators.icp.rules import judge

    cfg = IcpConfig()
    rng = np.random.default_rng(2)
    ang = np.linspace(-math.pi, math.pi, 240, endpoint=False)
    room = np.column_stack([np.clip(3 / np.abs(np.cos(ang)), 0, 4) * np.cos(ang), 2.5 * np.sin(ang)])
    prepared = prepare_reference(Reference(scan=Scan(room)), cfg)
    qry = room[::2] + rng.normal(0, 0.01, (120, 2))
    seeds = Seeds((0.05, -0.03, 0.2, 0.2, "odometry"), (0.02, 0.05, "odometry"))
    sol = seeded_attempt(prepared, QueryScan(qry, cfg), seeds, cfg)
    ev = replace(sol.evidence, seed_fit=seed_fit(prepared, sol, seeds, cfg))
    want = replace(sol, evidence=ev, checks=judge(ev, cfg, after=sol.checks))
    got = near_seed(prepared, sol, seeds, cfg)
    assert got.evidence == want.evidence and got.checks == want.checks and got.reliable == want.reliable
    assert (got.result, got.covariance, got.origin, got.used_global, got.n_candidates) == (
        want.result,
        want.covariance,
        want.origin,
        want.used_global,
        want.n_candidates,
    )

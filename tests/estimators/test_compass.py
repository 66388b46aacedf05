"""The virtual compass (θ2) against exact heading truth: real 360° photos cut at known yaws, and synthetic scenes."""

from __future__ import annotations

import math

import numpy as np
import pytest
from helpers_visual import at
from helpers_visual import heading_error as _err

from factorloc import CameraImage, Estimate, Pose2, Query, Reference
from factorloc.errors import ConfigError, InputError
from factorloc.estimators import compass
from factorloc.estimators.base import Hypotheses, Step
from factorloc.sim import photo
from factorloc.verdicts import render_checks


@pytest.fixture(scope="module")
def real(real_photo):
    name, eq, ref = real_photo
    return name, eq, ref, compass.prepare(ref)


@pytest.fixture(scope="module")
def synthetic():
    eq = photo.synthetic_equirectangular(256, rng=np.random.default_rng(11))
    ref = Reference(panorama=photo.reference_panorama(eq, 1024, 160), T_world_reference=Pose2(2.0, -1.0, 0.4))
    return eq, ref, compass.prepare(ref)


def _views(eq, n, rng, fault):
    for _ in range(n):
        heading, yaw = rng.uniform(-math.pi, math.pi), rng.uniform(-0.6, 0.6)
        cam = photo.camera_view(eq, heading, yaw, width_px=320, height_px=240)
        img = cam.image_bgr
        if fault == "lighting":
            img = photo.photometric(
                img, gain=rng.uniform(0.6, 1.4), gamma=rng.uniform(0.75, 1.3), noise_sigma=4.0, blur_sigma_px=0.7, rng=rng
            )
        elif fault == "occlusion":
            img = photo.occlude(img, 0.3, rng=rng, n_blocks=2)
        yield heading, CameraImage(img, cam.hfov_rad, cam.yaw_in_robot_rad)


@pytest.mark.parametrize("fault", ["clean", "lighting", "occlusion"])
def test_heading_on_real_photos_is_accurate_and_never_confidently_wrong(real, fault) -> None:
    name, eq, ref, prepared = real
    rng = np.random.default_rng([len(name), ["clean", "lighting", "occlusion"].index(fault)])
    errors, z, reliable = [], [], []
    for heading, cam in _views(eq, 12, rng, fault):
        est = compass.estimate(ref, Query(images=(cam,)), at(ref), prepared=prepared)
        reliable.append(est.reliable)
        if est.reliable:
            errors.append(_err(est, heading))
            z.append(_err(est, heading) / est.sigma("theta"))
    assert np.mean(reliable) >= (0.6 if fault != "occlusion" else 0.3), f"{name} {fault}: reliable rate {np.mean(reliable):.2f}"
    assert np.median(errors) < math.radians(0.5)
    assert max(z) < 3.0, f"{name} {fault}: a reliable estimate is off by {max(z):.1f}σ"


def test_seeding_by_theta1_shrinks_the_candidate_set_and_keeps_the_answer(synthetic) -> None:
    eq, ref, prepared = synthetic
    cam = photo.camera_view(eq, 1.0, 0.2, width_px=320, height_px=240)
    q = Query(images=(cam,))
    blind = compass.estimate(ref, q, at(ref), prepared=prepared)
    theta_world = 0.4 + 1.0
    seed = Hypotheses((Estimate.pose("odometry", Pose2(2.0, -1.0, theta_world + 0.02), 0.01, 0.01, 0.03),))
    seeded = compass.estimate(ref, q, seed, prepared=prepared)
    assert blind.reliable and seeded.reliable
    assert not blind.seed.windowed and seeded.seed.windowed and seeded.seed.heading_step == "odometry"
    assert seeded.diagnostics["window_rad"] == pytest.approx(math.radians(5.16), abs=1e-3)  # 3σ + nothing below 3°
    assert seeded.diagnostics["candidates"] < 0.5 * blind.diagnostics["candidates"]
    for est in (blind, seeded):  # world frame: the reference's heading is added
        assert _err(est, theta_world) < math.radians(0.3)


def test_a_wrong_seed_does_not_produce_a_confident_heading(synthetic) -> None:
    eq, ref, prepared = synthetic
    cam = photo.camera_view(eq, 1.0, 0.0, width_px=320, height_px=240)
    seed = Hypotheses((Estimate.heading("odometry", 0.4 + 1.0 + math.radians(40), math.radians(1.0)),))
    est = compass.estimate(ref, Query(images=(cam,)), seed, prepared=prepared)
    assert not est.reliable


def test_several_images_and_a_query_panorama_across_the_seam(synthetic) -> None:
    eq, ref, prepared = synthetic
    heading = math.pi - 0.05  # the front camera straddles azimuth ±π of the reference
    cams = tuple(photo.camera_view(eq, heading, yaw, math.radians(60), 200, 150) for yaw in (-2.1, 0.0, 2.1))
    est = compass.estimate(ref, Query(images=cams), at(ref), prepared=prepared)
    assert est.reliable and _err(est, 0.4 + heading) < math.radians(0.3)
    pano_q = photo.panorama_view(eq, heading, 800, 200, math.radians(70))
    est = compass.estimate(ref, Query(panorama=pano_q), at(ref), prepared=prepared)
    assert est.reliable and _err(est, 0.4 + heading) < math.radians(0.3)


def test_orb_detector_also_works(synthetic) -> None:
    eq, ref, _ = synthetic
    cfg = compass.CompassConfig(detector="orb")
    cam = photo.camera_view(eq, -2.0, 0.3, width_px=320, height_px=240)
    est = compass.estimate(ref, Query(images=(cam,)), at(ref), config=cfg)
    assert est.reliable and est.diagnostics["detector"] == "orb"
    assert _err(est, 0.4 - 2.0) < math.radians(0.3)


@pytest.mark.parametrize("value", [0, 255, 77])
def test_black_white_or_flat_images_give_an_unreliable_estimate_with_a_reason(synthetic, value) -> None:
    _, ref, prepared = synthetic
    cam = CameraImage(np.full((240, 320, 3), value, np.uint8))
    est = compass.estimate(ref, Query(images=(cam,)), prepared=prepared)
    assert not est.reliable
    assert "black" in est.reason or "flat" in est.reason
    assert [c.code for c in est.checks] == ["compass.query_views"] and not est.checks[0].passed
    assert est.sigma("theta") == pytest.approx(math.pi)


def test_bad_images_are_refused_by_the_types() -> None:
    with pytest.raises(InputError, match="uint8"):
        CameraImage(np.zeros((240, 320, 3), np.float32))
    with pytest.raises(InputError, match="H×W×3"):
        CameraImage(np.zeros((240, 320), np.uint8))
    with pytest.raises(InputError, match="too small"):
        CameraImage(np.zeros((0, 0, 3), np.uint8))


def test_step_skips_missing_inputs_and_implements_the_protocol(synthetic) -> None:
    eq, ref, _ = synthetic
    step = compass.CompassStep()
    assert isinstance(step, Step) and step.name == "compass"
    prepared = step.prepare(ref)
    assert step.estimate(prepared, Query(), Hypotheses()) is None
    no_pano = Reference(scan=__import__("factorloc").Scan(np.zeros((3, 2))))
    assert step.prepare(no_pano) is None
    assert step.estimate(None, Query(images=(photo.camera_view(eq, 0.0, width_px=64, height_px=48),)), Hypotheses()) is None
    with pytest.raises(InputError, match="panorama"):
        compass.estimate(no_pano, Query())


def test_config_is_validated() -> None:
    with pytest.raises(ConfigError, match="min_inliers"):
        compass.CompassConfig(min_inliers=1)
    with pytest.raises(ConfigError, match="detector"):
        compass.CompassConfig(detector="akaze")
    with pytest.raises(ConfigError, match="query_scale"):
        compass.CompassConfig(query_scale=1.5)
    with pytest.raises(ConfigError, match="query_min_detect_px"):
        compass.CompassConfig(query_min_detect_px=-1)
    for bad in (0.0, 1.0, math.nan):
        with pytest.raises(ConfigError, match="spread_confidence"):
            compass.CompassConfig(spread_confidence=bad)
    with pytest.raises(ConfigError, match="spread_bound_gain"):
        compass.CompassConfig(spread_bound_gain=0.0)
    for bad in (0.0, -1.0, math.inf, math.nan):
        with pytest.raises(ConfigError, match="same_spot_max_d2"):
            compass.CompassConfig(same_spot_max_d2=bad)
        with pytest.raises(ConfigError, match="same_spot_max_sigma_m"):
            compass.CompassConfig(same_spot_max_sigma_m=bad)


def test_detection_scale_never_reduces_a_view_below_the_minimum_pixel_count() -> None:
    cfg = compass.CompassConfig(query_scale=0.5, query_min_detect_px=12000)
    assert compass.detection_scale(160 * 320, cfg) == 0.5  # a 640×480 camera on a 2048-px grid
    assert compass.detection_scale(111 * 160, cfg) == pytest.approx(math.sqrt(12000 / (111 * 160)))  # kept at ≥ 12000 px
    assert compass.detection_scale(40 * 60, cfg) == 1.0  # a tiny view is never upsampled


# --------------------------------------------------------------------------
# The simulated apartment: real parallax (queries away from the reference), faults
# --------------------------------------------------------------------------
SIM_REF = Pose2(3.0, 2.2, 0.3)


@pytest.fixture(scope="module")
def sim_reference():
    from factorloc.sim import DepthCamera, apartment, render_cloud_360, render_panorama

    world = apartment()
    pano = render_panorama(world, SIM_REF, width_px=2048)
    cloud = render_cloud_360(world, SIM_REF, DepthCamera(stride_px=4), np.random.default_rng(1))
    ref = Reference(panorama=pano, cloud=cloud, T_world_reference=SIM_REF)
    return world, ref, compass.prepare(ref)


def sim_queries(world, n, d_range_m, sigma_position_m, fault, seed, *, with_hypotheses=True):
    """``n`` camera queries at free poses ``d_range_m`` from the reference, random headings, with an
    odometry-like hypothesis (position σ ``sigma_position_m``, heading σ 2°) drawn around the truth."""
    from factorloc.sim import PinholeCamera, render_camera

    rng = np.random.default_rng(seed)
    made = 0
    while made < n:
        d, a = rng.uniform(*d_range_m), rng.uniform(-math.pi, math.pi)
        x, y = SIM_REF.x + d * math.cos(a), SIM_REF.y + d * math.sin(a)
        if not world.is_free(np.array([[x, y]]), 0.4)[0]:
            continue
        theta = rng.uniform(-math.pi, math.pi)
        cam = render_camera(world, Pose2(x, y, theta), PinholeCamera(width_px=320, height_px=240))
        img = cam.image_bgr
        if fault == "lighting":
            img = photo.photometric(
                img, gain=rng.uniform(0.6, 1.4), gamma=rng.uniform(0.75, 1.3), noise_sigma=4.0, blur_sigma_px=0.7, rng=rng
            )
        elif fault == "occlusion":
            img = photo.occlude(img, 0.3, rng=rng, n_blocks=2)
        s_th = math.radians(2.0)
        odo = Pose2(x + rng.normal(0, sigma_position_m), y + rng.normal(0, sigma_position_m), theta + rng.normal(0, s_th))
        hyp = Hypotheses((Estimate.pose("odometry", odo, sigma_position_m, sigma_position_m, s_th),))
        made += 1
        yield theta, Query(images=(CameraImage(img, cam.hfov_rad),)), (hyp if with_hypotheses else Hypotheses())


def _run(reference, prepared, queries, config=compass.CompassConfig()):
    errors, z, reliable = [], [], []
    for theta, query, hyp in queries:
        est = compass.estimate(reference, query, hyp, config, prepared=prepared)
        reliable.append(est.reliable)
        if est.reliable:
            errors.append(_err(est, theta))
            z.append(_err(est, theta) / est.sigma("theta"))
    return np.array(errors), np.array(z), float(np.mean(reliable))


#: the fewest reliable of 24 views 0–2 m away, per fault: the default detects query views at half the grid's
#: resolution (~2.4× faster); under 30 % occlusion that leaves fewer inliers (13/24 reliable vs 17/24 at full scale)
MIN_RELIABLE = {"clean": 0.7, "lighting": 0.7, "occlusion": 0.5}


@pytest.mark.parametrize("fault", ["clean", "lighting", "occlusion"])
def test_sim_queries_up_to_2m_are_accurate_and_reliable_ones_within_3_sigma(sim_reference, fault) -> None:
    world, ref, prepared = sim_reference
    errors, z, rate = _run(ref, prepared, sim_queries(world, 24, (0.0, 2.0), 0.005, fault, seed=10))
    assert rate >= MIN_RELIABLE[fault], f"{fault}: reliable rate {rate:.2f}"
    assert np.median(errors) < math.radians(0.5)
    assert np.sum(z > 3.0) <= 0.01 * len(z), f"{fault}: {np.sum(z > 3)} of {len(z)} reliable estimates off by > 3σ"


def test_full_scale_query_detection_keeps_more_occluded_views_reliable(sim_reference) -> None:
    """``query_scale=1``: the query views detected at the grid's resolution (slower), more inliers under occlusion."""
    world, ref, prepared = sim_reference
    full = compass.CompassConfig(query_scale=1.0, query_sift_sigma=1.6)
    errors, z, rate = _run(ref, prepared, sim_queries(world, 24, (0.0, 2.0), 0.005, "occlusion", seed=10), full)
    assert rate >= 0.7, f"full scale, occlusion: reliable rate {rate:.2f}"
    assert np.median(errors) < math.radians(0.5) and np.sum(z > 3.0) == 0


def test_sim_beyond_2m_degrades_gracefully(sim_reference) -> None:
    world, ref, prepared = sim_reference
    errors, z, rate = _run(ref, prepared, sim_queries(world, 16, (2.0, 3.5), 0.005, "clean", seed=11))
    assert 0.1 <= rate < 0.9  # fewer reliable estimates far away …
    assert np.all(z <= 3.0)  # … but those are still within 3σ


def test_sim_realistic_position_hypothesis_gives_honest_sigma(sim_reference) -> None:
    world, ref, prepared = sim_reference
    errors, z, rate = _run(ref, prepared, sim_queries(world, 24, (0.0, 2.0), 0.03, "clean", seed=12))
    assert rate >= 0.6
    assert np.median(errors) < math.radians(1.0)
    assert np.median(z) < 1.5 and np.sum(z > 3.0) <= 1


def test_sim_without_a_position_hypothesis_sigma_covers_an_unknown_displacement(sim_reference) -> None:
    """No hypothesis at all: the heading of the pose resected from the bearings needs none (the bearings measure the
    displacement), but its position is not emitted (nothing checks it against a look-alike); the heading-only
    fallback assumes the robot within 0.3 m of the reference, so its σ is several degrees."""
    world, ref, prepared = sim_reference
    resected = 0
    for theta, query, _ in sim_queries(world, 8, (0.0, 1.0), 0.005, "clean", seed=13):
        est = compass.estimate(ref, query, prepared=prepared)
        assert not est.measures("x")
        if est.reliable and est.reason.startswith("heading of a pose"):
            resected += 1
            assert est.sigma("theta") < math.radians(2.0) and _err(est, theta) <= 3.0 * est.sigma("theta")
        else:
            assert est.sigma("theta") > math.radians(4.0)
            assert not est.reliable or _err(est, theta) <= 3.0 * est.sigma("theta")
    assert resected >= 2  # 2 of these 8 single 320×240 views see enough of the room for a pose (measured)


def test_sim_pose_from_bearings_is_accurate_and_its_covariance_honest(sim_reference) -> None:
    """Beyond the patent: views 0–2 m away, odometry σ 0.2 m — the compass's resected poses against the truth."""
    from factorloc.sim import PinholeCamera, render_camera

    world, ref, prepared = sim_reference
    rng = np.random.default_rng(21)
    perr, d2, n = [], [], 0
    while n < 30:
        d, a = rng.uniform(0.0, 2.0), rng.uniform(-math.pi, math.pi)
        x, y = SIM_REF.x + d * math.cos(a), SIM_REF.y + d * math.sin(a)
        if not world.is_free(np.array([[x, y]]), 0.4)[0]:
            continue
        n += 1
        theta = rng.uniform(-math.pi, math.pi)
        cam = render_camera(world, Pose2(x, y, theta), PinholeCamera(width_px=320, height_px=240))
        odo = Pose2(x + rng.normal(0, 0.2), y + rng.normal(0, 0.2), theta + rng.normal(0, 0.17))
        hyp = Hypotheses((Estimate.pose("odometry", odo, 0.2, 0.2, 0.17),))
        est = compass.estimate(ref, Query(images=(CameraImage(cam.image_bgr, cam.hfov_rad),)), hyp, prepared=prepared)
        if est.reliable and est.measures("x"):
            e = np.array([est.value("x") - x, est.value("y") - y, math.remainder(est.value("theta") - theta, 2 * math.pi)])
            perr.append(math.hypot(e[0], e[1]))
            d2.append(float(e @ np.linalg.solve(est.covariance, e)))
            assert {c.code for c in est.checks} >= {"compass.pose.inliers", "compass.pose.condition", "compass.pose.residual"}
    assert len(perr) >= 8, f"only {len(perr)} of 30 views gave a pose"
    assert np.median(perr) < 0.03, f"position error median {np.median(perr):.3f} m"
    assert np.sum(np.array(d2) > 14.16) <= 1, f"d² {np.round(d2, 1)}"  # 3 dof, 3σ


def test_resection_recovers_heading_and_position_from_exact_bearings() -> None:
    from factorloc.vision.depth import DepthMap
    from factorloc.vision.strips import Grid

    grid = Grid(720, 90, math.radians(60.0), math.pi)
    rng = np.random.default_rng(3)
    ranges = 2.0 + 1.5 * rng.random((1, 360))  # a room of varied depth around the reference
    depth = DepthMap(ranges, grid, Pose2(1.0, 2.0, 0.3), 1.0)
    truth = Pose2(1.6, 1.7, 1.1)
    az_ref = np.asarray(grid.azimuth_of_column(np.linspace(0, 719, 60)))
    pts = depth.world_points(az_ref)
    az_q = np.arctan2(pts[:, 1] - truth.y, pts[:, 0] - truth.x) - truth.theta
    seed = Pose2(truth.x + 0.15, truth.y - 0.1, truth.theta + 0.05)
    cfg = compass.CompassConfig()
    theta, sigma, (x, y) = compass.resect(depth, az_ref, np.zeros_like(az_ref), az_q, seed, 0.3, grid.rad_per_px, cfg)
    assert abs(math.remainder(theta - truth.theta, 2 * math.pi)) < 1e-4
    assert math.hypot(x - truth.x, y - truth.y) < 1e-3  # the prior pulls the MAP by a hair
    # bearings all round pin the heading far better than the 0.3 m prior alone (0.3 m / 2 m ≈ 8.6°) would
    assert sigma < math.radians(0.5)


# --------------------------------------------------------------------------
# Regression: repeated textures and wrong seeds (apartment, 300 queries, seed 7)
# --------------------------------------------------------------------------
#: Queries of ``factorloc simulate --world apartment --queries 300 --seed 7`` that the compass got confidently wrong
#: (|error| > 3σ while reliable): q0091 and q0281 (clean; tiled wall textures put a look-alike vote mode 17–19° from
#: the truth, and the odometry's position is off by up to 2σ), q0146 and q0271 (kidnapped: the odometry seed is ~50° off
#: and a look-alike inside its window "confirmed" it). q0219 and q0261 are good queries (control).
APT300_WRONG = (91, 146, 271, 281)
APT300_GOOD = (219, 261)


@pytest.fixture(scope="module")
def apt300():
    from factorloc.sim import generate_scenario

    scenario = generate_scenario("apartment", 300, 7, only_queries=APT300_WRONG + APT300_GOOD)
    return scenario, compass.prepare(scenario.reference)


def test_repeated_textures_and_wrong_seeds_give_a_correct_or_unreliable_heading(apt300) -> None:
    from factorloc.estimators.odometry import OdometryStep

    scenario, prepared = apt300
    for sq in scenario.queries:
        odometry = OdometryStep().estimate(None, sq.query, Hypotheses())
        est = compass.estimate(scenario.reference, sq.query, Hypotheses((odometry,)), prepared=prepared)
        error = _err(est, sq.truth.theta)
        if int(sq.id[1:]) in APT300_WRONG:
            assert not est.reliable or error <= 3.0 * est.sigma("theta"), (
                f"{sq.id}: reliable, off by {math.degrees(error):.1f}° = {error / est.sigma('theta'):.1f}σ ({est.reason})"
            )
        else:  # the checks do not reject good estimates
            assert est.reliable, f"{sq.id}: {est.reason}"
            assert error < math.radians(0.5)
    kidnapped = [sq for sq in scenario.queries if "kidnapped" in sq.faults]
    assert len(kidnapped) == 2  # the scenario regenerated as measured


def test_resection_trusts_neither_a_wall_of_bearings_nor_far_points_behind_a_depth_edge() -> None:
    """A dozen exact bearings on one near wall and two far bearings whose coarse ranges are 1 m wrong (a depth edge):
    the heading σ must cover the error the far points cause (the map's range spread there widens their σ)."""
    from factorloc.vision.depth import DepthMap
    from factorloc.vision.strips import Grid

    grid = Grid(720, 90, math.radians(60.0), math.pi)
    ranges = np.full((1, 360), 1.2)
    ranges[0, 150:160] = 4.4  # a door: far behind a narrow band of directions, next to the near wall
    pose_ref = Pose2(0.0, 0.0, 0.0)
    truth = Pose2(0.05, -0.08, 0.2)
    door = np.asarray(grid.azimuth_of_column((np.array([153.5, 156.5])) * grid.width_px / 360))
    az = np.concatenate([np.radians(np.linspace(-20.0, 20.0, 12)), door])
    cols = np.mod((grid.azimuth_col0_rad - az) / grid.rad_per_px, grid.width_px) * 360 / grid.width_px
    assert np.all((cols[-2:] >= 150) & (cols[-2:] < 160))  # the two far points lie in the door's cells
    true_ranges = ranges[0, cols.astype(int)].copy()
    true_ranges[-2:] = 3.4  # what they really are
    pts = np.column_stack([true_ranges * np.cos(az), true_ranges * np.sin(az)])
    d = pts - np.array([truth.x, truth.y])
    az_query = np.arctan2(d[:, 1], d[:, 0]) - truth.theta
    spread = np.zeros_like(ranges)
    spread[0, 149:161] = 3.2
    for depth, covers in ((DepthMap(ranges, grid, pose_ref, 1.0, spread), True), (DepthMap(ranges, grid, pose_ref, 1.0), False)):
        out = compass.resect(
            depth, az, np.zeros_like(az), az_query, Pose2(0.0, 0.0, 0.2), 0.1, math.radians(0.1), compass.CompassConfig()
        )
        assert out is not None
        error = abs(math.remainder(out[0] - truth.theta, 2 * math.pi))
        assert (error <= 3.0 * out[1]) is covers, (
            f"spread known: {covers}, error {math.degrees(error):.2f}°, σ {math.degrees(out[1]):.2f}°"
        )


def test_at_the_reference_spot_without_depth_the_votes_own_spread_bounds_the_parallax(real) -> None:
    """Issue 17's same-spot protocol on the real photos (no depth): 640×480 57° views at random yaws with lighting
    changes, an odometry hypothesis drawn with σ 0.2 m / 10°. Without the bound the heading-only σ assumes the
    displacement the odometry allows (≈ 8° at the default 3 m range: above ``max_sigma_rad``, so unreliable);
    the votes agree to a fraction of a pixel, which bounds the parallax, and the step commits — never beyond 3σ."""
    name, eq, ref, prepared = real
    rng = np.random.default_rng([len(name), 17])
    off = compass.CompassConfig(parallax_from_spread=False)
    on_rel, off_rel, errors = 0, 0, []
    for _ in range(24):
        heading = rng.uniform(-math.pi, math.pi)
        cam = photo.camera_view(eq, heading, 0.0, width_px=640, height_px=480, hfov_rad=math.radians(57.0))
        img = photo.photometric(
            cam.image_bgr, gain=rng.uniform(0.6, 1.4), gamma=rng.uniform(0.75, 1.3), noise_sigma=4.0, blur_sigma_px=0.7, rng=rng
        )
        q = Query(images=(CameraImage(img, cam.hfov_rad, cam.yaw_in_robot_rad),))
        odo = Pose2(rng.normal(0.0, 0.2), rng.normal(0.0, 0.2), heading + rng.normal(0.0, math.radians(10.0)))
        hyp = Hypotheses((Estimate.pose("odometry", odo, 0.2, 0.2, math.radians(10.0)),))
        est = compass.estimate(ref, q, hyp, prepared=prepared)
        off_rel += compass.estimate(ref, q, hyp, off, prepared=prepared).reliable
        if est.reliable:
            on_rel += 1
            errors.append(_err(est, heading))
            assert _err(est, heading) < 3.0 * est.sigma("theta")
            assert est.diagnostics["parallax_bound_rad"] < est.diagnostics["sigma_parallax_rad"] + 1e-12
    assert on_rel >= max(6, off_rel + 4), f"{name}: reliable {on_rel}/24 with the bound, {off_rel}/24 without"
    assert float(np.median(errors)) <= math.radians(0.05)


def test_a_panorama_query_without_depth_commits_at_the_spot_only() -> None:
    """A 360° query view and a reference without depth (simulated apartment, odometry drawn with σ 0.2 m / 10°): at
    the reference's spot the votes agree and bound the parallax; 0.3 m away every vote's parallax differs by degrees,
    the inlier band keeps a slice of them, and their spread bounds nothing (measured: 5 of 12 such views were
    reliable, 5° off, before the bound required the band to hold the spread's 3σ)."""
    from factorloc.sim import apartment, render_panorama

    world, t_ref = apartment(), Pose2(3.0, 2.2, 0.3)
    ref = Reference(panorama=render_panorama(world, t_ref, width_px=2048), T_world_reference=t_ref)
    prepared = compass.prepare(ref)
    rng = np.random.default_rng(3)
    for dist in (0.0, 0.3, 0.3, 0.3, 0.3):
        while True:
            a = rng.uniform(-math.pi, math.pi)
            truth = Pose2(t_ref.x + dist * math.cos(a), t_ref.y + dist * math.sin(a), rng.uniform(-math.pi, math.pi))
            if world.is_free(np.array([[truth.x, truth.y]]), 0.3)[0]:
                break
        q = Query(panorama=render_panorama(world, truth, width_px=2048))
        odo = Pose2(t_ref.x + rng.normal(0.0, 0.2), t_ref.y + rng.normal(0.0, 0.2), truth.theta + rng.normal(0.0, 0.17))
        est = compass.estimate(ref, q, Hypotheses((Estimate.pose("odometry", odo, 0.2, 0.2, 0.17),)), prepared=prepared)
        if dist == 0.0:
            assert est.reliable and _err(est, truth.theta) < math.radians(0.05)
        else:
            assert not est.reliable or _err(est, truth.theta) < 3.0 * est.sigma("theta")
            assert est.diagnostics["inliers"] >= compass.CompassConfig().min_inliers  # the bound was computed: not vacuous
            assert est.diagnostics["parallax_bound_rad"] == math.inf


def test_the_dominant_group_does_not_depend_on_where_the_cell_boundaries_fall() -> None:
    """Two false matches on a near object hide each other when a cell boundary splits them (seen on a simulated
    view: an object at x = 3.59–3.61 m straddles 12 × 0.3 m): the object's share and the covariance it adds must be
    the same wherever the scene sits against the grid (``_group_leverage`` uses four half-cell-offset grids)."""
    from factorloc.estimators.compass import _group_leverage

    wall = np.column_stack([np.linspace(0.05, 6.0, 30), np.zeros(30)])  # 30 bearings on one far wall
    obj = np.array([[3.59, 1.6], [3.61, 1.62]])  # two on a near object, 2 cm apart
    out = []
    for dx in (0.0, 0.1, -0.1, 0.05):
        pts = np.vstack([wall, obj]) + [dx, 0.0]
        out.append(_group_leverage(pts, Pose2(3.0 + dx, 3.5, 0.3), np.ones(len(pts)), cell_m=0.3))
    share0, extra0 = out[0]
    assert share0 > 0.7  # the pose's position across the wall rests on the object
    assert np.sqrt(extra0[0, 0]) > 1.0  # without it the position along the wall is barely known
    for share, extra in out[1:]:
        assert share == pytest.approx(share0, rel=1e-9)
        np.testing.assert_allclose(extra, extra0, rtol=1e-6)


def test_a_planar_scan_alone_does_not_lend_the_compass_its_depth_by_default(sim_reference) -> None:
    """A reference with a panorama and a planar scan but no cloud: the scan's one row of ranges would be read for
    every elevation, wrong above and below what the laser cut (a wall above a low cabinet gets the cabinet's
    range). Read so (``planar_depth=True``) it made resected poses 15–33 cm and headings 2–18° off at σ 0.4–3.9°
    (3.0–4.0 % of the simulated scenarios' queries, ``bench_vision.py --pose ... --depth scan``); by default such
    a reference has no depth, and views from other spots are never confidently wrong."""
    from factorloc.sim import render_scan

    world, with_cloud, _ = sim_reference
    scan = render_scan(world, SIM_REF, 360, 0.3, rng=np.random.default_rng(2))
    ref = Reference(panorama=with_cloud.panorama, scan=scan, T_world_reference=SIM_REF)
    configs = {True: compass.CompassConfig(planar_depth=True), False: compass.CompassConfig()}
    prepared = {flag: compass.prepare(ref, cfg) for flag, cfg in configs.items()}
    assert prepared[False].depth is None and prepared[True].depth.planar
    wrong = {True: 0, False: 0}
    for theta, query, hyp in sim_queries(world, 40, (0.2, 1.0), 0.2, "clean", seed=30):
        for flag, cfg in configs.items():
            est = compass.estimate(ref, query, hyp, cfg, prepared=prepared[flag])
            wrong[flag] += est.reliable and _err(est, theta) > 3.0 * est.sigma("theta")
    assert wrong[False] == 0
    assert wrong[True] >= 1  # the reason for the default (measured: 3 of these 40 views)


def test_the_heading_only_verdict_is_typed_checks_and_the_sigma_rule_is_the_shared_one(synthetic) -> None:
    # the heading-only compass (no depth here) reports its rules as typed checks in the order they apply, the reason
    # rendered from them; failing only σθ2's limit makes it a hypothesis too broad to fuse, like every step's σ rule
    eq, ref, prepared = synthetic
    cam = photo.camera_view(eq, 0.7, 0.2, width_px=320, height_px=240)
    hyp = at(ref).plus(Estimate.heading("odometry", 0.4 + 0.7 + 0.01, math.radians(3.0)))
    est = compass.estimate(ref, Query(images=(cam,)), hyp, prepared=prepared)
    codes = [c.code for c in est.checks]
    assert est.reliable and all(c.passed for c in est.checks)
    assert codes[:4] == ["compass.inliers", "compass.inlier_ratio", "compass.ambiguity", "compass.distinct"]
    assert codes[-2:] == ["compass.seed_consistency", "compass.sigma_heading"]
    inliers = est.checks[0]
    assert inliers.value == est.diagnostics["inliers"] and est.reason.startswith(f"{inliers.value:.0f} inlier pairs")
    sigma = est.sigma("theta")
    tight = compass.CompassConfig(max_sigma_rad=0.5 * sigma)
    narrow = compass.estimate(ref, Query(images=(cam,)), hyp, config=tight, prepared=compass.prepare(ref, tight))
    failed = [c for c in narrow.checks if not c.passed]
    assert not narrow.reliable and [c.code for c in failed] == ["compass.sigma_heading"]
    assert failed[0].value == pytest.approx(sigma) and narrow.reason == render_checks(narrow.checks)
    assert Hypotheses().plus(narrow).weak == (narrow,)
    # a seed the views refute: the seed-consistency rule fails, with the gap it measured
    wrong = at(ref).plus(Estimate.heading("odometry", 0.4 + 0.7 + math.radians(2.0), math.radians(0.3)))
    far = compass.estimate(ref, Query(images=(cam,)), wrong, prepared=prepared)
    gap = next(c for c in far.checks if c.code == "compass.seed_consistency")
    assert not far.reliable and not gap.passed and gap.value > gap.limit


def _spot_views(world, offsets_m, rng):
    """640×480 57° views with photometric changes at ``SIM_REF`` moved by each offset (m, world), random headings."""
    from factorloc.sim import PinholeCamera, render_camera

    for dx, dy in offsets_m:
        theta = float(rng.uniform(-math.pi, math.pi))
        truth = Pose2(SIM_REF.x + dx, SIM_REF.y + dy, theta)
        cam = render_camera(world, truth, PinholeCamera(width_px=640, height_px=480, hfov_rad=math.radians(57.0)))
        img = photo.photometric(
            cam.image_bgr, gain=rng.uniform(0.6, 1.4), gamma=rng.uniform(0.75, 1.3), noise_sigma=4.0, blur_sigma_px=0.7, rng=rng
        )
        odo = Pose2(truth.x + rng.normal(0, 0.2), truth.y + rng.normal(0, 0.2), theta + rng.normal(0, math.radians(10.0)))
        hyp = Hypotheses((Estimate.pose("odometry", odo, 0.2, 0.2, math.radians(10.0)),))
        yield truth, Query(images=(CameraImage(img, cam.hfov_rad),)), hyp


def test_at_the_reference_spot_the_pose_is_the_reference_position_and_the_heading_exact(sim_reference) -> None:
    """Issue #17's same spot, with depth: the bearings cannot tell the robot from the reference's spot (the Wald test
    of the reference position under the resection's covariance, when that locates it within 5 cm σ), so the pose is
    re-estimated there — the heading an order of magnitude more accurate than the free resection's (measured: 0.010°
    against 0.136° median over 40 views, ``bench_vision.py --same-spot 40``; here 8 of 12 accepted, 0.019° against
    0.106°) — with the resection's covariance; with the test off, the free pose."""
    world, ref, prepared = sim_reference
    free = compass.CompassConfig(same_spot_max_d2=None)
    at_spot, err, err_free = 0, [], []
    for truth, query, hyp in _spot_views(world, [(0.0, 0.0)] * 12, np.random.default_rng(3)):
        est = compass.estimate(ref, query, hyp, prepared=prepared)
        off = compass.estimate(ref, query, hyp, free, prepared=prepared)
        if not (est.reliable and est.measures("x")):
            continue
        assert off.reliable and off.measures("x") and not off.diagnostics["at_reference"]
        if est.diagnostics["at_reference"]:
            at_spot += 1
            assert est.diagnostics["same_spot_d2"] <= 5.99 and "at the reference" in est.reason
            assert (est.value("x"), est.value("y")) == (SIM_REF.x, SIM_REF.y)
            np.testing.assert_array_equal(est.covariance, off.covariance)  # the resection's own, floors included
        err.append(_err(est, truth.theta))
        err_free.append(_err(off, truth.theta))
    assert at_spot >= 6, f"only {at_spot} of 12 views accepted at the spot"  # measured: 8 (the others σ > 5 cm)
    assert np.median(err) < math.radians(0.05) and np.median(err) < 0.5 * np.median(err_free), (
        np.degrees(np.median(err)),
        np.degrees(np.median(err_free)),
    )


def test_off_the_reference_spot_the_test_refuses_or_stays_within_three_sigma(sim_reference) -> None:
    """A few centimetres away the test may still accept (its power is the resection's σ); the heading it then gives
    is biased by the offset's parallax but stays within the emitted σ's 3σ. From 0.3 m it never accepts."""
    world, ref, prepared = sim_reference
    rng = np.random.default_rng(4)
    near = [(0.03 * math.cos(a), 0.03 * math.sin(a)) for a in rng.uniform(-math.pi, math.pi, 6)]
    far = [(0.3 * math.cos(a), 0.3 * math.sin(a)) for a in rng.uniform(-math.pi, math.pi, 6)]
    far_poses = 0
    for truth, query, hyp in _spot_views(world, near + far, rng):
        est = compass.estimate(ref, query, hyp, prepared=prepared)
        if not (est.reliable and est.measures("x")):
            continue
        e = np.array(
            [est.value("x") - truth.x, est.value("y") - truth.y, math.remainder(est.value("theta") - truth.theta, 2 * math.pi)]
        )
        assert float(e @ np.linalg.solve(est.covariance, e)) <= 14.16  # 3 dof, 3σ
        if math.hypot(truth.x - SIM_REF.x, truth.y - SIM_REF.y) > 0.2:
            far_poses += 1
            assert not est.diagnostics["at_reference"] and est.diagnostics["same_spot_d2"] > 5.99
    assert far_poses >= 3

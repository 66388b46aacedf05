"""``convert_bag``: real laser logs (ROS 1, and ROS 2 / MCAP made by rosbags-convert) and camera bags written here."""

from __future__ import annotations

import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from bagmaker import OPTICAL, BagMaker, ideal_K

import factorloc as fl
from factorloc.datasets import load_scenario, save_scenario
from factorloc.datasets.bag import ConvertConfig, Rigid3, SensorConfig, convert_bag
from factorloc.datasets.rosbag import read_odometry
from factorloc.datasets.tum import read_tum_trajectory, write_tum_trajectory
from factorloc.errors import DatasetError
from factorloc.evaluation import run_hierarchy
from factorloc.evaluation.relations import read_relations
from factorloc.geometry import Pose2
from factorloc.types import StepStatus
from factorloc.vision.panoramas import camera_view_from_equirectangular, load_equirectangular


# --------------------------------------------------------------------------
# The Intel Research Lab log, with its relations as ground truth
# --------------------------------------------------------------------------
@pytest.fixture(scope="module")
def intel(shared_data: Path):
    laser = shared_data / "laser"
    rel = read_relations(laser / "intel.relations")
    conv = convert_bag(laser / "intel.sort.bag", ConvertConfig(reference_every_m=10.0), rel)
    return laser, rel, conv


@pytest.mark.slow
def test_intel_relations_become_queries_against_references_at_their_start(intel) -> None:
    laser, rel, conv = intel
    s, r = conv.scenario, conv.report
    assert r.references == len(s.references) == 66 and r.queries == len(s.queries) == 145
    assert r.queries_with_truth == 145 and not r.missing
    assert r.extrinsics == {"laser": [0.0] * 6}  # /tf_static: base_link → laser is the identity
    odo = read_odometry(laser / "intel.sort.bag")
    for q in s.queries:
        ref = s.reference_by_id(q.reference_id)
        t_ref = ref.metadata["time_s"]
        # the world frame is the odometry's: the reference sits at odom(t1), the truth at odom(t1)·T_12
        assert ref.reference.T_world_reference == odo.pose_at(t_ref)
        candidates = [i for i, (a, b) in enumerate(zip(rel.t1_s, rel.t2_s, strict=True)) if abs(a - t_ref) < 2e-3]
        i = min(candidates, key=lambda k: abs(rel.t2_s[k] - q.timestamp_s))
        true = odo.pose_at(t_ref) * Pose2.from_array(rel.poses[i])
        assert abs(rel.t2_s[i] - q.timestamp_s) < 2e-3
        assert np.allclose(q.truth.as_array(), true.as_array(), atol=1e-9)
        # the odometry is the dead-reckoned pose with the default model's σ
        d, rot = odo.distance_between(t_ref, q.timestamp_s)
        assert q.query.odometry.sigma_x_m == pytest.approx(max(0.05, 0.2 * d))


@pytest.mark.slow
def test_intel_converted_to_ros2_and_mcap_by_rosbags_convert_gives_the_same_scenario(intel, tmp_path: Path) -> None:
    laser, rel, conv = intel
    tool = Path(sys.executable).with_name("rosbags-convert")
    for storage in ("sqlite3", "mcap"):
        dst = tmp_path / f"intel-{storage}"
        subprocess.run(
            [str(tool), "--src", str(laser / "intel.sort.bag"), "--dst", str(dst), "--dst-storage", storage],
            check=True,
            capture_output=True,
        )
        other = convert_bag(dst, ConvertConfig(reference_every_m=10.0), rel).scenario
        assert [q.id for q in other.queries] == [q.id for q in conv.scenario.queries]
        assert other.references == conv.scenario.references
        assert all(
            a.truth == b.truth and a.query.odometry == b.query.odometry
            for a, b in zip(other.queries, conv.scenario.queries, strict=True)
        )
        assert all(
            np.array_equal(a.query.scan.points_m, b.query.scan.points_m)
            for a, b in zip(other.queries, conv.scenario.queries, strict=True)
        )


# --------------------------------------------------------------------------
# A camera + depth bag rendered by the simulator
# --------------------------------------------------------------------------
T_BASE_CAMERA = Rigid3.from_xyz_rpy(0.0, 0.0, 1.0, 0.0, 0.0, 0.0) * OPTICAL
#: an odometry model for the bags written here (their odometry drifts 1 cm and 0.2° per leg)
TIGHT = fl.OdometryModel(
    drift_ratio=0.05, min_sigma_m=0.01, heading_drift_ratio=0.02, heading_drift_rad_per_m=0.01, min_sigma_rad=0.005
)


@pytest.fixture(scope="module")
def sim_bag(tmp_path_factory):
    """The robot turns on the spot at the apartment's reference (8 views, 45° apart), then drives 5 short legs.

    Camera: raw rgb8 320×240, 57°, with CameraInfo; depth camera: PointCloud2 in its optical frame; both 1 m up.
    Truth: a TUM file. Odometry: exact during the turn, then 1 cm and 0.2° more drift per leg.
    """
    from factorloc.sim import world_by_name
    from factorloc.sim.generate import reference_pose_of
    from factorloc.sim.render import DepthCamera, PinholeCamera, render_camera, render_cloud

    out = tmp_path_factory.mktemp("simbag")
    world = world_by_name("apartment")
    ref = reference_pose_of(world)
    cam, depth = PinholeCamera(320, 240, math.radians(57.0)), DepthCamera(stride_px=4)
    rng = np.random.default_rng(0)
    bm = BagMaker(out / "sim.bag")
    bm.static_tf({("base_link", "camera_optical"): T_BASE_CAMERA, ("base_link", "depth_optical"): T_BASE_CAMERA})
    bm.camera_info("/camera/camera_info", "camera_optical", 320, 240, ideal_K(320, 240, cam.hfov_rad))
    stamps, poses = [], []

    def publish(t: float, true: Pose2, sense: bool, drift: Pose2 = Pose2()) -> None:
        bm.odometry(ref.inverse() * true * drift, t)
        stamps.append(bm.t0 + t)
        poses.append(true.as_array())
        if sense:
            bm.image("/camera/image_raw", "camera_optical", render_camera(world, true, cam).image_bgr, t, encoding="rgb8")
            pts = render_cloud(world, true, depth, rng).points_m
            bm.cloud("/depth/points", "depth_optical", T_BASE_CAMERA.inverse().apply(pts), t)

    t = 0.0
    for k in range(8):
        publish(t, Pose2(ref.x, ref.y, ref.theta + k * math.pi / 4), True)
        for s in range(1, 10):
            publish(t + 0.1 * s, Pose2(ref.x, ref.y, ref.theta + (k + s / 10) * math.pi / 4), False)
        t += 1.0
    cur, legs = Pose2(ref.x, ref.y, ref.theta), 0
    while legs < 5:
        goal = Pose2(cur.x + rng.uniform(-0.5, 0.5), cur.y + rng.uniform(-0.5, 0.5), cur.theta + rng.uniform(-1.0, 1.0))
        if not world.is_free(np.array([[goal.x, goal.y]]), 0.4)[0]:
            continue
        for s in range(1, 21):
            a = s / 20
            th = cur.theta + a * math.remainder(goal.theta - cur.theta, 2 * math.pi)
            publish(
                t + 0.1 * s,
                Pose2(cur.x + a * (goal.x - cur.x), cur.y + a * (goal.y - cur.y), th),
                s == 20,
                Pose2(0.01 * legs, 0, 0.003 * legs),
            )
        t, cur, legs = t + 2.5, goal, legs + 1
    bm.close()
    write_tum_trajectory(out / "truth.tum", np.array(stamps), np.array(poses))
    return out, bm.t0


def test_a_camera_and_depth_bag_converts_and_its_queries_run_the_compass_and_the_correlation(sim_bag, tmp_path: Path) -> None:
    out, t0 = sim_bag
    truth = read_tum_trajectory(out / "truth.tum")
    config = ConvertConfig(reference_times_s=(t0 + 7.0,), query_every_m=0.2, odometry_model=TIGHT)
    conv = convert_bag(out / "sim.bag", config, truth)
    assert conv.report.topics["keyframes"] == "cloud" and conv.report.topics["cameras"] == ["/camera/image_raw"]
    ref = conv.scenario.references[0].reference
    # the turn on the spot: eight 57° views stitched into a full panorama, eight depth views into a 360° cloud
    assert ref.panorama is not None and ref.panorama.seen_columns is None and ref.panorama.width_px == 2048
    assert ref.T_world_reference == truth.pose_at(t0 + 7.0)
    az = np.arctan2(ref.cloud.points_m[:, 1], ref.cloud.points_m[:, 0])
    assert np.histogram(az, bins=8, range=(-math.pi, math.pi))[0].min() > 200
    path = save_scenario(conv.scenario, tmp_path / "scn")
    run = run_hierarchy(load_scenario(path))
    assert len(run.runs) == 6
    for r in run.runs:
        steps = {s.name: s for s in r.reports}
        assert steps["compass"].status is not StepStatus.SKIPPED and steps["correlation"].status is not StepStatus.SKIPPED
        for name in ("compass", "correlation"):
            est = steps[name].estimate
            if est.reliable:  # right within 3σ of the heading truth
                assert abs(math.remainder(est.value("theta") - r.case.truth.theta, 2 * math.pi)) < 3 * est.sigma("theta")
        e = r.localization.pose.between(r.case.truth)
        assert math.hypot(e.x, e.y) < 0.03 and abs(e.theta) < math.radians(0.5)
    fused = [sum(s.fused for s in r.reports if s.name in ("compass", "correlation")) for r in run.runs]
    assert sum(f == 2 for f in fused) >= 5  # both camera steps fused on (nearly) every query


# --------------------------------------------------------------------------
# A camera-only bag of views cut from the real panoramas (JPEG), turning on the spot
# --------------------------------------------------------------------------
@pytest.mark.parametrize("photo", ["indoor-bedroom.png", "outdoor-summit.jpg"])
def test_a_compressed_camera_bag_of_a_real_panorama_gives_headings_within_a_tenth_of_a_degree(
    photo: str, shared_data: Path, tmp_path: Path
) -> None:
    eq = load_equirectangular(shared_data / "panoramas" / photo)
    rng = np.random.default_rng(len(photo))
    bm = BagMaker(tmp_path / "cam.bag")
    bm.static_tf({("base_link", "cam_optical"): T_BASE_CAMERA})
    bm.camera_info("/cam/camera_info", "cam_optical", 640, 480, ideal_K(640, 480, math.radians(57.0)))
    headings = []

    def at(t: float, x: float, heading: float, sense: bool) -> None:
        bm.odometry(Pose2(x, 0.0, heading), t)
        if sense:
            img = camera_view_from_equirectangular(eq, heading, width_px=640, height_px=480).image_bgr
            bm.compressed_image("/cam/image_raw/compressed", "cam_optical", img, t)

    for k in range(8):  # the reference: 8 views 45° apart, 1 s apart
        at(float(k), 0.0, k * math.pi / 4, True)
    at(9.0, 0.3, 0.0, False)  # drive off and back: the reference's stay on the spot ends
    at(10.0, 0.0, 0.0, False)
    for k, h in enumerate(np.sort(rng.uniform(-math.pi, math.pi, 12))):  # the queries: held-back headings, one turn
        headings.append(float(h))
        at(11.0 + k, 0.0, float(h), True)
    bm.close()
    conv = convert_bag(tmp_path / "cam.bag", ConvertConfig(reference_times_s=(bm.t0,), query_every_m=0.0, odometry_model=TIGHT))
    assert conv.report.topics["keyframes"] == "camera /cam/image_raw/compressed"
    ref = conv.scenario.references[0].reference
    assert ref.panorama is not None and ref.cloud is None and ref.scan is None
    queries = [q for q in conv.scenario.queries if q.timestamp_s >= bm.t0 + 11.0]
    assert len(queries) == 12
    localizer = fl.Localizer(ref)
    errors = []
    for q, h in zip(queries, headings, strict=True):
        loc = localizer.localize(q.query)
        est = loc.step("compass").estimate
        assert loc.step("compass").status is not StepStatus.SKIPPED and loc.step("correlation").status is not StepStatus.SKIPPED
        if est.reliable:
            errors.append(abs(math.remainder(est.value("theta") - h, 2 * math.pi)))
    assert len(errors) >= 9
    assert np.median(errors) < math.radians(0.1)


# --------------------------------------------------------------------------
# Frames and errors
# --------------------------------------------------------------------------
def _laser_bag(path: Path, tf: bool) -> Path:
    bm = BagMaker(path)
    if tf:
        bm.static_tf({("base_link", "laser"): Rigid3.from_xyz_rpy(0.2, 0.1, 0.3, 0.0, 0.0, math.pi / 2)})
    ranges = np.full(181, 2.0)
    for k in range(5):
        bm.odometry(Pose2(0.5 * k, 0.0, 0.0), float(k))
        bm.scan("/scan", "laser", ranges, -math.pi / 2, math.pi / 180, float(k) + 0.01)
    bm.odometry(Pose2(2.5, 0.0, 0.0), 5.0)
    return bm.close()


def test_the_laser_is_moved_into_the_robot_frame_with_tf_static(tmp_path: Path) -> None:
    conv = convert_bag(_laser_bag(tmp_path / "l.bag", True), ConvertConfig(reference_every_m=10.0, query_every_m=0.4))
    ref = conv.scenario.references[0].reference
    # beam 0 looks right in the laser frame (-90°): turned by +90° it looks forward, 2 m from (0.2, 0.1)
    assert np.allclose(ref.scan.points_m[0], [0.2 + 2.0, 0.1], atol=1e-6)
    assert np.allclose(conv.report.extrinsics["laser"], [0.2, 0.1, 0.3, 0.0, 0.0, math.pi / 2])
    for q in conv.scenario.queries:  # the world frame is the odometry's: 0.5 m/s along x, interpolated at the scan's stamp
        assert q.query.odometry.T_world_robot.x == pytest.approx(0.5 * (q.timestamp_s - 1000.0))
        assert np.allclose(q.query.scan.points_m[0], [2.2, 0.1], atol=1e-6)


def test_a_frame_the_tf_does_not_reach_is_an_error_naming_it_unless_given(tmp_path: Path) -> None:
    bag = _laser_bag(tmp_path / "l.bag", False)
    with pytest.raises(DatasetError, match="'laser'.*--extrinsic"):
        convert_bag(bag)
    given = Rigid3.from_xyz_rpy(0.0, 0.0, 0.0, 0.0, 0.0, math.pi)
    conv = convert_bag(bag, ConvertConfig(sensors=SensorConfig(extrinsics={"laser": given})))
    assert np.allclose(conv.scenario.references[0].reference.scan.points_m[0], [0.0, 2.0], atol=1e-6)


def test_unknown_topics_and_a_bag_without_odometry_are_errors(tmp_path: Path, shared_data: Path) -> None:
    bag = shared_data / "laser" / "mit-csail.sort.bag"
    with pytest.raises(DatasetError, match="no topic '/nope'"):
        convert_bag(bag, ConvertConfig(sensors=SensorConfig(scan_topic="/nope")))
    bm = BagMaker(tmp_path / "no-odom.bag")
    bm.scan("/scan", "laser", np.full(10, 1.0), 0.0, 0.1, 0.0)
    with pytest.raises(DatasetError, match="no nav_msgs/Odometry"):
        convert_bag(bm.close())
    with pytest.raises(DatasetError, match="bag not found"):
        convert_bag(tmp_path / "missing.bag")

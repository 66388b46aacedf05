"""ROS bag reading: the real Intel/ACES ROS 1 bags, and a ROS 2 bag written here with odometry, a scan and a cloud."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from factorloc.datasets.rosbag import (
    laser_ranges_to_scan,
    read_laser_log,
    read_odometry,
    read_point_clouds,
    read_scans,
)
from factorloc.errors import DatasetError
from factorloc.evaluation.relations import read_relations
from factorloc.geometry import Pose2


@pytest.fixture(scope="module")
def laser_dir(shared_data: Path) -> Path:
    return shared_data / "laser"


def test_intel_bag_reads_every_scan_and_odometry_message(laser_dir: Path) -> None:
    log = read_laser_log(laser_dir / "intel.sort.bag")
    assert len(log.scans) == 13631
    assert len(log.odometry) == 26915
    assert log.scans.frame_id == "laser"
    sizes = np.array([len(s) for s in log.scans.scans])
    assert sizes.max() == 180  # 180 beams, the no-return ones dropped
    assert 150 < np.median(sizes) <= 180
    pts = log.scans.scans[1000].points_m
    assert np.all(pts[:, 0] >= -1e-5)  # a 180° front laser sees nothing behind it (float32 angles)
    assert np.hypot(pts[:, 0], pts[:, 1]).max() < 80.0


def test_every_relation_time_matches_a_scan_within_1_ms(laser_dir: Path) -> None:
    log = read_laser_log(laser_dir / "aces.sort.bag")
    rel = read_relations(laser_dir / "aces.relations")
    assert len(rel) == 1279
    for t in np.concatenate([rel.t1_s, rel.t2_s])[::50]:
        i = log.scans.index_at(float(t), 1e-3)
        assert abs(log.scans.stamps_s[i] - t) <= 1e-3


def test_odometry_between_two_times_composes_the_track(laser_dir: Path) -> None:
    odom = read_odometry(laser_dir / "aces.sort.bag")
    t1, t2 = float(odom.stamps_s[100]), float(odom.stamps_s[400])
    rel = odom.between(t1, t2)
    expected = Pose2.from_array(odom.poses[100]).between(Pose2.from_array(odom.poses[400]))
    assert rel.as_array() == pytest.approx(expected.as_array(), abs=1e-12)
    d, r = odom.distance_between(t1, t2)
    assert d >= math.hypot(rel.x, rel.y) - 1e-9
    assert r >= abs(rel.theta) - 1e-9


def test_missing_topic_and_missing_file_raise_dataset_errors(laser_dir: Path, tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="no topic '/points'"):
        read_point_clouds(laser_dir / "aces.sort.bag", "/points")
    with pytest.raises(DatasetError, match="bag not found"):
        read_scans(tmp_path / "nothing.bag")


def test_laser_ranges_drop_no_returns_and_place_beams_counter_clockwise() -> None:
    scan = laser_ranges_to_scan([1.0, np.nan, 0.05, 2.0, 80.0], -math.pi / 2, math.pi / 4, 0.1, 80.0)
    np.testing.assert_allclose(scan.points_m, [[0.0, -1.0], [2 * math.cos(math.pi / 4), 2 * math.sin(math.pi / 4)]], atol=1e-12)


def _write_ros2_bag(path: Path) -> None:
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    Time, Header = T["builtin_interfaces/msg/Time"], T["std_msgs/msg/Header"]
    with Writer(path, version=8) as w:
        c_odom = w.add_connection("/odom", "nav_msgs/msg/Odometry", typestore=ts)
        c_scan = w.add_connection("/scan", "sensor_msgs/msg/LaserScan", typestore=ts)
        c_pc = w.add_connection("/points", "sensor_msgs/msg/PointCloud2", typestore=ts)
        for k in range(3):
            hdr = Header(stamp=Time(sec=100 + k, nanosec=500_000_000), frame_id="base_link")
            yaw = 0.1 * k
            pose = T["geometry_msgs/msg/Pose"](
                position=T["geometry_msgs/msg/Point"](x=float(k), y=0.0, z=0.0),
                orientation=T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2)),
            )
            twist = T["geometry_msgs/msg/Twist"](
                linear=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
                angular=T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0),
            )
            odom = T["nav_msgs/msg/Odometry"](
                header=hdr,
                child_frame_id="base_link",
                pose=T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36)),
                twist=T["geometry_msgs/msg/TwistWithCovariance"](twist=twist, covariance=np.zeros(36)),
            )
            t_ns = (100 + k) * 10**9 + 500_000_000
            w.write(c_odom, t_ns, ts.serialize_cdr(odom, "nav_msgs/msg/Odometry"))
            scan = T["sensor_msgs/msg/LaserScan"](
                header=hdr, angle_min=0.0, angle_max=math.pi / 2, angle_increment=math.pi / 2, time_increment=0.0,
                scan_time=0.0, range_min=0.1, range_max=10.0, ranges=np.array([1.0, 2.0 + k], dtype=np.float32),
                intensities=np.zeros(0, dtype=np.float32),
            )  # fmt: skip
            w.write(c_scan, t_ns, ts.serialize_cdr(scan, "sensor_msgs/msg/LaserScan"))
            xyz = np.array([[1.0, 2.0, 3.0], [np.nan, 0.0, 0.0], [4.0, 5.0, 6.0 + k]], dtype=np.float32)
            fields = [T["sensor_msgs/msg/PointField"](name=n, offset=4 * i, datatype=7, count=1) for i, n in enumerate("xyz")]
            pc = T["sensor_msgs/msg/PointCloud2"](
                header=hdr, height=1, width=3, fields=fields, is_bigendian=False, point_step=12, row_step=36,
                data=np.frombuffer(xyz.tobytes(), dtype=np.uint8), is_dense=False,
            )  # fmt: skip
            w.write(c_pc, t_ns, ts.serialize_cdr(pc, "sensor_msgs/msg/PointCloud2"))


def test_ros2_bag_odometry_scans_and_point_clouds(tmp_path: Path) -> None:
    bag = tmp_path / "bag2"
    _write_ros2_bag(bag)
    log = read_laser_log(bag)
    np.testing.assert_allclose(log.odometry.stamps_s, [100.5, 101.5, 102.5])
    np.testing.assert_allclose(log.odometry.poses[:, 2], [0.0, 0.1, 0.2], atol=1e-12)
    assert log.odometry.pose_at(101.0).x == pytest.approx(0.5)
    np.testing.assert_allclose(log.scans.scans[2].points_m, [[1.0, 0.0], [0.0, 4.0]], atol=1e-6)
    stamps, clouds = read_point_clouds(bag, "/points")
    np.testing.assert_allclose(stamps, [100.5, 101.5, 102.5])
    np.testing.assert_allclose(clouds[1].points_m, [[1, 2, 3], [4, 5, 7]])  # the NaN point is dropped


def test_odometry_track_gaps_brackets_and_path_length() -> None:
    from factorloc.datasets.rosbag import OdometryTrack

    track = OdometryTrack(np.array([0.0, 1.0, 3.0]), np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [1.0, 2.0, 0.0]]))
    assert track.gap_s(1.2) == pytest.approx(0.2) and track.gap_s(-0.5) == pytest.approx(0.5)
    assert track.bracket_s(1.0) == 0.0 and track.bracket_s(2.0) == pytest.approx(2.0) and track.bracket_s(3.5) == math.inf
    assert track.path_length_m(2.0) == pytest.approx(2.0) and np.allclose(track.path_length_m(np.array([0.5, 9.0])), [0.5, 3.0])

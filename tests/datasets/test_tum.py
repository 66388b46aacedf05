"""TUM trajectory files: round trip, planar projection, errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from factorloc.datasets.tum import read_tum_trajectory, write_tum_trajectory
from factorloc.errors import DatasetError


def test_a_written_trajectory_reads_back_and_interpolates(tmp_path: Path) -> None:
    t = np.array([10.0, 11.0, 12.0])
    poses = np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 3.0], [2.0, 1.0, -3.0]])
    track = read_tum_trajectory(write_tum_trajectory(tmp_path / "gt.tum", t, poses))
    assert np.allclose(track.stamps_s, t) and np.allclose(track.poses, poses, atol=1e-9)
    mid = track.pose_at(11.5)  # the heading goes the short way across ±π
    assert mid.x == pytest.approx(1.5) and abs(math.remainder(mid.theta - math.pi, 2 * math.pi)) < 0.15


def test_the_yaw_of_a_tilted_quaternion_and_comments(tmp_path: Path) -> None:
    # yaw 90° composed with a small roll: the planar heading is still 90°
    r, y = math.radians(5.0), math.radians(90.0)
    q = (
        math.sin(r / 2) * math.cos(y / 2),
        math.sin(r / 2) * math.sin(y / 2),
        math.cos(r / 2) * math.sin(y / 2),
        math.cos(r / 2) * math.cos(y / 2),
    )
    p = tmp_path / "gt.txt"
    p.write_text(f"# a comment\n\n1.0 2.0 3.0 0.4 {q[0]} {q[1]} {q[2]} {q[3]}\n")
    track = read_tum_trajectory(p)
    assert track.poses[0].tolist() == pytest.approx([2.0, 3.0, math.pi / 2])


def test_malformed_files_are_errors_naming_the_line(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="not found"):
        read_tum_trajectory(tmp_path / "missing.tum")
    p = tmp_path / "bad.tum"
    p.write_text("1 2 3\n")
    with pytest.raises(DatasetError, match=r"bad.tum:1: a TUM line has 8 numbers"):
        read_tum_trajectory(p)
    p.write_text("1 0 0 0 0 0 0 0\n")
    with pytest.raises(DatasetError, match="zero quaternion"):
        read_tum_trajectory(p)
    p.write_text("# nothing\n")
    with pytest.raises(DatasetError, match="holds no pose"):
        read_tum_trajectory(p)

"""CARMEN log reading: FLASER beam geometry, odometry, timestamps, errors."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from factorloc.datasets.carmen import read_carmen
from factorloc.errors import DatasetError

LOG = """# a CARMEN log
PARAM robot_front_laser_max 80.0
ODOM 0.0 0.0 0.0 0.0 0.0 0.0 10.0 host 10.01
FLASER 5 1.0 2.0 3.0 81.83 1.0 0.0 0.0 0.0 0.0 0.0 0.0 10.5 host 10.51
ODOM 1.0 0.5 0.3 0.1 0.0 0.0 11.0 host 11.01
FLASER 5 2.0 2.0 2.0 2.0 2.0 5.0 5.0 0.3 1.0 0.5 0.3 11.5 host 11.51
"""


def test_flaser_beams_span_180_degrees_and_no_returns_are_dropped(tmp_path: Path) -> None:
    p = tmp_path / "log.clf"
    p.write_text(LOG)
    log = read_carmen(p)
    np.testing.assert_allclose(log.scans.stamps_s, [10.5, 11.5])
    first = log.scans.scans[0].points_m
    assert len(first) == 4  # 81.83 m is the "no return" reading
    # beams at -90°, -45°, 0°, (+45° dropped), +90°
    np.testing.assert_allclose(
        first, [[0.0, -1.0], [2 * math.cos(math.pi / 4), -2 * math.sin(math.pi / 4)], [3.0, 0.0], [0.0, 1.0]], atol=1e-12
    )
    np.testing.assert_allclose(log.odometry.poses, [[0, 0, 0], [1.0, 0.5, 0.3]])
    assert log.odometry.between(10.0, 11.0).x == pytest.approx(math.hypot(1.0, 0.5) * math.cos(math.atan2(0.5, 1.0)))


def test_logger_timestamps_on_request_and_laser_odometry_without_odom_lines(tmp_path: Path) -> None:
    p = tmp_path / "log.clf"
    p.write_text("\n".join(line for line in LOG.splitlines() if not line.startswith("ODOM")))
    log = read_carmen(p, use_logger_time=True)
    np.testing.assert_allclose(log.scans.stamps_s, [10.51, 11.51])
    np.testing.assert_allclose(log.odometry.poses, [[0, 0, 0], [1.0, 0.5, 0.3]])


def test_malformed_lines_and_empty_logs_raise_with_the_line_number(tmp_path: Path) -> None:
    p = tmp_path / "bad.clf"
    p.write_text("FLASER 5 1.0 2.0\n")
    with pytest.raises(DatasetError, match=r"bad.clf:1: malformed FLASER"):
        read_carmen(p)
    p.write_text("ODOM 0 0 0 0 0 0 1.0 host 1.0\n")
    with pytest.raises(DatasetError, match="no FLASER"):
        read_carmen(p)
    with pytest.raises(DatasetError, match="not found"):
        read_carmen(tmp_path / "missing.clf")

"""Read CARMEN log files (the text format of the classic 2D laser datasets).

Understood lines (fields separated by white space; ``#`` comments, ``PARAM``
and other messages are skipped)::

    ODOM x y theta tv rv accel ipc_timestamp ipc_hostname logger_timestamp
    FLASER n r_1 … r_n x y theta odom_x odom_y odom_theta ipc_timestamp ipc_hostname logger_timestamp
    ROBOTLASER1 type start_angle fov resolution max_range accuracy remission_mode n r_1 … r_n
                m e_1 … e_m laser_x laser_y laser_theta robot_x robot_y robot_theta
                tv rv forward_safety side_safety turn_axis ipc_timestamp ipc_hostname logger_timestamp

``FLASER`` beams span ``fov_rad`` (default 180°) from ``−fov/2`` to
``+fov/2`` in ``n − 1`` equal steps (the convention of the Freiburg logs and
their ROS conversions); ``ROBOTLASER1`` carries its own start angle and
resolution. Readings at or beyond ``max_range_m`` are "no return" and are
dropped. The laser is assumed at the robot origin (as in the Intel and ACES
logs); pass ``T_robot_laser`` otherwise. Odometry comes from the ``ODOM``
lines, or from the odometry fields of the laser lines when there are none.
Times are the IPC timestamps (those of the published relations).
"""

from __future__ import annotations

import logging
import math
from pathlib import Path

import numpy as np

from factorloc.datasets.rosbag import LaserLog, OdometryTrack, ScanTrack, laser_ranges_to_scan
from factorloc.errors import DatasetError
from factorloc.geometry import Pose2

_log = logging.getLogger(__name__)

__all__ = ["read_carmen"]


def read_carmen(
    path: str | Path,
    *,
    fov_rad: float = math.pi,
    max_range_m: float = 80.0,
    min_range_m: float = 0.0,
    T_robot_laser: Pose2 | None = None,
    use_logger_time: bool = False,
) -> LaserLog:
    """Read the odometry and the front-laser scans of a CARMEN log.

    Raises
    ------
    DatasetError
        When the file is missing, a laser or odometry line is malformed
        (the message names the line number), or the log holds no scan.
    """
    p = Path(path)
    if not p.is_file():
        raise DatasetError(f"CARMEN log not found: {p}")
    scan_t: list[float] = []
    scans = []
    odom_t: list[float] = []
    odom_p: list[tuple[float, float, float]] = []
    laser_odom_t: list[float] = []
    laser_odom_p: list[tuple[float, float, float]] = []
    with p.open("r", encoding="utf-8", errors="replace") as fh:
        for lineno, line in enumerate(fh, start=1):
            parts = line.split()
            if not parts or parts[0].startswith("#"):
                continue
            kind = parts[0]
            try:
                if kind == "ODOM":
                    x, y, th = (float(v) for v in parts[1:4])
                    t = float(parts[9] if use_logger_time else parts[7])
                    odom_t.append(t)
                    odom_p.append((x, y, th))
                elif kind == "FLASER":
                    n = int(parts[1])
                    ranges = np.array(parts[2 : 2 + n], dtype=np.float64)
                    rest = parts[2 + n :]
                    if len(ranges) != n or len(rest) < 9:
                        raise ValueError(f"expected {n} readings and 9 trailing fields")
                    t = float(rest[8] if use_logger_time else rest[6])
                    step = fov_rad / (n - 1) if n > 1 else 0.0
                    scans.append(
                        laser_ranges_to_scan(ranges, -0.5 * fov_rad, step, min_range_m, max_range_m, T_robot_laser=T_robot_laser)
                    )
                    scan_t.append(t)
                    laser_odom_t.append(t)
                    laser_odom_p.append((float(rest[3]), float(rest[4]), float(rest[5])))
                elif kind == "ROBOTLASER1":
                    start, _fov, res, rmax = (float(v) for v in parts[2:6])
                    n = int(parts[8])
                    ranges = np.array(parts[9 : 9 + n], dtype=np.float64)
                    m = int(parts[9 + n])
                    rest = parts[10 + n + m :]
                    if len(ranges) != n or len(rest) < 14:
                        raise ValueError(f"expected {n} readings, {m} remissions and 14 trailing fields")
                    t = float(rest[13] if use_logger_time else rest[11])
                    scans.append(
                        laser_ranges_to_scan(ranges, start, res, min_range_m, min(max_range_m, rmax), T_robot_laser=T_robot_laser)
                    )
                    scan_t.append(t)
                    laser_odom_t.append(t)
                    laser_odom_p.append((float(rest[3]), float(rest[4]), float(rest[5])))
            except (ValueError, IndexError) as exc:
                raise DatasetError(f"{p}:{lineno}: malformed {kind} line: {exc}") from exc
    if not scans:
        raise DatasetError(f"CARMEN log {p} holds no FLASER or ROBOTLASER1 line")
    if odom_t:
        odometry = OdometryTrack(np.array(odom_t), np.array(odom_p))
    else:
        odometry = OdometryTrack(np.array(laser_odom_t), np.array(laser_odom_p))
    _log.info("read %d scans and %d odometry poses from %s", len(scans), len(odometry), p)
    return LaserLog(odometry, ScanTrack(np.array(scan_t), tuple(scans), "laser"), str(p))

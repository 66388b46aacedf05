"""TUM trajectory files (``timestamp tx ty tz qx qy qz qw`` per line), the format ``evo`` reads.

A ground-truth trajectory (motion capture, a SLAM solution) becomes an
:class:`~factorloc.datasets.rosbag.OdometryTrack` of planar poses
``T_world_robot`` (x, y and the yaw of the quaternion; z, roll and pitch are
dropped), interpolated at any time within its span. Lines starting with ``#``
are comments (Sturm et al., "A benchmark for the evaluation of RGB-D SLAM
systems", IROS 2012; https://cvg.cit.tum.de/data/datasets/rgbd-dataset/file_formats).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from factorloc.datasets.rosbag import OdometryTrack
from factorloc.errors import DatasetError, InputError

__all__ = ["read_tum_trajectory", "write_tum_trajectory"]


def read_tum_trajectory(path: str | Path) -> OdometryTrack:
    """Read a TUM trajectory as planar poses (the yaw of each quaternion).

    Raises
    ------
    DatasetError
        When the file is missing, has no pose line, a line without 8 numbers, or a zero quaternion.
    """
    p = Path(path)
    if not p.is_file():
        raise DatasetError(f"TUM trajectory not found: {p}")
    rows = []
    for n, line in enumerate(p.read_text(encoding="utf-8").splitlines(), start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        parts = text.replace(",", " ").split()
        try:
            values = [float(v) for v in parts]
        except ValueError as exc:
            raise DatasetError(f"{p}:{n}: not a number in {text!r}") from exc
        if len(values) != 8:
            raise DatasetError(f"{p}:{n}: a TUM line has 8 numbers (t tx ty tz qx qy qz qw), got {len(values)}")
        t, x, y, _, qx, qy, qz, qw = values
        if qx * qx + qy * qy + qz * qz + qw * qw < 1e-12:
            raise DatasetError(f"{p}:{n}: zero quaternion")
        yaw = math.atan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz))
        rows.append((t, x, y, yaw))
    if not rows:
        raise DatasetError(f"TUM trajectory {p} holds no pose")
    a = np.array(rows)
    try:
        return OdometryTrack(a[:, 0], a[:, 1:])
    except InputError as exc:
        raise DatasetError(f"TUM trajectory {p}: {exc}") from exc


def write_tum_trajectory(path: str | Path, stamps_s: np.ndarray, poses: np.ndarray) -> Path:
    """Write (N,) times (s) and (N, 3) planar poses ``[x_m, y_m, theta_rad]`` as a TUM file (z = 0)."""
    t = np.asarray(stamps_s, dtype=np.float64).reshape(-1)
    p = np.asarray(poses, dtype=np.float64)
    if p.shape != (t.shape[0], 3) or not (np.all(np.isfinite(t)) and np.all(np.isfinite(p))):
        raise InputError(f"write_tum_trajectory needs N stamps and N×3 finite poses, got {t.shape} and {p.shape}")
    lines = ["# timestamp tx ty tz qx qy qz qw"]
    for ti, (x, y, th) in zip(t, p, strict=True):
        lines.append(f"{ti:.9f} {x:.9f} {y:.9f} 0 0 0 {math.sin(th / 2):.12f} {math.cos(th / 2):.12f}")
    out = Path(path)
    out.write_text("\n".join(lines) + "\n", encoding="utf-8")
    return out

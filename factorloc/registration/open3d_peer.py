"""Open3D's ICP on 2D scans, the peer our point-to-line ICP is compared with.

The 2D points are lifted to the plane z = 0. Open3D's own normal estimation
is meaningless on a planar cloud (it returns ±z), so point-to-plane uses the
same 2D PCA line normals as our ICP, lifted as ``(n_x, n_y, 0)``; Open3D then
solves its 6-DoF problem, whose z, roll and pitch stay at the seed's (zero)
values. The result is projected back to SE(2).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from factorloc.errors import InputError
from factorloc.geometry import Pose2

__all__ = ["Open3dResult", "open3d_cloud", "open3d_icp", "pose_from_matrix", "pose_matrix"]


@dataclass(frozen=True)
class Open3dResult:
    """Open3D's answer projected to SE(2): the source pose in the target frame, fitness and inlier RMSE."""

    T_target_source: Pose2
    fitness: float
    rmse_m: float


def pose_matrix(p: Pose2) -> np.ndarray:
    """The 4×4 homogeneous matrix of a planar pose (z = 0), as Open3D takes a transformation."""
    T = np.eye(4)
    c, s = math.cos(p.theta), math.sin(p.theta)
    T[:2, :2] = [[c, -s], [s, c]]
    T[0, 3], T[1, 3] = p.x, p.y
    return T


def pose_from_matrix(T: np.ndarray) -> Pose2:
    """The planar pose of a 4×4 transformation (its x, y and the yaw of its rotation; z, roll, pitch dropped)."""
    T = np.asarray(T)
    return Pose2(float(T[0, 3]), float(T[1, 3]), math.atan2(T[1, 0], T[0, 0]))


def open3d_cloud(points_m: np.ndarray, normals: np.ndarray | None = None):  # noqa: ANN201 - open3d object
    """An ``open3d.geometry.PointCloud`` of N×2 points lifted to z = 0 (and N×2 normals lifted to (n_x, n_y, 0))."""
    import open3d as o3d

    pts = np.asarray(points_m, dtype=np.float64)
    c = o3d.geometry.PointCloud()
    c.points = o3d.utility.Vector3dVector(np.column_stack([pts, np.zeros(len(pts))]))
    if normals is not None:
        c.normals = o3d.utility.Vector3dVector(np.column_stack([normals, np.zeros(len(normals))]))
    return c


def open3d_icp(
    target_points_m: np.ndarray,
    source_points_m: np.ndarray,
    T_init: Pose2,
    *,
    method: str = "point_to_plane",
    target_normals: np.ndarray | None = None,
    max_correspondence_m: float = 0.5,
    max_iterations: int = 50,
) -> Open3dResult:
    """Run ``open3d.pipelines.registration.registration_icp`` on 2D scans.

    Parameters
    ----------
    target_points_m, source_points_m
        M×2 and N×2 points (metres) of the target (reference) and source (query).
    T_init
        The seed: source pose in the target frame.
    method
        ``"point_to_point"`` or ``"point_to_plane"`` (needs ``target_normals``, M×2).
    """
    import open3d as o3d

    reg = o3d.pipelines.registration
    if method == "point_to_point":
        est = reg.TransformationEstimationPointToPoint()
        tgt = open3d_cloud(target_points_m)
    elif method == "point_to_plane":
        if target_normals is None:
            raise InputError("open3d_icp(method='point_to_plane') needs target_normals (M×2)")
        est = reg.TransformationEstimationPointToPlane()
        tgt = open3d_cloud(target_points_m, target_normals)
    else:
        raise InputError(f"method must be 'point_to_point' or 'point_to_plane', got {method!r}")
    src = open3d_cloud(source_points_m)
    res = reg.registration_icp(
        src, tgt, max_correspondence_m, pose_matrix(T_init), est, reg.ICPConvergenceCriteria(max_iteration=max_iterations)
    )
    return Open3dResult(pose_from_matrix(res.transformation), float(res.fitness), float(res.inlier_rmse))

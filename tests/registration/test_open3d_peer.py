"""The Open3D peer's conversions between planar data and Open3D's 3D objects."""

from __future__ import annotations

import math

import numpy as np

from factorloc.geometry import Pose2
from factorloc.registration.open3d_peer import open3d_cloud, pose_from_matrix, pose_matrix


def test_a_planar_pose_survives_the_round_trip_through_a_4x4_matrix() -> None:
    p = Pose2(1.5, -0.25, math.radians(-170.0))
    T = pose_matrix(p)
    assert T.shape == (4, 4) and T[2, 3] == 0.0 and T[2, 2] == 1.0
    np.testing.assert_allclose(T[:2, :2] @ [1.0, 0.0], [math.cos(p.theta), math.sin(p.theta)])
    q = pose_from_matrix(T)
    assert (q.x, q.y) == (1.5, -0.25) and math.isclose(q.theta, p.theta, abs_tol=1e-12)


def test_a_cloud_is_lifted_to_the_plane_z_0_with_horizontal_normals() -> None:
    pts = np.array([[0.0, 1.0], [2.0, 3.0]])
    normals = np.array([[1.0, 0.0], [0.0, -1.0]])
    c = open3d_cloud(pts, normals)
    np.testing.assert_array_equal(np.asarray(c.points), [[0.0, 1.0, 0.0], [2.0, 3.0, 0.0]])
    np.testing.assert_array_equal(np.asarray(c.normals), [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0]])
    assert not open3d_cloud(pts).has_normals()

"""Rigid transforms, the TF tree, and camera messages → CameraImage (encodings, intrinsics, optical frames)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import cv2
import numpy as np
import pytest
from bagmaker import OPTICAL
from hypothesis import given, settings
from hypothesis import strategies as st

from factorloc.datasets.bag import CameraIntrinsics, Rigid3, TransformTree, camera_image, compressed_image_to_bgr, image_to_bgr
from factorloc.errors import DatasetError, InputError
from factorloc.geometry import Pose2

angles = st.floats(-3.1, 3.1)


@settings(max_examples=60, deadline=None)
@given(angles, st.floats(-1.5, 1.5), angles, st.floats(-5, 5), st.floats(-5, 5), st.floats(-5, 5))
def test_rpy_and_quaternion_round_trip(roll, pitch, yaw, x, y, z) -> None:
    T = Rigid3.from_xyz_rpy(x, y, z, roll, pitch, yaw)
    assert np.allclose(T.rpy, (roll, pitch, yaw), atol=1e-9)
    again = Rigid3.from_quaternion(T.t, T.quaternion)
    assert np.allclose(again.R, T.R, atol=1e-12) and np.allclose((T * T.inverse()).R, np.eye(3), atol=1e-12)


def test_planar_transforms_agree_with_pose2() -> None:
    a, b = Pose2(1.0, -2.0, 0.7), Pose2(-0.3, 0.5, -2.0)
    ab = (Rigid3.from_pose2(a) * Rigid3.from_pose2(b)).to_pose2()
    assert np.allclose(ab.as_array(), (a * b).as_array())
    pts = np.array([[1.0, 2.0, 0.5], [-3.0, 0.1, 0.0]])
    assert np.allclose(Rigid3.from_pose2(a).apply(pts)[:, :2], a.transform_points(pts[:, :2]))


def test_not_a_rotation_is_refused() -> None:
    with pytest.raises(InputError, match="rotation"):
        Rigid3(np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(InputError, match="no direction"):
        Rigid3.from_quaternion((0, 0, 0), (0, 0, 0, 0))


def test_the_tree_chains_inverts_and_interpolates_a_moving_joint() -> None:
    tree = TransformTree()
    tree.add("base_link", "mast", Rigid3.from_xyz_rpy(0.1, 0.0, 1.0, 0, 0, 0))
    tree.add("mast", "laser", Rigid3.from_xyz_rpy(0.0, 0.2, 0.0, 0, 0, math.pi / 2))
    for t, yaw in ((10.0, 0.0), (11.0, math.pi / 2)):  # a pan head turning at 90°/s
        tree.add("mast", "head", Rigid3.from_xyz_rpy(0, 0, 0.3, 0, 0, yaw), t)
    for t in (10.0, 20.0):  # /tf that never moves becomes static
        tree.add("base_link", "imu", Rigid3.from_xyz_rpy(0, 0, 0.2, 0, 0, 0), t)
    tree.freeze()
    T = tree.lookup("base_link", "laser")
    assert np.allclose(T.t, [0.1, 0.2, 1.0]) and T.rpy[2] == pytest.approx(math.pi / 2)
    assert np.allclose(tree.lookup("laser", "base_link").R, T.inverse().R)
    assert tree.is_static("base_link", "imu") and not tree.depends_on_time("base_link", "imu")
    assert tree.depends_on_time("base_link", "head")
    assert tree.lookup("base_link", "head", 10.5).rpy[2] == pytest.approx(math.pi / 4)
    with pytest.raises(DatasetError, match="moves during the bag"):
        tree.lookup("base_link", "head")
    with pytest.raises(DatasetError, match="no transform within"):
        tree.lookup("base_link", "head", 30.0)
    with pytest.raises(DatasetError, match="no chain of transforms .*'camera'"):
        tree.lookup("base_link", "camera")


# --------------------------------------------------------------------------
# Images
# --------------------------------------------------------------------------
def _img(rng: np.random.Generator) -> np.ndarray:
    return rng.integers(0, 256, (12, 10, 3), dtype=np.uint8)


def _msg(data: np.ndarray, encoding: str, step: int | None = None, big: bool = False) -> SimpleNamespace:
    h, w = data.shape[:2]
    raw = data.reshape(h, -1).view(np.uint8) if data.dtype != np.uint8 else data.reshape(h, -1)
    s = raw.shape[1] if step is None else step
    padded = np.zeros((h, s), np.uint8)
    padded[:, : raw.shape[1]] = raw
    return SimpleNamespace(encoding=encoding, height=h, width=w, step=s, is_bigendian=big, data=padded.reshape(-1))


def test_image_encodings_become_bgr() -> None:
    bgr = _img(np.random.default_rng(0))
    assert np.array_equal(image_to_bgr(_msg(bgr, "bgr8", step=40)), bgr)  # rows padded to the step
    assert np.array_equal(image_to_bgr(_msg(bgr[:, :, ::-1].copy(), "rgb8")), bgr)
    rgba = np.dstack([bgr[:, :, ::-1], np.full(bgr.shape[:2], 255, np.uint8)])
    assert np.array_equal(image_to_bgr(_msg(rgba, "rgba8")), bgr)
    grey = bgr[:, :, 0].copy()
    assert np.array_equal(image_to_bgr(_msg(grey, "mono8")), np.dstack([grey] * 3))
    wide = (bgr.astype(np.uint16) << 8) | 0x7F
    assert np.array_equal(image_to_bgr(_msg(wide.astype("<u2"), "bgr16")), bgr)
    assert np.array_equal(image_to_bgr(_msg(wide.astype(">u2"), "bgr16", big=True)), bgr)
    with pytest.raises(DatasetError, match="not a colour image"):
        image_to_bgr(_msg(np.zeros((4, 4), np.float32), "32FC1"))
    with pytest.raises(DatasetError, match="malformed"):
        image_to_bgr(SimpleNamespace(encoding="bgr8", height=4, width=4, step=12, is_bigendian=0, data=np.zeros(10, np.uint8)))


def test_compressed_images_decode_to_bgr() -> None:
    bgr = np.random.default_rng(1).integers(0, 256, (16, 16, 3), dtype=np.uint8)
    png = cv2.imencode(".png", bgr)[1].reshape(-1)
    assert np.array_equal(compressed_image_to_bgr(SimpleNamespace(format="png", data=png)), bgr)
    swapped = cv2.imencode(".png", np.ascontiguousarray(bgr[:, :, ::-1]))[1].reshape(-1)
    assert np.array_equal(compressed_image_to_bgr(SimpleNamespace(format="rgb8; png compressed rgb8", data=swapped)), bgr)
    with pytest.raises(DatasetError, match="depth"):
        compressed_image_to_bgr(SimpleNamespace(format="16UC1; compressedDepth", data=png))
    with pytest.raises(DatasetError, match="could not be decoded"):
        compressed_image_to_bgr(SimpleNamespace(format="jpeg", data=np.zeros(20, np.uint8)))


def _info(K: np.ndarray, D=(0.0,) * 5, w: int = 160, h: int = 120) -> SimpleNamespace:
    return SimpleNamespace(
        width=w, height=h, K=K.reshape(9), D=np.asarray(D), distortion_model="plumb_bob", binning_x=0, binning_y=0
    )


def test_intrinsics_give_the_field_of_view_and_rectify_a_distorted_camera() -> None:
    f = 100.0
    K = np.array([[f, 0, 79.5], [0, f, 59.5], [0, 0, 1.0]])
    intr = CameraIntrinsics.from_camera_info(_info(K))
    assert intr.is_ideal and intr.hfov_rad == pytest.approx(2 * math.atan(80 / f)) and intr.principal_x_px() is None
    # a distorted, off-centre camera: distort an ideal image, then rectify it back
    ideal = cv2.GaussianBlur(np.random.default_rng(2).integers(0, 256, (120, 160, 3), dtype=np.uint8), (0, 0), 2.0)
    Kd = np.array([[f, 0, 83.0], [0, 1.02 * f, 57.0], [0, 0, 1.0]])
    D = (-0.2, 0.05, 0.0, 0.0, 0.0)
    distorted_intr = CameraIntrinsics.from_camera_info(_info(Kd, D))
    assert not distorted_intr.is_ideal
    # where does each distorted pixel look? undistortPoints → the ideal camera (focal fx, centred) → sample the ideal image
    uu, vv = np.meshgrid(np.arange(160, dtype=np.float32), np.arange(120, dtype=np.float32))
    rays = cv2.undistortPoints(np.stack([uu.ravel(), vv.ravel()], 1)[:, None], Kd, np.array(D)).reshape(-1, 2)
    mx = (rays[:, 0] * f + 79.5).reshape(120, 160).astype(np.float32)
    my = (rays[:, 1] * f + 59.5).reshape(120, 160).astype(np.float32)
    distorted = cv2.remap(ideal, mx, my, cv2.INTER_LINEAR)
    back = distorted_intr.rectify(distorted)
    inner = (slice(20, 100), slice(25, 135))
    assert np.abs(back[inner].astype(float) - ideal[inner].astype(float)).mean() < 3.0
    with pytest.raises(DatasetError, match="CameraInfo says 160×120"):
        distorted_intr.rectify(np.zeros((10, 10, 3), np.uint8))
    with pytest.raises(DatasetError, match="not supported"):
        CameraIntrinsics.from_camera_info(
            SimpleNamespace(**{**vars(_info(K, (0.1, 0, 0, 0))), "distortion_model": "equidistant"})
        )


def test_the_optical_frame_gives_the_yaw_and_pitch_and_a_rolled_camera_is_refused() -> None:
    intr = CameraIntrinsics.from_hfov(160, 120, math.radians(60.0))
    img = np.zeros((120, 160, 3), np.uint8)
    T = (
        Rigid3.from_xyz_rpy(0.1, 0.0, 1.0, 0.0, math.radians(-10.0), math.radians(30.0)) * OPTICAL
    )  # 30° left, 10° up (ROS pitch is positive nose-down)
    cam = camera_image(img, intr, T)
    assert cam.yaw_in_robot_rad == pytest.approx(math.radians(30.0)) and cam.pitch_rad == pytest.approx(math.radians(10.0))
    assert cam.hfov_rad == pytest.approx(math.radians(60.0))
    rolled = T * Rigid3.from_xyz_rpy(0, 0, 0, 0, 0, math.radians(20.0))  # about the optical z axis
    with pytest.raises(DatasetError, match="rolled by 20.0°"):
        camera_image(img, intr, rolled, "cam")

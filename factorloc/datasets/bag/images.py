"""Camera messages of a bag → :class:`~factorloc.CameraImage` (BGR uint8) in the robot frame.

* ``sensor_msgs/Image`` (``bgr8``, ``rgb8``, ``bgra8``, ``rgba8``, ``mono8``, their 16-bit
  forms, ``bayer_*8``) and ``sensor_msgs/CompressedImage`` (JPEG, PNG) become BGR uint8
  arrays (:func:`image_to_bgr`, :func:`compressed_image_to_bgr`). Depth encodings
  (``16UC1``, ``32FC1``, ``compressedDepth``) are refused: they are not colour views.
* ``sensor_msgs/CameraInfo`` gives the intrinsics (:class:`CameraIntrinsics`). factorloc's
  pinhole model has square pixels, the principal point's row at the image centre and no
  distortion; an image that differs (plumb-bob or rational-polynomial distortion, fx ≠ fy,
  an off-centre principal point) is first resampled onto that ideal camera with the same
  focal length fx (:meth:`CameraIntrinsics.rectify`).
* The camera's pose in the robot frame comes from the optical frame of the header
  (REP-103 optical convention: z forward, x right, y down): its yaw and pitch become
  ``CameraImage.yaw_in_robot_rad`` and ``pitch_rad`` (:func:`camera_image`). A rolled
  camera is refused, since the model has no roll.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import cv2
import numpy as np

from factorloc.datasets.bag.frames import Rigid3
from factorloc.errors import DatasetError
from factorloc.types import CameraImage

__all__ = [
    "CameraIntrinsics",
    "MAX_CAMERA_ROLL_RAD",
    "camera_image",
    "compressed_image_to_bgr",
    "image_to_bgr",
    "is_colour_encoding",
]

#: Largest camera roll (rad) accepted when the optical frame is mapped to a yaw and a pitch.
MAX_CAMERA_ROLL_RAD = math.radians(3.0)

_BAYER = {
    "bayer_rggb8": cv2.COLOR_BayerRG2BGR,
    "bayer_bggr8": cv2.COLOR_BayerBG2BGR,
    "bayer_gbrg8": cv2.COLOR_BayerGB2BGR,
    "bayer_grbg8": cv2.COLOR_BayerGR2BGR,
}
_CHANNELS = {"bgr8": 3, "rgb8": 3, "bgra8": 4, "rgba8": 4, "mono8": 1, "8uc1": 1, "8uc3": 3, "8uc4": 4}
_CHANNELS16 = {"bgr16": 3, "rgb16": 3, "bgra16": 4, "rgba16": 4, "mono16": 1}


def is_colour_encoding(encoding: str) -> bool:
    """Whether :func:`image_to_bgr` reads this ``sensor_msgs/Image`` encoding (depth encodings are not)."""
    e = str(encoding).lower()
    return e in _CHANNELS or e in _CHANNELS16 or e in _BAYER


def image_to_bgr(msg: Any) -> np.ndarray:
    """A deserialized ``sensor_msgs/Image`` as an H×W×3 BGR uint8 array (rows padded to ``step`` are cut).

    Raises
    ------
    DatasetError
        For an unknown or depth encoding, or data shorter than ``height·step``.
    """
    enc = str(msg.encoding).lower()
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8)
    if enc in _CHANNELS16:
        depth, ch = 2, _CHANNELS16[enc]
    elif enc in _CHANNELS:
        depth, ch = 1, _CHANNELS[enc]
    elif enc in _BAYER:
        depth, ch = 1, 1
    else:
        raise DatasetError(f"sensor_msgs/Image encoding {msg.encoding!r} is not a colour image (known: bgr8, rgb8, mono8, …)")
    if h < 1 or w < 1 or step < w * ch * depth or data.size < h * step:
        raise DatasetError(f"sensor_msgs/Image of {w}×{h} px, step {step}, holds {data.size} bytes: malformed")
    rows = data[: h * step].reshape(h, step)[:, : w * ch * depth]
    if depth == 2:
        big = bool(msg.is_bigendian)
        px = rows.reshape(h, w * ch, 2)
        hi = px[:, :, 0] if big else px[:, :, 1]  # keep the most significant byte
        img = np.ascontiguousarray(hi).reshape(h, w, ch)
    else:
        img = np.ascontiguousarray(rows).reshape(h, w, ch)
    if enc in _BAYER:
        return cv2.cvtColor(img[:, :, 0], _BAYER[enc])
    if ch == 1:
        return cv2.cvtColor(img[:, :, 0], cv2.COLOR_GRAY2BGR)
    if enc.startswith("rgb"):
        return np.ascontiguousarray(img[:, :, 2::-1]) if ch == 3 else cv2.cvtColor(img, cv2.COLOR_RGBA2BGR)
    return img if ch == 3 else cv2.cvtColor(img, cv2.COLOR_BGRA2BGR)


def compressed_image_to_bgr(msg: Any) -> np.ndarray:
    """A deserialized ``sensor_msgs/CompressedImage`` (JPEG or PNG) as an H×W×3 BGR uint8 array.

    image_transport writes ``format`` as ``"<encoding>; jpeg compressed bgr8"``: the data
    are then BGR-ordered, which is what OpenCV decodes to. ``"rgb8; jpeg compressed rgb8"``
    (some drivers) is swapped back to BGR.
    """
    fmt = str(msg.format).lower()
    if "compresseddepth" in fmt:
        raise DatasetError(f"CompressedImage format {msg.format!r} is a depth image, not a colour view")
    buf = np.asarray(msg.data, dtype=np.uint8)
    img = cv2.imdecode(buf, cv2.IMREAD_COLOR)
    if img is None:
        raise DatasetError(f"CompressedImage ({msg.format!r}, {buf.size} bytes) could not be decoded")
    if "compressed rgb" in fmt:
        img = np.ascontiguousarray(img[:, :, ::-1])
    return img


@dataclass(frozen=True)
class CameraIntrinsics:
    """A camera's pinhole intrinsics (pixels) and distortion, as ``sensor_msgs/CameraInfo`` holds them.

    ``distortion`` are the coefficients of ``distortion_model`` (``"plumb_bob"`` k1 k2 p1 p2 k3,
    or ``"rational_polynomial"`` with 8), in OpenCV's order.
    """

    width_px: int
    height_px: int
    fx_px: float
    fy_px: float
    cx_px: float
    cy_px: float
    distortion: tuple[float, ...] = ()
    distortion_model: str = "plumb_bob"

    @classmethod
    def from_camera_info(cls, msg: Any) -> CameraIntrinsics:
        """From a deserialized ``sensor_msgs/CameraInfo`` (ROS 1 ``K``/``D`` or ROS 2 ``k``/``d``)."""
        K = np.asarray(getattr(msg, "k", None) if hasattr(msg, "k") else msg.K, dtype=np.float64).reshape(-1)
        D = np.asarray(getattr(msg, "d", None) if hasattr(msg, "d") else msg.D, dtype=np.float64).reshape(-1)
        if K.size != 9 or not np.all(np.isfinite(K)) or K[0] <= 0 or K[4] <= 0:
            raise DatasetError(f"CameraInfo has no valid camera matrix K: {K.tolist()}")
        model = str(msg.distortion_model or "plumb_bob")
        if np.any(D != 0) and model not in ("plumb_bob", "rational_polynomial"):
            raise DatasetError(f"CameraInfo distortion model {model!r} is not supported (plumb_bob, rational_polynomial)")
        binning = max(int(getattr(msg, "binning_x", 0) or 0), int(getattr(msg, "binning_y", 0) or 0))
        if binning > 1:
            raise DatasetError(f"CameraInfo uses binning {binning}: not supported, give the intrinsics of the binned image")
        return cls(int(msg.width), int(msg.height), K[0], K[4], K[2], K[5], tuple(float(d) for d in D), model)

    @classmethod
    def from_hfov(cls, width_px: int, height_px: int, hfov_rad: float) -> CameraIntrinsics:
        """An ideal camera of horizontal field of view ``hfov_rad`` (no CameraInfo in the bag)."""
        f = 0.5 * width_px / math.tan(0.5 * hfov_rad)
        return cls(width_px, height_px, f, f, (width_px - 1) / 2.0, (height_px - 1) / 2.0)

    @property
    def hfov_rad(self) -> float:
        """Horizontal field of view of the ideal camera of focal ``fx``: ``2·atan(W / 2fx)``."""
        return 2.0 * math.atan(0.5 * self.width_px / self.fx_px)

    @property
    def is_ideal(self) -> bool:
        """No distortion, square pixels, principal row at the centre (what :class:`CameraImage` models)."""
        return (
            not any(self.distortion)
            and abs(self.fx_px - self.fy_px) <= 1e-6 * self.fx_px
            and abs(self.cy_px - (self.height_px - 1) / 2.0) <= 0.5
        )

    @cached_property
    def _maps(self) -> tuple[np.ndarray, np.ndarray]:
        K = np.array([[self.fx_px, 0, self.cx_px], [0, self.fy_px, self.cy_px], [0, 0, 1]], dtype=np.float64)
        f = self.fx_px
        K_new = np.array([[f, 0, (self.width_px - 1) / 2.0], [0, f, (self.height_px - 1) / 2.0], [0, 0, 1]])
        D = np.asarray(self.distortion or (0.0,) * 5, dtype=np.float64)
        return cv2.initUndistortRectifyMap(K, D, None, K_new, (self.width_px, self.height_px), cv2.CV_32FC1)

    def rectify(self, image_bgr: np.ndarray) -> np.ndarray:
        """Resample an image of this camera onto the ideal camera (focal fx, centred, no distortion)."""
        h, w = image_bgr.shape[:2]
        if (w, h) != (self.width_px, self.height_px):
            raise DatasetError(f"image is {w}×{h} px, its CameraInfo says {self.width_px}×{self.height_px}")
        if self.is_ideal:
            return image_bgr
        mx, my = self._maps
        return cv2.remap(image_bgr, mx, my, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)

    def principal_x_px(self) -> float | None:
        """``cx`` of the (possibly rectified) image, None when it is the centre."""
        if not self.is_ideal:
            return None
        cx = self.cx_px
        return None if abs(cx - (self.width_px - 1) / 2.0) <= 1e-9 else float(cx)


def camera_image(image_bgr: np.ndarray, intrinsics: CameraIntrinsics, T_robot_optical: Rigid3, frame: str = "") -> CameraImage:
    """A :class:`~factorloc.CameraImage` in the robot frame from an image, its intrinsics and its optical frame's pose.

    The optical axis (the optical frame's z) gives ``yaw_in_robot_rad`` (azimuth, CCW from the
    robot's x) and ``pitch_rad`` (elevation, up positive). The camera's offset from the robot's
    vertical axis is not modelled (parallax of a few centimetres).

    Raises
    ------
    DatasetError
        When the camera is rolled by more than :data:`MAX_CAMERA_ROLL_RAD` about its optical axis.
    """
    R = T_robot_optical.R
    z = R[:, 2]  # optical axis in the robot frame
    yaw = math.atan2(z[1], z[0])
    pitch = math.atan2(z[2], math.hypot(z[0], z[1]))
    # image right (optical x) of an unrolled camera with this yaw and pitch is horizontal: (sin yaw, −cos yaw, 0)
    right = np.array([math.sin(yaw), -math.cos(yaw), 0.0])
    down = np.cross(z, right)
    roll = math.atan2(float(np.dot(R[:, 0], down)), float(np.dot(R[:, 0], right)))
    if abs(roll) > MAX_CAMERA_ROLL_RAD:
        raise DatasetError(
            f"camera frame {frame!r} is rolled by {math.degrees(roll):.1f}° about its optical axis "
            f"(at most {math.degrees(MAX_CAMERA_ROLL_RAD):.0f}°): factorloc's camera model has no roll; "
            "check that the image's frame_id is the optical frame (z forward, x right, y down)"
        )
    img = intrinsics.rectify(image_bgr)
    return CameraImage(img, intrinsics.hfov_rad, yaw, pitch, intrinsics.principal_x_px())

"""The real-photo cutter: reference panoramas and pinhole views share one geometry, faults behave."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc.errors import InputError
from factorloc.sim import photo
from factorloc.vision.strips import to_gray


@pytest.fixture(scope="module")
def equirect() -> np.ndarray:
    return photo.synthetic_equirectangular(256, rng=np.random.default_rng(3))


def _corr(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.corrcoef(a.ravel(), b.ravel())[0, 1])


def test_camera_centre_column_looks_where_the_panorama_says(equirect: np.ndarray) -> None:
    pano = photo.reference_panorama(equirect, 1024, 160)
    heading, yaw = 0.7, -0.3
    cam = photo.camera_view(equirect, heading, yaw, hfov_rad=math.radians(40), width_px=101, height_px=81)
    # the camera's centre column (u = 50) looks at photo azimuth heading + yaw, at elevations atan((cy - v)/f)
    u = pano.column_of_azimuth(heading + yaw)
    f_cam = cam.focal_px
    v_cam = np.arange(20, 61)
    elev = np.arctan((40 - v_cam) / f_cam)
    v_pano = pano.height_px / 2 - np.tan(elev) * (pano.height_px / 2) / math.tan(pano.fov_v_rad / 2)
    g_pano, g_cam = to_gray(pano.image_bgr), to_gray(cam.image_bgr)
    col_pano = g_pano[np.rint(v_pano).astype(int), int(round(u))]
    assert _corr(col_pano, g_cam[v_cam, 50]) > 0.9
    # a column 20 px to the side of the true one correlates much less
    wrong = g_pano[np.rint(v_pano).astype(int), int(round(u)) + 20]
    assert _corr(wrong, g_cam[v_cam, 50]) < 0.8


def test_panorama_view_is_the_reference_rolled_by_the_heading(equirect: np.ndarray) -> None:
    ref = photo.reference_panorama(equirect, 512, 96)
    heading = 2 * math.pi * 37 / 512  # an exact number of columns
    rotated = photo.panorama_view(equirect, heading, 512, 96)
    # a robot turned left by θ sees at robot azimuth a what the reference sees at a + θ: 37 columns to the left
    rolled = np.roll(ref.image_bgr.astype(int), 37, axis=1)
    assert np.abs(rolled - rotated.image_bgr.astype(int)).mean() < 1.0


def test_photometric_changes_brightness_and_leaves_the_input_alone(equirect: np.ndarray) -> None:
    img = photo.camera_view(equirect, 0.0, width_px=64, height_px=48).image_bgr
    before = img.copy()
    darker = photo.photometric(img, gain=0.5)
    assert darker.mean() == pytest.approx(0.5 * img.mean(), rel=0.02)
    noisy = photo.photometric(img, noise_sigma=10.0, rng=np.random.default_rng(0))
    assert 7.0 < float((noisy.astype(float) - img).std()) < 11.0
    assert np.array_equal(img, before)


def test_occlude_covers_about_the_requested_fraction(equirect: np.ndarray) -> None:
    img = photo.camera_view(equirect, 0.0, width_px=160, height_px=120).image_bgr
    out = photo.occlude(img, 0.3, rng=np.random.default_rng(1), n_blocks=2)
    changed = np.any(out != img, axis=2).mean()
    assert 0.15 < changed < 0.35


def test_bad_inputs_raise_input_error(tmp_path) -> None:
    with pytest.raises(InputError, match="not found"):
        photo.load_equirectangular(tmp_path / "missing.png")
    with pytest.raises(InputError, match="uint8"):
        photo.reference_panorama(np.zeros((64, 128, 3), np.float32))
    with pytest.raises(InputError, match="fraction"):
        photo.occlude(np.zeros((32, 32, 3), np.uint8), 1.5)


def test_real_photos_load_as_two_to_one_colour_images(shared_data) -> None:
    for name in ("indoor-bedroom.png", "outdoor-summit.jpg"):
        img = photo.load_equirectangular(shared_data / "panoramas" / name)
        assert img.shape[1] == 2 * img.shape[0] and img.shape[2] == 3

"""Query views reprojected onto the reference grid: a heading becomes a pure column shift."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc.sim import photo
from factorloc.vision.strips import Grid, camera_strip, panorama_strip, texture_problem, to_gray


@pytest.fixture(scope="module")
def equirect() -> np.ndarray:
    return photo.synthetic_equirectangular(256, rng=np.random.default_rng(5))


def _reference_window(ref_gray: np.ndarray, strip, heading_rad: float) -> np.ndarray:
    w = ref_gray.shape[1]
    x = strip.col0 - heading_rad * w / (2 * math.pi)
    assert abs(x - round(x)) < 1e-6
    cols = np.mod(int(round(x)) + np.arange(strip.width_px), w)
    return ref_gray[strip.row0 : strip.row0 + strip.height_px, cols]


@pytest.mark.parametrize(
    ("hfov_deg", "size", "yaw", "pitch"),
    [(57.0, (320, 240), 0.0, 0.0), (90.0, (200, 100), 1.2, 0.0), (40.0, (640, 480), -2.0, 0.08)],
)
def test_camera_strip_is_the_reference_shifted_by_the_heading(equirect, hfov_deg, size, yaw, pitch) -> None:
    pano = photo.reference_panorama(equirect, 720, 160)
    grid = Grid.of(pano)
    heading = 2 * math.pi * 123 / 720  # whole columns, so the comparison needs no interpolation
    cam = photo.camera_view(equirect, heading, yaw, math.radians(hfov_deg), size[0], size[1], pitch_rad=pitch)
    strip = camera_strip(cam, grid)
    assert strip is not None
    # the strip spans the camera's field of view minus the edge columns
    assert strip.width_px == pytest.approx(math.radians(hfov_deg) / grid.rad_per_px, abs=4)
    window = _reference_window(to_gray(pano.image_bgr), strip, heading)
    assert np.corrcoef(window.ravel(), strip.gray.ravel())[0, 1] > 0.97
    assert float(strip.azimuth_of_column((strip.width_px - 1) / 2)) == pytest.approx(yaw, abs=grid.rad_per_px)


def test_panorama_strip_resamples_a_finer_query_panorama(equirect) -> None:
    pano = photo.reference_panorama(equirect, 512, 96)
    query = photo.panorama_view(equirect, 2 * math.pi * 40 / 512, 1024, 240, math.radians(70))
    strip = panorama_strip(query, Grid.of(pano))
    assert strip is not None and strip.full_circle and strip.width_px == 512
    window = _reference_window(to_gray(pano.image_bgr), strip, 2 * math.pi * 40 / 512)
    assert np.corrcoef(window.ravel(), strip.gray.ravel())[0, 1] > 0.95


def test_texture_problem_names_black_and_flat_images() -> None:
    assert "black" in texture_problem(np.zeros((20, 20), np.float32))
    assert "flat" in texture_problem(np.full((20, 20), 120.0, np.float32))
    assert texture_problem(np.random.default_rng(0).uniform(0, 255, (20, 20)).astype(np.float32)) is None

"""Reference panoramas stitched from pinhole views at known yaws (real photos), and the equirectangular helpers."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from factorloc import CameraImage, Estimate, Panorama, Query, Reference
from factorloc.errors import InputError
from factorloc.estimators import compass
from factorloc.estimators.base import Hypotheses
from factorloc.sim import photo
from factorloc.vision.panoramas import camera_view_from_equirectangular, load_equirectangular, panorama_from_equirectangular

PHOTOS = {"indoor-bedroom.png": 1024, "outdoor-summit.jpg": 2048}
#: the robot stands where the reference was taken (± 1 cm), as the camera-step tests of the real photos assume
AT_REFERENCE = Hypotheses((Estimate.position("odometry", 0.0, 0.0, 0.01, 0.01),))


def _stitched(eq: np.ndarray, width: int, yaws_deg: np.ndarray) -> Panorama:
    views = [camera_view_from_equirectangular(eq, math.radians(y), width_px=640, height_px=480) for y in yaws_deg]
    return Panorama.from_images(views, np.radians(yaws_deg), width_px=width)


@pytest.fixture(scope="module", params=sorted(PHOTOS))
def real(request, shared_data: Path):
    eq = load_equirectangular(shared_data / "panoramas" / request.param)
    return request.param, eq, _stitched(eq, PHOTOS[request.param], np.arange(8) * 45.0)


def test_eight_views_give_the_photos_own_panorama(real) -> None:
    name, eq, pano = real
    assert pano.seen_columns is None  # 8 × 57° cover the circle
    direct = panorama_from_equirectangular(eq, pano.width_px, pano.height_px, pano.fov_v_rad)
    err = np.abs(pano.image_bgr.astype(float) - direct.image_bgr.astype(float))
    assert np.median(err) <= 2.0 and np.mean(err) < 4.0, (
        f"{name}: stitched differs from the photo by {np.mean(err):.1f} grey levels"
    )


def test_the_compass_against_a_stitched_panorama_is_reliable_and_within_a_tenth_of_a_degree(real) -> None:
    """Held-back views at random headings (none of the 8 used): ≥ 90 % reliable, median error ≤ 0.1°.

    The bedroom has a plain wall: 4 of its 60 views see fewer than 8 keypoints and no compass can vote on them
    (they fail against the photo's own panorama as well). The 90 % is counted on the views the compass can vote on,
    the comparison with the photo's own panorama on all of them.
    """
    name, eq, pano = real
    direct = Reference(panorama=panorama_from_equirectangular(eq, pano.width_px, pano.height_px, pano.fov_v_rad))
    stitched = Reference(panorama=pano)
    prepared = {k: compass.prepare(r) for k, r in (("stitched", stitched), ("direct", direct))}
    rng = np.random.default_rng(7)
    results = {"stitched": [], "direct": []}
    for _ in range(60):
        h = rng.uniform(-math.pi, math.pi)
        cam = camera_view_from_equirectangular(eq, h, width_px=320, height_px=240)
        for k, ref in (("stitched", stitched), ("direct", direct)):
            est = compass.estimate(ref, Query(images=(cam,)), AT_REFERENCE, prepared=prepared[k])
            err = abs(math.remainder(est.value("theta") - h, 2 * math.pi))
            results[k].append((est.reliable, err, est.sigma("theta"), est.diagnostics.get("query_keypoints", 10**6)))
    s = results["stitched"]
    votable = [r for r in s if r[3] >= compass.CompassConfig().min_inliers]
    reliable = [r for r in s if r[0]]
    assert len(votable) >= 55
    assert sum(r[0] for r in votable) >= 0.9 * len(votable), f"{name}: {sum(r[0] for r in votable)}/{len(votable)} reliable"
    assert np.median([r[1] for r in reliable]) <= math.radians(0.1)
    assert all(r[1] < 3 * r[2] for r in reliable)
    assert len(reliable) >= sum(r[0] for r in results["direct"]) - 1  # no worse than the photo's own panorama


def test_fewer_views_leave_the_columns_no_view_covers_unseen(shared_data: Path) -> None:
    eq = load_equirectangular(shared_data / "panoramas" / "outdoor-summit.jpg")
    yaws = np.array([0.0, 60.0, 120.0, 200.0])  # gaps between 120° and 200°, and between 200° and 360°
    pano = _stitched(eq, 720, yaws)
    seen = pano.seen_columns
    assert seen is not None and pano.width_px == 720
    # a column is seen when some view's horizontal half-angle (28.5°) reaches it, at the band's top and bottom rows;
    # the default band is the one every view covers across its whole width, so the seen span ends at ±28.5° to a column (0.5°)
    az = np.degrees(pano.azimuth_of_column(np.arange(720)))
    off = np.min(np.abs(((az[:, None] - yaws[None, :]) + 180.0) % 360.0 - 180.0), axis=1)
    assert seen[off < 27.9].all() and not seen[off > 28.6].any()
    assert np.all(pano.image_bgr[:, ~seen].reshape(-1, 3).max(axis=0) <= 255)
    with pytest.raises(InputError, match="seen_columns marks no column"):
        Panorama(pano.image_bgr, seen_columns=np.zeros(720, bool))


def test_gain_compensation_evens_out_exposure_between_views(shared_data: Path) -> None:
    eq = load_equirectangular(shared_data / "panoramas" / "outdoor-summit.jpg")
    yaws = np.arange(8) * 45.0
    views = []
    for i, y in enumerate(yaws):
        v = camera_view_from_equirectangular(eq, math.radians(y), width_px=640, height_px=480)
        gain = 0.8 if i % 2 else 1.15  # auto-exposure alternating between views
        views.append(CameraImage(photo.photometric(v.image_bgr, gain=gain), v.hfov_rad, v.yaw_in_robot_rad))
    direct = panorama_from_equirectangular(eq, 1024, 117, math.radians(39.4)).image_bgr.astype(float)
    errs = {}
    for comp in (True, False):
        pano = Panorama.from_images(
            views, np.radians(yaws), width_px=1024, height_px=117, fov_v_rad=math.radians(39.4), gain_compensation=comp
        )
        img = pano.image_bgr.astype(float)
        errs[comp] = np.abs(img * direct.mean() / img.mean() - direct).mean()
    assert errs[True] < 0.8 * errs[False]


def test_bad_inputs_are_refused() -> None:
    cam = CameraImage(np.full((48, 64, 3), 100, np.uint8))
    with pytest.raises(InputError, match="at least one image"):
        Panorama.from_images([], [])
    with pytest.raises(InputError, match="2 values for 1 images"):
        Panorama.from_images([cam], [0.0, 1.0])
    with pytest.raises(InputError, match="finite"):
        Panorama.from_images([cam], [math.nan])
    with pytest.raises(InputError, match="must be a factorloc.CameraImage"):
        Panorama.from_images([np.zeros((48, 64, 3), np.uint8)], [0.0])
    one = Panorama.from_images([cam], [0.0], width_px=256)
    assert one.seen_columns is not None and 0.1 < one.seen_columns.mean() < 0.2  # 57° of 360°


def test_views_that_reach_unseen_columns_are_never_confidently_wrong(real) -> None:
    """Five views of eight leave 135° unseen. Views that overlap the gap (in part) may be unreliable, never wrong.

    Measured on this branch, where the camera steps do not yet skip unseen columns (``Panorama.seen_columns``
    is honoured by the vision engineer's change): of 30 such views the compass is reliable on 50–57 %, the
    correlation on 3 %, none beyond 3σ.
    """
    from factorloc.estimators import correlation

    name, eq, _ = real
    pano = _stitched(eq, PHOTOS[name], np.arange(5) * 45.0)
    ref = Reference(panorama=pano)
    prepared = {"compass": compass.prepare(ref), "correlation": correlation.prepare(ref)}
    rng = np.random.default_rng(3)
    checked = 0
    while checked < 20:
        h = rng.uniform(-math.pi, math.pi)
        cols = np.round(pano.column_of_azimuth(h + np.linspace(-0.5, 0.5, 20))).astype(int) % pano.width_px
        if pano.seen_columns[cols].all():
            continue
        checked += 1
        cam = camera_view_from_equirectangular(eq, h, width_px=320, height_px=240)
        for module in (compass, correlation):
            est = module.estimate(ref, Query(images=(cam,)), AT_REFERENCE, prepared=prepared[module.__name__.rsplit(".", 1)[-1]])
            if est.reliable:
                assert abs(math.remainder(est.value("theta") - h, 2 * math.pi)) < 3 * est.sigma("theta"), (name, module.__name__)

"""The compass's vote consensus and descriptor matching."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from factorloc.vision.keypoints import match, vote_consensus


def test_consensus_finds_the_mode_across_the_wrap_and_ignores_outliers() -> None:
    rng = np.random.default_rng(1)
    true = math.pi - 0.002  # votes straddle ±π
    inl = true + rng.normal(0, math.radians(0.3), 40)
    out = rng.uniform(-math.pi, math.pi, 60)
    votes = np.angle(np.exp(1j * np.concatenate([inl, out])))
    theta, inliers, runner_up = vote_consensus(votes, math.radians(1.5))
    assert abs(math.remainder(theta - true, 2 * math.pi)) < math.radians(0.15)
    assert inliers[:40].mean() > 0.95 and inliers[40:].mean() < 0.1
    assert runner_up < 10


def test_ratio_test_and_window_mask_restrict_matches() -> None:
    rng = np.random.default_rng(2)
    ref = rng.integers(0, 256, (50, 32), dtype=np.uint8)
    query = ref[[3, 7, 11]].copy()
    qi, ri = match(query, ref, cv2.NORM_HAMMING, 0.8)
    assert list(ri) == [3, 7, 11] and list(qi) == [0, 1, 2]
    allowed = np.ones((3, 50), bool)
    allowed[1, 7] = False  # the true partner of query 1 lies outside its window
    qi, ri = match(query, ref, cv2.NORM_HAMMING, 0.8, allowed)
    assert 1 not in qi.tolist()
    assert qi.tolist() == [0, 2] and ri.tolist() == [3, 11]


def test_nearest_circular_distance_wraps_around() -> None:
    from factorloc.vision.keypoints import nearest_circular_distance

    d = nearest_circular_distance(np.array([3.1, -3.1, 0.0]), np.array([-3.13, 0.5]))
    assert d == pytest.approx([2 * math.pi - 3.1 - 3.13, 0.03, 0.5], abs=1e-9)


def test_l2_matcher_takes_the_same_decisions_as_opencv_brute_force() -> None:
    """The matrix-product matcher keeps exactly the pairs OpenCV's knnMatch + ratio test keeps, with a window mask."""
    rng = np.random.default_rng(3)
    ref = rng.random((400, 128), dtype=np.float32) * 100
    query = ref[rng.choice(400, 150, replace=False)] + rng.normal(0, 8, (150, 128)).astype(np.float32)
    query = np.vstack([query, rng.random((50, 128), dtype=np.float32) * 100])  # 50 without a partner
    allowed = rng.random((200, 400)) < 0.5
    allowed[:, :3] = False
    allowed[0] = False
    allowed[1] = False
    allowed[1, 7] = True  # a single candidate: no ratio test, only the absolute distance
    for mask in (None, allowed):
        qi, ri = match(query, ref, cv2.NORM_L2, 0.8, mask)
        knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(query, ref, k=2, mask=None if mask is None else mask.astype(np.uint8))
        expected = []
        for pair in knn:
            if len(pair) == 2 and pair[0].distance < 0.8 * pair[1].distance:
                expected.append((pair[0].queryIdx, pair[0].trainIdx))
            elif len(pair) == 1 and pair[0].distance < 250.0:
                expected.append((pair[0].queryIdx, pair[0].trainIdx))
        assert list(zip(qi.tolist(), ri.tolist(), strict=True)) == expected
        assert len(expected) > 40  # most true partners survive (about half of them are masked out)


def test_support_of_many_vote_rows_equals_the_pairwise_count() -> None:
    from factorloc.geometry import wrap_angle
    from factorloc.vision.keypoints import support_rows

    rng = np.random.default_rng(4)
    votes = rng.uniform(-4.0, 4.0, (24, 120))
    votes[:, :40] = math.pi - 0.01 + rng.normal(0, 0.01, (24, 40))  # a mode straddling ±π
    band = math.radians(1.5)
    brute = np.array([(np.abs(wrap_angle(v[:, None] - v[None, :])) <= band).sum(axis=1) for v in votes])
    assert np.array_equal(support_rows(votes, band), brute)
    assert brute.max() >= 30


def test_circular_abs_diff_matches_wrap_angle_to_a_microradian() -> None:
    from factorloc.geometry import wrap_angle
    from factorloc.vision.keypoints import circular_abs_diff

    rng = np.random.default_rng(5)
    a, b = rng.uniform(-math.pi, math.pi, 300), rng.uniform(-math.pi, math.pi, 200)
    exact = np.abs(wrap_angle(a[None, :] - b[:, None] - 2.5))
    assert np.max(np.abs(circular_abs_diff(a, b, 2.5) - exact)) < 2e-6


@pytest.mark.parametrize("scale", [1.0, 0.5])
def test_sift_keypoints_are_unbiased_at_full_and_reduced_detection_scale(scale) -> None:
    """OpenCV's SIFT reports blobs ¼ px off (its doubled first octave); detect() removes that at any scale."""
    from factorloc.vision.keypoints import detect, make_detector

    yy, xx = np.mgrid[0:200, 0:400]
    centres = [(50.3, 60.0), (150.0, 100.7), (300.5, 140.2), (220.0, 50.0)]
    image = sum(200 * np.exp(-((xx - x) ** 2 + (yy - y) ** 2) / (2 * 3.0**2)) for x, y in centres) + 20
    xy, desc = detect(image.astype(np.float32), make_detector("sift", 100), scale=scale)
    assert desc is not None and len(xy) >= 4
    for x, y in centres:
        assert np.min(np.hypot(xy[:, 0] - x, xy[:, 1] - y)) < 0.06


def test_one_per_location_keeps_the_smallest_angle_of_each_position() -> None:
    from factorloc.vision.keypoints import one_per_location_index

    xy = np.array([[5.0, 2.0], [1.0, 1.0], [5.0, 2.0], [1.0, 1.5], [5.0, 2.0], [1.0, 1.0]])
    angle = np.array([200.0, 30.0, 10.0, 90.0, 350.0, 5.0])
    assert one_per_location_index(xy, angle).tolist() == [2, 3, 5]
    assert one_per_location_index(xy[:1], angle[:1]).tolist() == [0]


def test_sift_detection_with_one_keypoint_per_location_drops_only_the_orientation_copies() -> None:
    """SIFT reports some keypoints once per dominant orientation; ``one_per_location`` keeps every position once."""
    from factorloc.vision.keypoints import detect, make_detector

    rng = np.random.default_rng(6)
    image = cv2.GaussianBlur(rng.uniform(0, 255, (160, 320)).astype(np.float32), (0, 0), 2.0)
    image = cv2.normalize(image, None, 0, 255, cv2.NORM_MINMAX)
    xy_all, desc_all = detect(image, make_detector("sift", 2000))
    xy_one, desc_one = detect(image, make_detector("sift", 2000), one_per_location=True)
    positions = {tuple(p) for p in xy_all.tolist()}
    assert len(positions) < len(xy_all) - 10  # the image has orientation copies to drop
    assert len(xy_one) == len(positions) == len({tuple(p) for p in xy_one.tolist()})
    assert desc_one.shape == (len(xy_one), 128)
    # each kept descriptor is one of its position's copies
    for p, d in zip(xy_one[:50], desc_one[:50], strict=True):
        same = np.flatnonzero(np.all(xy_all == p, axis=1))
        assert any(np.array_equal(d, desc_all[k]) for k in same)


def test_l2_matcher_with_fewer_than_100_query_rows_matches_the_brute_force() -> None:
    """Below 100 query rows the product is padded (OpenCV's fast path): the same pairs as OpenCV's knnMatch."""
    rng = np.random.default_rng(8)
    ref = rng.integers(0, 120, (900, 128)).astype(np.float32)  # integer-valued, like OpenCV's SIFT descriptors
    query = np.rint(ref[rng.choice(900, 60, replace=False)] + rng.normal(0, 6, (60, 128))).clip(0, 255).astype(np.float32)
    allowed = rng.random((60, 900)) < 0.7
    for mask in (None, allowed):
        qi, ri = match(query, ref, cv2.NORM_L2, 0.8, mask)
        knn = cv2.BFMatcher(cv2.NORM_L2).knnMatch(query, ref, k=2, mask=None if mask is None else mask.astype(np.uint8))
        expected = [(p[0].queryIdx, p[0].trainIdx) for p in knn if len(p) == 2 and p[0].distance < 0.8 * p[1].distance]
        assert list(zip(qi.tolist(), ri.tolist(), strict=True)) == expected
        assert len(expected) > 30


@pytest.mark.parametrize("n_query", [60, 150])
def test_windowed_matcher_keeps_the_pairs_of_the_masked_brute_force(n_query) -> None:
    """match_in_window = match with the window mask circular_abs_diff(...) <= reach, also at the window's edge."""
    from factorloc.vision.keypoints import circular_abs_diff, match_in_window

    rng = np.random.default_rng(9)
    ref = rng.integers(0, 120, (700, 128)).astype(np.float32)
    partner = rng.choice(700, n_query, replace=False)
    query = np.rint(ref[partner] + rng.normal(0, 6, (n_query, 128))).clip(0, 255).astype(np.float32)
    az_ref = rng.uniform(-math.pi, math.pi, 700)
    az_query = np.asarray(np.angle(np.exp(1j * (az_ref[partner] - 2.9 + rng.normal(0, 0.3, n_query)))))
    offset, reach = 2.9, 0.35  # the window straddles ±π
    az_ref[:40] = az_query[:40] + offset + reach  # reference points exactly at the window's edge
    az_ref[40:80] = az_query[:40] + offset - reach * (1 + 1e-7)
    allowed = circular_abs_diff(az_ref, az_query, offset) <= reach
    assert 0.05 < allowed.mean() < 0.5
    expected = match(query, ref, cv2.NORM_L2, 0.8, allowed)
    qi, ri = match_in_window(query, az_query, ref, az_ref, offset, reach, 0.8)
    assert qi.tolist() == expected[0].tolist() and ri.tolist() == expected[1].tolist()
    assert len(qi) > n_query // 3
    assert np.all(allowed[qi, ri])


def test_windowed_matcher_refuses_azimuths_that_do_not_fit_the_descriptors() -> None:
    from factorloc.errors import InputError
    from factorloc.vision.keypoints import match_in_window

    d = np.zeros((5, 128), np.float32)
    with pytest.raises(InputError, match="ref_az_rad"):
        match_in_window(d, np.zeros(5), d, np.zeros(4), 0.0, 0.5, 0.8)


def test_compiled_vote_consensus_and_support_agree_with_the_numpy_reference() -> None:
    """The compiled votes (sequential circular mean) and the NumPy reference (pairwise): the same inliers and
    rival support on 300 vote sets with a mode and outliers, the mode within 1e-12 rad."""
    from factorloc.vision.keypoints import support_rows

    rng = np.random.default_rng(5)
    band = math.radians(1.5)
    for _ in range(300):
        n = int(rng.integers(1, 150))
        votes = np.concatenate([rng.normal(rng.uniform(-4, 4), 0.01, n // 2 + 1), rng.uniform(-7, 7, n)])
        ref = vote_consensus(votes, band, compiled=False)
        got = vote_consensus(votes, band)
        assert np.array_equal(ref[1], got[1]) and ref[2] == got[2]
        assert abs(math.remainder(ref[0] - got[0], 2 * math.pi)) < 1e-12
    rows = rng.uniform(-7.0, 7.0, (24, 90))
    assert np.array_equal(support_rows(rows, band, compiled=False), support_rows(rows, band))


def test_two_nearest_kernel_finds_the_first_smallest_and_the_second_order_statistic_with_ties() -> None:
    """The lane-wise scan of the windowed kernel = argmin (first column of the smallest) and the second smallest
    value of the masked row (a tie with the smallest counts), also where no or one column is allowed."""
    from factorloc.vision._kernels import two_nearest_in_window
    from factorloc.vision.keypoints import circular_abs_diff

    rng = np.random.default_rng(10)
    for nr, reach in ((37, 0.8), (1000, 0.05), (1000, 1e-4), (5, 3.2)):
        d2 = -2.0 * rng.integers(0, 400, (60, nr)).astype(np.float32)  # few distinct values: many ties
        norms = rng.integers(0, 50, nr).astype(np.float32)
        az_ref = rng.uniform(-math.pi, math.pi, nr).astype(np.float32)
        az_query = rng.uniform(-math.pi, math.pi, 60).astype(np.float32)
        j, best, second = two_nearest_in_window(d2, norms, az_ref, az_query, np.float32(reach), np.float32(2 * math.pi))
        full = d2 + norms[None, :]
        full[circular_abs_diff(az_ref, az_query) > reach] = np.inf
        k = np.argmin(full, axis=1)
        srt = np.sort(full, axis=1)
        assert np.array_equal(best, srt[:, 0]) and np.array_equal(second, srt[:, 1] if nr > 1 else np.inf)
        none = ~np.isfinite(srt[:, 0])
        assert np.array_equal(j[~none], k[~none]) and np.all(j[none] == 0)

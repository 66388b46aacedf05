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

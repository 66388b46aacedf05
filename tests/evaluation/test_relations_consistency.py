"""The relations' own consistency around their triangles (factorloc.evaluation.relations_consistency)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc.errors import InputError
from factorloc.evaluation.relations import Relations, read_relations
from factorloc.evaluation.relations_consistency import relations_consistency
from factorloc.geometry import Pose2


def _trajectory(n: int, rng: np.random.Generator) -> list[Pose2]:
    """A wandering planar path (m, rad), one pose a second."""
    poses, p = [], Pose2(0.0, 0.0, 0.0)
    for _ in range(n):
        poses.append(p)
        p = p.compose(Pose2(rng.uniform(0.2, 0.5), 0.0, rng.normal(0.0, 0.3)))
    return poses


def _relations(poses: list[Pose2], pairs: list[tuple[int, int]], sigma_m: float, sigma_rad: float, rng) -> Relations:
    """Relations between ``pairs`` of ``poses`` (stamps = indices in s) with independent noise of known σ."""
    out = []
    for a, b in pairs:
        r = poses[a].inverse().compose(poses[b])
        out.append((r.x + rng.normal(0, sigma_m), r.y + rng.normal(0, sigma_m), r.theta + rng.normal(0, sigma_rad)))
    t1 = np.array([a for a, _ in pairs], dtype=float)
    t2 = np.array([b for _, b in pairs], dtype=float)
    return Relations(t1, t2, np.array(out))


def _pairs(n: int) -> list[tuple[int, int]]:
    """Chains a→a+1 and a→a+2: every (a, a+1, a+2) is a triangle."""
    return [(a, a + 1) for a in range(n - 1)] + [(a, a + 2) for a in range(n - 2)]


def test_exact_relations_close_every_triangle():
    rng = np.random.default_rng(3)
    poses = _trajectory(40, rng)
    c = relations_consistency(_relations(poses, _pairs(40), 0.0, 0.0, rng))
    assert len(c.triangles) == 38 and len(c.members) == 77  # every relation lies on a triangle
    assert np.abs(c.closures).max() < 1e-12
    assert c.sigma_position_m < 1e-12 and c.best_fit_mean_error_m < 1e-6


def test_noise_level_is_recovered():
    """Relations with 2 cm / 0.3° noise per axis: the triangles say so (within the sampling spread of ~600)."""
    rng = np.random.default_rng(11)
    n = 600
    poses = _trajectory(n, rng)
    c = relations_consistency(_relations(poses, _pairs(n), 0.02, math.radians(0.3), rng))
    assert c.sigma_position_m == pytest.approx(0.02, rel=0.15)
    assert c.sigma_heading_rad == pytest.approx(math.radians(0.3), rel=0.15)
    assert c.implied_mean_error_m == pytest.approx(0.02 * math.sqrt(math.pi / 2), rel=0.15)
    # the trajectory fitted to the relations alone absorbs part of the noise, never all of it
    assert 0.2 * c.implied_mean_error_m < c.best_fit_mean_error_m < c.implied_mean_error_m


def test_no_triangle_and_bad_input():
    rng = np.random.default_rng(5)
    poses = _trajectory(10, rng)
    chain = relations_consistency(_relations(poses, [(a, a + 1) for a in range(9)], 0.01, 0.01, rng))
    assert len(chain.triangles) == 0 and math.isnan(chain.sigma_position_m)
    assert "no triangle" in chain.summary()
    bad = Relations(np.array([0.0]), np.array([1.0]), np.array([[np.nan, 0.0, 0.0]]))
    with pytest.raises(InputError, match="non-finite"):
        relations_consistency(bad)
    with pytest.raises(InputError, match="tolerance_s"):
        relations_consistency(_relations(poses, [(0, 1)], 0.0, 0.0, rng), tolerance_s=0.0)


def test_real_logs_carry_centimetre_noise(shared_data):
    """The three logs' loop relations disagree with each other around their triangles by centimetres."""
    expected = {"intel": (327, 0.006, 0.012), "aces": (28, 0.018, 0.03), "mit-csail": (53, 0.015, 0.026)}
    for name, (triangles, lo, hi) in expected.items():
        c = relations_consistency(read_relations(shared_data / "laser" / f"{name}.relations"))
        assert len(c.triangles) == triangles
        assert lo < c.sigma_position_m < hi, name

"""Wrap-around normalized cross-correlation and the sub-pixel parabola."""

from __future__ import annotations

import numpy as np
import pytest

from factorloc.vision.ncc import correlate_wrapped, parabolic_peak


def test_template_straddling_column_zero_matches_at_its_true_shift() -> None:
    rng = np.random.default_rng(0)
    ref = rng.uniform(0, 255, (40, 300)).astype(np.float32)
    cols = np.mod(np.arange(280, 280 + 50), 300)  # crosses the seam
    template = np.ascontiguousarray(ref[5:35, cols])
    scores = correlate_wrapped(ref, template, 0, 299)
    dy, k = np.unravel_index(np.argmax(scores), scores.shape)
    assert (dy, k) == (5, 280)
    assert scores[dy, k] == pytest.approx(1.0, abs=1e-4)
    # shifts outside [0, W) are taken modulo W
    scores2 = correlate_wrapped(ref, template, -30, -10)
    assert int(np.argmax(scores2.max(axis=0))) == 10  # shift -20 ≡ 280


def test_parabolic_peak_recovers_the_vertex_of_a_parabola() -> None:
    vertex, curvature = 0.3, 0.8
    y = [-0.5 * curvature * (x - vertex) ** 2 for x in (-1, 0, 1)]
    delta, kappa = parabolic_peak(*y)
    assert delta == pytest.approx(vertex)
    assert kappa == pytest.approx(curvature)
    assert parabolic_peak(1.0, 0.5, 1.0) == (0.0, 0.0)  # a minimum is not refined


def test_synthesized_columns_subset_equals_the_full_rendering() -> None:
    """Rendering only the columns the seeded window reaches gives those columns bit for bit."""
    from factorloc import Pose2, Reference
    from factorloc.sim import DepthCamera, apartment, render_cloud_360, render_panorama
    from factorloc.vision.depth import depth_map
    from factorloc.vision.strips import Grid, to_gray
    from factorloc.vision.synth import synthesize

    world, pose = apartment(), Pose2(3.0, 2.2, 0.3)
    pano = render_panorama(world, pose, width_px=512)
    ref = Reference(panorama=pano, cloud=render_cloud_360(world, pose, DepthCamera(stride_px=8)), T_world_reference=pose)
    grid = Grid.of(pano)
    gray, depth = to_gray(pano.image_bgr), depth_map(ref, grid, 1.0)
    cols = np.zeros(grid.width_px, dtype=bool)
    cols[np.arange(-40, 90) % grid.width_px] = True  # across the seam
    full, r_full, m_full = synthesize(gray, grid, depth, (0.4, -0.3))
    part, r_part, m_part = synthesize(gray, grid, depth, (0.4, -0.3), columns=cols)
    assert np.array_equal(part[:, cols], full[:, cols]) and not part[:, ~cols].any()
    assert np.array_equal(r_part, r_full) and np.array_equal(m_part, m_full)
    assert full[:, cols].std() > 5.0

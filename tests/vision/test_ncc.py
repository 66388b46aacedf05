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

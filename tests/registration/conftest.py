"""Synthetic 2D scenes for the registration tests: a room with furniture and a long corridor."""

from __future__ import annotations

import numpy as np
import pytest


def _segments_points(segments: list[tuple[tuple[float, float], tuple[float, float]]], spacing_m: float) -> np.ndarray:
    pts = []
    for (x0, y0), (x1, y1) in segments:
        n = max(2, int(np.hypot(x1 - x0, y1 - y0) / spacing_m))
        t = np.linspace(0.0, 1.0, n)
        pts.append(np.column_stack([x0 + t * (x1 - x0), y0 + t * (y1 - y0)]))
    return np.vstack(pts)


@pytest.fixture(scope="module")
def room_points() -> np.ndarray:
    """An irregular 8 × 6 m room with a pillar and a cupboard (robot frame at the origin), 2 cm spacing."""
    segs = [
        ((-3.0, -2.5), (5.0, -2.5)),
        ((5.0, -2.5), (5.0, 1.0)),
        ((5.0, 1.0), (4.0, 1.0)),
        ((4.0, 1.0), (4.0, 3.5)),
        ((4.0, 3.5), (-3.0, 3.5)),
        ((-3.0, 3.5), (-3.0, -2.5)),
        ((1.0, 1.0), (1.5, 1.0)),
        ((1.5, 1.0), (1.5, 1.5)),
        ((1.5, 1.5), (1.0, 1.5)),
        ((1.0, 1.5), (1.0, 1.0)),
        ((-2.0, -2.5), (-2.0, -1.5)),
        ((-2.0, -1.5), (-1.0, -1.5)),
        ((-1.0, -1.5), (-1.0, -2.5)),
    ]
    return _segments_points(segs, 0.02)


@pytest.fixture(scope="module")
def corridor_points() -> np.ndarray:
    """A 30 m long, 1.5 m wide featureless corridor along x (robot frame at the origin), 2 cm spacing."""
    segs = [((-15.0, -0.75), (15.0, -0.75)), ((-15.0, 0.75), (15.0, 0.75))]
    return _segments_points(segs, 0.02)

"""Helpers shared by the compass and correlation tests: the real photographs and position hypotheses."""

from __future__ import annotations

import math

from factorloc import Estimate, Reference
from factorloc.estimators.base import Hypotheses

#: the real panoramas of ../shared/data/panoramas and the reference panorama size (W, H) cut from each
PHOTOS = {"indoor-bedroom.png": (1024, 180), "outdoor-summit.jpg": (2048, 340)}


def at(reference: Reference, sigma_m: float = 0.01) -> Hypotheses:
    """A position hypothesis: the robot stands where the reference was taken (± ``sigma_m``)."""
    p = reference.T_world_reference
    return Hypotheses((Estimate.position("odometry", p.x, p.y, sigma_m, sigma_m),))


def heading_error(est: Estimate, truth: float) -> float:
    """|θ − truth| on the circle (rad)."""
    return abs(math.remainder(est.value("theta") - truth, 2 * math.pi))

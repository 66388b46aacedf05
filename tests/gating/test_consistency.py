"""The consistency gate's ``heading_takes_position``: a full pose whose heading disagrees loses its position too (the
ICP solutions of several places, some reading a corridor the other way: ``TrackerConfig.recognition_whole_pose``)."""

from __future__ import annotations

import math

import numpy as np

from factorloc.gating import consistency_gate
from factorloc.types import FULL, POSITION, Estimate


def _corridor_pose(step: str, x_m: float, y_m: float, theta_rad: float, sigma_rad: float = 0.05) -> Estimate:
    """A full pose vague along the corridor (x: σ 30 m), tight across it and in heading."""
    return Estimate(step, FULL, np.array([x_m, y_m, theta_rad]), np.diag([30.0**2, 0.3**2, sigma_rad**2]))


def test_a_turned_full_pose_loses_its_position_with_heading_takes_position() -> None:
    from factorloc.gating.consistency import WHOLE_POSE_POSITION

    # two places read the corridor one way, three the other (180°, the majority, its headings the more certain: the
    # shape of ACES scan 5139, docs/places.md); all positions agree, being vague along the corridor
    true = [_corridor_pose(f"icp@a{i}", -35.0, 1.9 + 0.1 * i, 0.0, 0.08) for i in range(2)]
    turned = [_corridor_pose(f"icp@b{i}", -24.0 + 10 * i, 1.0, math.pi - 0.02 * i, 0.02) for i in range(3)]
    per_axis = consistency_gate(true + turned)
    assert [v.accepted for v in per_axis[:2]] == [POSITION, POSITION]  # the position of one reading, kept
    whole = consistency_gate(true + turned, heading_takes_position=True)
    assert [v.accepted for v in whole[:2]] == [(), ()]
    assert all(v.fully_accepted for v in whole[2:])
    codes = [c.code for c in whole[0].checks if not c.passed]
    assert codes == ["gate.consistency.heading", WHOLE_POSE_POSITION]
    # a full pose that agrees in heading keeps everything either way
    same = [_corridor_pose(f"icp@c{i}", -35.0, 1.9, 0.01 * i) for i in range(3)]
    assert all(v.fully_accepted for v in consistency_gate(same, heading_takes_position=True))

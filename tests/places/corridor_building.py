"""The building of the tracker's state tests (imported beside them: pytest puts this folder on the path): a room of
five places at y = ``ROOM_Y_M`` beside a corridor of seventeen at y = 0, every place 1.5 m from the next along x,
each with the same ring scan — a building whose places look alike, so only the tracker's rules tell them apart."""

from __future__ import annotations

import math

import numpy as np

from factorloc.geometry import Pose2
from factorloc.places import Place, PlaceMap
from factorloc.types import Reference, Scan

ROOM_Y_M = 4.0  # the start: a room beside the corridor (y = 0)


def ring_scan(radius_m: float = 3.0, n: int = 90) -> Scan:
    """``n`` points on a circle of ``radius_m`` about the sensor (robot frame, m)."""
    a = np.linspace(-math.pi, math.pi, n, endpoint=False)
    return Scan(np.column_stack([radius_m * np.cos(a), radius_m * np.sin(a)]))


def building() -> PlaceMap:
    """The room and the corridor (world frame, m)."""
    room = [Place(f"r{i}", Reference(scan=ring_scan()), Pose2(1.5 * i, ROOM_Y_M, 0.0)) for i in range(5)]
    corridor = [Place(f"c{i}", Reference(scan=ring_scan()), Pose2(1.5 * i, 0.0, 0.0)) for i in range(17)]
    return PlaceMap(room + corridor)

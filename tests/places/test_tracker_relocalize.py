"""Re-localization by place recognition: the factors of the recognized places of one query share its error.

The situation of a start-up on the simulated office tour (seed 1004 with ``relocalize_k = 10``, docs/places.md):
the factors of five recognized places of one query entered the graph as independent and the start was
over-confident (4 cm off, d² 13 against its own covariance). Made small on a synthetic building: recognition is
replaced by a fixed answer (the factors it would give), so the test checks the tracker's rule.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc.geometry import Pose2
from factorloc.odometry_model import CHI2_3SIGMA_2DOF
from factorloc.pipeline import fuse
from factorloc.places import Place, PlaceMap, Tracker, TrackerConfig, TrackState
from factorloc.places.multi import PlaceLocalization
from factorloc.types import FULL, Estimate, Odometry, Query, Reference, Scan

TRUTH = Pose2(4.0, 1.0, 0.3)  # where the robot starts (world frame)
SIGMA_M = 0.02  # σ of one place factor (m), each axis
SIGMA_RAD = 0.005


def _ring_scan(radius_m: float = 3.0, n: int = 90) -> Scan:
    a = np.linspace(-math.pi, math.pi, n, endpoint=False)
    return Scan(np.column_stack([radius_m * np.cos(a), radius_m * np.sin(a)]))


def _building(n: int = 12) -> PlaceMap:
    return PlaceMap([Place(f"p{i}", Reference(scan=_ring_scan()), Pose2(1.0 * i, 0.0, 0.0)) for i in range(n)])


def _query(k: int = 0) -> Query:
    return Query(scan=_ring_scan(), odometry=Odometry(Pose2(0.25 * k, 0.0, 0.0), 0.05, 0.05, 0.01), id=f"q{k}")


def _factor(place: str, offset_m: tuple[float, float]) -> Estimate:
    cov = np.diag([SIGMA_M**2, SIGMA_M**2, SIGMA_RAD**2])
    return Estimate(f"icp@{place}", FULL, np.array([TRUTH.x + offset_m[0], TRUTH.y + offset_m[1], TRUTH.theta]), cov)


def test_the_factors_of_one_recognized_query_share_its_error(monkeypatch: pytest.MonkeyPatch) -> None:
    # five places, one scan: the five factors carry the same 5 cm error of the query (its scan's), ±2 mm apart
    places = ("p3", "p4", "p5", "p6", "p7")
    common = (0.05, 0.0)
    spread = (-0.002, -0.001, 0.0, 0.001, 0.002)
    factors = [_factor(p, (common[0] + d, common[1] - d)) for p, d in zip(places, spread, strict=True)]
    loc = fuse(factors)
    assert loc.determined and len(loc.steps) == 5
    tracker = Tracker(_building(), TrackerConfig())
    monkeypatch.setattr(tracker, "_recognize", lambda query: PlaceLocalization(loc, places, (), ()))
    r = tracker.update(_query())
    assert r.state is TrackState.RELOCALIZED
    # flagged only because a chain recognized from one scan waits for a later query's places to confirm it
    assert [c.code for c in r.checks if not c.passed] == ["tracker.confirmed"]
    # the start's covariance is that of one factor (covariance intersection of five), not a fifth of it
    np.testing.assert_allclose(r.covariance, 5.0 * loc.covariance, rtol=1e-6, atol=1e-12)
    e = np.array([r.pose.x - TRUTH.x, r.pose.y - TRUTH.y])
    assert np.hypot(*e) > 0.045  # the error is the query's: no fusion of one scan's factors averages it out
    d2 = float(e @ np.linalg.solve(r.covariance[:2, :2], e))
    assert d2 <= CHI2_3SIGMA_2DOF, d2  # honest: inside its own 3σ (independent factors: d² ≈ 31)
    naive = float(e @ np.linalg.solve(loc.covariance[:2, :2], e))
    assert naive > CHI2_3SIGMA_2DOF  # the case fails without the rule

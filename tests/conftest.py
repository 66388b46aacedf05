"""Shared fixtures: where the real data lives (``<repo>/../shared/data``), skipping when absent."""

from __future__ import annotations

from collections.abc import Callable
from pathlib import Path

import numpy as np
import pytest

import factorloc
from factorloc.datasets import Scenario, ScenarioQuery, ScenarioReference

REPO = Path(__file__).resolve().parents[1]
SHARED_DATA = REPO.parent / "shared" / "data"


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """The real public data beside the checkout; the test is skipped where it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"real data not available at {SHARED_DATA} (../shared/data beside the checkout)")
    return SHARED_DATA


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO


# ----------------------------------------------------------------------------
# A scan-only test room (shared by the CLI and benchmark tests)
# ----------------------------------------------------------------------------
#: Walls of a 5×4 m room with a 1×0.7 m box in it (world frame, m).
ROOM_SEGMENTS = (
    ((0.0, 0.0), (5.0, 0.0)),
    ((5.0, 0.0), (5.0, 4.0)),
    ((5.0, 4.0), (0.0, 4.0)),
    ((0.0, 4.0), (0.0, 0.0)),
    ((2.0, 1.5), (3.0, 1.5)),
    ((3.0, 1.5), (3.0, 2.2)),
    ((3.0, 2.2), (2.0, 2.2)),
    ((2.0, 2.2), (2.0, 1.5)),
)


def room_points(rng: np.random.Generator, per_m: int = 30) -> np.ndarray:
    """N×2 points drawn uniformly on :data:`ROOM_SEGMENTS`, ``per_m`` per metre of wall (world frame, m)."""
    pts = []
    for a, b in ROOM_SEGMENTS:
        a, b = np.array(a), np.array(b)
        t = rng.uniform(0.0, 1.0, (int(per_m * np.linalg.norm(b - a)), 1))
        pts.append(a + t * (b - a))
    return np.vstack(pts)


@pytest.fixture(scope="session")
def make_room_scenario() -> Callable[[int, int], Scenario]:
    """Factory ``make_room_scenario(n, seed)``: a scan-only :class:`factorloc.datasets.Scenario` in the test room.

    The reference scan is taken at ``T_world_reference = (1, 1, 0.3 rad)``; query i
    stands at a random pose (x ∈ [0.6, 1.4], y ∈ [0.6, 3.4] m, θ ∈ [−3, 3] rad),
    its scan is exact (fresh points on the same walls, query frame), its odometry is
    off by (+4, −3) cm and +0.02 rad with σ (5 cm, 5 cm, 0.03 rad); query 1 is
    tagged ``"blur"``. No images: the visual steps are skipped.
    """

    def make(n: int, seed: int) -> Scenario:
        rng = np.random.default_rng(seed)
        T_ref = factorloc.Pose2(1.0, 1.0, 0.3)
        ref = factorloc.Reference(
            scan=factorloc.Scan(T_ref.inverse().transform_points(room_points(rng))), T_world_reference=T_ref
        )
        queries = []
        for i in range(n):
            T = factorloc.Pose2(rng.uniform(0.6, 1.4), rng.uniform(0.6, 3.4), rng.uniform(-3.0, 3.0))
            odo = factorloc.Odometry(factorloc.Pose2(T.x + 0.04, T.y - 0.03, T.theta + 0.02), 0.05, 0.05, 0.03)
            scan = factorloc.Scan(T.inverse().transform_points(room_points(rng)))
            queries.append(
                ScenarioQuery(factorloc.Query(scan=scan, odometry=odo, id=f"q{i}"), float(i), T, ("blur",) if i == 1 else ())
            )
        return Scenario("room", (ScenarioReference("ref0", ref),), tuple(queries))

    return make

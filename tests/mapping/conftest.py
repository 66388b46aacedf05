"""Fixtures of the mapping tests: a simulated run with a known ground truth and its map."""

from __future__ import annotations

import numpy as np
import pytest

from factorloc.geometry import Pose2
from factorloc.mapping import MapConfig, MapResult, build_map
from factorloc.sim.laser import simulate_laser_log
from factorloc.sim.motion import random_walk
from factorloc.sim.world import apartment


@pytest.fixture(scope="session")
def sim_run():
    """A 20 m random walk through the apartment (it comes back to rooms it saw), 360-beam scans without the
    scanner's unobservable per-scan pose error, 5 % odometry drift."""
    rng = np.random.default_rng(0)
    traj = random_walk(apartment(), Pose2(2.6, 2.2, 0.0), 20.0, rng)
    log, true = simulate_laser_log(apartment(), traj, rng, scan_every=3, pose_sigma_m=0.0, pose_sigma_rad=0.0)
    return log, true


@pytest.fixture(scope="session")
def sim_map(sim_run) -> MapResult:
    log, _ = sim_run
    return build_map(log, MapConfig())

"""Markov grid localization: the predict step moves the belief by the odometry motion, the
correct step finds the measured cell, tracking is bounded by the cell size, a kidnapped
robot is found again, and the cost grows with the number of cells."""

from __future__ import annotations

import math

import numpy as np
import pytest
from synthetic_trajectories import BOUNDS, position_errors

from factorloc.baselines import MarkovGridLocalization
from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.types import Estimate


def _run(strategy, syn):
    strategy.reset()
    return [strategy.update(q, r) for q, r in zip(syn.queries, syn.reports, strict=True)]


def test_correct_then_predict_moves_the_mode_by_the_motion() -> None:
    grid = MarkovGridLocalization(BOUNDS, resolution_m=0.1, n_theta=36)
    grid.belief = grid._uniform()
    grid.correct([Estimate.pose("icp", Pose2(2.05, 2.05, math.pi / 2 - math.pi / 36), 0.02, 0.02, 0.02)])
    before, _ = grid.estimate()
    assert np.allclose(before[:2], [2.05, 2.05], atol=0.03)
    grid.predict(Pose2(1.0, 0.0, 0.0))  # 1 m forward at heading 85° (a bin centre)
    after, _ = grid.estimate()
    assert after[0] == pytest.approx(before[0] + math.cos(math.radians(85.0)), abs=0.02)
    assert after[1] == pytest.approx(before[1] + math.sin(math.radians(85.0)), abs=0.02)
    assert after[2] == pytest.approx(before[2], abs=0.02)


def test_tracking_error_is_bounded_by_the_cell_size(synthetic) -> None:
    syn = synthetic(30, seed=1)
    fused = _run(MarkovGridLocalization(BOUNDS, resolution_m=0.1, n_theta=72), syn)
    err = position_errors([f.pose for f in fused], syn.truths)
    assert err.max() < 0.1
    assert np.sqrt(np.mean(err**2)) < 0.05


def test_kidnapped_robot_is_found_again(synthetic) -> None:
    syn = synthetic(30, seed=2, kidnap_at=15)
    fused = _run(MarkovGridLocalization(BOUNDS, resolution_m=0.1, n_theta=72), syn)
    err = position_errors([f.pose for f in fused], syn.truths)
    assert err[20:].max() < 0.1


def test_cells_grow_with_the_cube_of_resolution() -> None:
    coarse = MarkovGridLocalization(BOUNDS, resolution_m=0.2, n_theta=36)
    fine = MarkovGridLocalization(BOUNDS, resolution_m=0.1, n_theta=72)
    assert fine.n_cells == 8 * coarse.n_cells


def test_bad_grid_is_refused() -> None:
    with pytest.raises(InputError, match="resolution_m"):
        MarkovGridLocalization(BOUNDS, resolution_m=0.0)
    with pytest.raises(InputError, match="bounds_xy"):
        MarkovGridLocalization((0.0, 0.0, 0.0, 1.0))


def test_heading_only_evidence_leaves_position_undetermined(synthetic) -> None:
    from factorloc.types import Component

    syn = synthetic(2, seed=6, no_odometry=True)
    grid = MarkovGridLocalization(BOUNDS, resolution_m=0.2, n_theta=36)
    grid.reset()
    fused = grid.update(syn.queries[0], tuple(r for r in syn.reports[0] if r.name == "compass"))
    assert fused.undetermined == (Component.X, Component.Y)
    assert abs((fused.pose.theta - syn.truths[0].theta + np.pi) % (2 * np.pi) - np.pi) < math.radians(10.0)

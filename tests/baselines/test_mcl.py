"""Monte Carlo localization against ground truth: tracking, kidnapped-robot recovery by
random particles, global localization from a uniform start, low-variance resampling, reproducibility."""

from __future__ import annotations

import numpy as np
import pytest
from synthetic_trajectories import BOUNDS, position_errors

from factorloc.baselines import MonteCarloLocalization
from factorloc.baselines.mcl import low_variance_resample, weighted_mean_covariance
from factorloc.errors import InputError


def _run(strategy, syn):
    strategy.reset()
    return [strategy.update(q, r) for q, r in zip(syn.queries, syn.reports, strict=True)]


def test_mcl_tracks_the_trajectory(synthetic) -> None:
    syn = synthetic(30, seed=1, no_icp=(10, 18))
    fused = _run(MonteCarloLocalization(1000, BOUNDS, seed=0), syn)
    err = position_errors([f.pose for f in fused], syn.truths)
    assert np.sqrt(np.mean(err**2)) < 0.05
    heading = np.abs([(f.pose.theta - t.theta + np.pi) % (2 * np.pi) - np.pi for f, t in zip(fused, syn.truths, strict=True)])
    assert heading.max() < np.radians(2.0)


def test_random_particles_recover_a_kidnapped_robot(synthetic) -> None:
    syn = synthetic(30, seed=2, kidnap_at=15)
    mcl = MonteCarloLocalization(1000, BOUNDS, seed=0)
    fused = _run(mcl, syn)
    err = position_errors([f.pose for f in fused], syn.truths)
    assert mcl.injected > 0
    assert err[16:].max() < 0.05  # found again by the next query


def test_global_localization_from_a_uniform_start(synthetic) -> None:
    syn = synthetic(10, seed=4, no_odometry=True)
    fused = _run(MonteCarloLocalization(2000, BOUNDS, seed=1), syn)
    err = position_errors([f.pose for f in fused], syn.truths)
    assert err.max() < 0.05


def test_same_seed_same_answer_other_seed_other_answer(synthetic) -> None:
    syn = synthetic(12, seed=5, no_icp=(3, 9))
    a = [f.pose.as_array() for f in _run(MonteCarloLocalization(500, BOUNDS, seed=3), syn)]
    b = [f.pose.as_array() for f in _run(MonteCarloLocalization(500, BOUNDS, seed=3), syn)]
    c = [f.pose.as_array() for f in _run(MonteCarloLocalization(500, BOUNDS, seed=4), syn)]
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)


def test_low_variance_resampling_keeps_counts_proportional_to_weights() -> None:
    w = np.array([0.5, 0.25, 0.125, 0.125])
    idx = low_variance_resample(np.repeat(w, 250) / 250, np.random.default_rng(0))
    counts = np.bincount(idx // 250, minlength=4)
    assert np.all(np.abs(counts - 1000 * w) <= 1)


def test_weighted_mean_is_circular_in_heading() -> None:
    p = np.array([[0.0, 0.0, np.pi - 0.1], [2.0, 0.0, -np.pi + 0.1]])
    mean, cov = weighted_mean_covariance(p, np.array([0.5, 0.5]))
    assert mean[0] == pytest.approx(1.0)
    assert abs(abs(mean[2]) - np.pi) < 1e-12
    assert cov[2, 2] == pytest.approx(0.01)


def test_bad_parameters_are_refused() -> None:
    with pytest.raises(InputError, match="n_particles"):
        MonteCarloLocalization(3)
    with pytest.raises(InputError, match="bounds_xy"):
        MonteCarloLocalization(100, (1.0, 0.0, 0.0, 1.0))


def test_a_belief_spread_over_the_map_reports_position_undetermined(synthetic) -> None:
    from factorloc.types import Component, StepReport

    syn = synthetic(3, seed=6, no_odometry=True)
    heading_only = [tuple(r for r in reps if r.name == "compass") for reps in syn.reports]
    assert all(isinstance(r, StepReport) for reps in heading_only for r in reps)
    mcl = MonteCarloLocalization(1000, BOUNDS, seed=0)
    mcl.reset()
    fused = mcl.update(syn.queries[0], heading_only[0])
    assert fused.undetermined == (Component.X, Component.Y)
    assert abs((fused.pose.theta - syn.truths[0].theta + np.pi) % (2 * np.pi) - np.pi) < 0.05

"""The odometry noise model and its fit for an honest 3σ tail: synthetic logs with known noise, and the real laser logs."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import pytest

import factorloc as fl
from factorloc.datasets.rosbag import OdometryTrack
from factorloc.errors import InputError
from factorloc.odometry_model import (
    CHI2_3SIGMA_2DOF,
    GAUSSIAN_3SIGMA_TAIL,
    OdometryModel,
    assess_odometry_model,
    fit_odometry_model,
    odometry_residuals,
)


@dataclass
class _Rel:
    t1_s: np.ndarray
    t2_s: np.ndarray
    poses: np.ndarray


@dataclass
class _Log:
    odometry: OdometryTrack
    source: str = ""


def _synthetic(seed: int, n: int = 4000, k: float = 0.1, floor: float = 0.02, kh: float = 0.05, kd: float = 0.03):
    """A straight odometry track and relations whose truth differs from it by Gaussian noise of a known model."""
    rng = np.random.default_rng(seed)
    t = np.arange(2 * n, dtype=float)
    x = np.cumsum(rng.uniform(0.0, 0.5, 2 * n))
    th = np.cumsum(rng.normal(0.0, 0.2, 2 * n))
    track = OdometryTrack(t, np.column_stack([x, np.zeros_like(x), th]))
    t1 = t[0::2]
    t2 = t1 + 1
    poses = []
    for a, b in zip(t1, t2, strict=True):
        seed_pose = track.between(a, b)
        d, r = track.distance_between(a, b)
        s, st = max(floor, k * d), max(1e-3, kh * r + kd * d)
        poses.append([seed_pose.x - rng.normal(0, s), seed_pose.y - rng.normal(0, s), seed_pose.theta - rng.normal(0, st)])
    return _Log(track, f"synthetic{seed}"), _Rel(t1, t2, np.array(poses))


def test_the_3sigma_quantiles_are_the_gates() -> None:
    from factorloc.stats import chi2_quantile

    assert CHI2_3SIGMA_2DOF == pytest.approx(chi2_quantile(1.0 - GAUSSIAN_3SIGMA_TAIL, 2), rel=1e-12)
    assert GAUSSIAN_3SIGMA_TAIL == pytest.approx(1.0 - 0.9973002039367398, rel=1e-9)


def test_the_model_is_what_odometry_from_distance_computes() -> None:
    m = OdometryModel(0.1, 0.02, 0.05, 0.03, 0.004)
    odo = m.odometry(fl.Pose2(1, 2, 0.3), 2.0, 1.0)
    assert odo.sigma_x_m == pytest.approx(m.sigma_position_m(2.0)) == pytest.approx(0.2)
    assert odo.sigma_theta_rad == pytest.approx(m.sigma_heading_rad(2.0, 1.0)) == pytest.approx(0.11)
    assert OdometryModel.from_dict(m.to_dict()) == m and fl.OdometryModel is OdometryModel
    with pytest.raises(InputError, match="unknown odometry model key"):
        OdometryModel.from_dict({"drift": 0.1})
    with pytest.raises(InputError, match="min_sigma_m must be > 0"):
        OdometryModel(min_sigma_m=0.0)


def test_a_fit_on_gaussian_odometry_recovers_its_tail_on_held_out_data() -> None:
    train, held = _synthetic(1), _synthetic(2)
    model = fit_odometry_model(*train)
    on_train = assess_odometry_model(model, odometry_residuals(*train))
    on_held = assess_odometry_model(model, odometry_residuals(*held))
    # by construction at most ⌊0.27 %·N⌋ of the training relations lie beyond 3σ
    assert on_train.tail_position <= GAUSSIAN_3SIGMA_TAIL and on_train.tail_heading <= GAUSSIAN_3SIGMA_TAIL
    # held out: the Gaussian's 0.27 % within binomial noise (4000 relations: 10.8 expected), NEES near its dof
    assert on_held.tail_position < 0.008 and on_held.tail_heading < 0.008
    assert 1.2 < on_held.nees_position < 2.6 and 0.6 < on_held.nees_heading < 1.3
    # the slopes come back near the truth (the floors trade with them at small paths)
    assert model.drift_ratio == pytest.approx(0.1, rel=0.3) and model.heading_drift_ratio == pytest.approx(0.05, rel=0.5)


def test_each_log_must_meet_the_tail_on_its_own() -> None:
    calm, rough = _synthetic(3, n=1500, k=0.05), _synthetic(4, n=1500, k=0.2)
    both = fit_odometry_model([calm[0], rough[0]], [calm[1], rough[1]])
    assert assess_odometry_model(both, odometry_residuals(*rough)).tail_position <= GAUSSIAN_3SIGMA_TAIL
    assert both.drift_ratio > fit_odometry_model(*calm).drift_ratio
    with pytest.raises(InputError, match="as many relations as logs"):
        fit_odometry_model([calm[0]], [calm[1], rough[1]])


@pytest.mark.slow
def test_on_the_real_logs_each_fold_keeps_its_training_tails_and_the_patent_example_is_far_off(shared_data: Path) -> None:
    from factorloc.datasets.rosbag import read_laser_log
    from factorloc.evaluation.relations import read_relations

    names = ("intel", "aces", "mit-csail")
    logs = {n: read_laser_log(shared_data / "laser" / f"{n}.sort.bag") for n in names}
    rels = {n: read_relations(shared_data / "laser" / f"{n}.relations") for n in names}
    res = {n: odometry_residuals(logs[n], rels[n], source=n) for n in names}
    patent = OdometryModel(0.05, 1e-3, 0.05, 0.02, 1e-3)  # Odometry.from_distance's defaults, the patent's 5 %
    for held in names:
        train = [n for n in names if n != held]
        model = fit_odometry_model([logs[n] for n in train], [rels[n] for n in train])
        for n in train:
            a = assess_odometry_model(model, res[n])
            assert a.tail_position <= GAUSSIAN_3SIGMA_TAIL and a.tail_heading <= GAUSSIAN_3SIGMA_TAIL
        # held out, the position tail stays within 4× the Gaussian's (docs/calibration/odometry.md has the table)
        assert assess_odometry_model(model, res[held]).tail_position < 4 * GAUSSIAN_3SIGMA_TAIL
    for n in names:  # the 5 % example: a quarter of the positions beyond 3σ
        assert assess_odometry_model(patent, res[n]).tail_position > 0.2

"""relations_lattice: relations made by a grid matcher around the odometry are found, others are not."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from factorloc.datasets.rosbag import OdometryTrack
from factorloc.errors import InputError
from factorloc.evaluation.relations import Relations
from factorloc.evaluation.relations_lattice import (
    SQUARE_MEAN_DISTANCE,
    TruthRounding,
    find_heading_grid,
    find_relations_grid,
    heading_lattice,
    relations_lattice,
    truth_rounding,
)
from factorloc.geometry import Pose2


def _odometry(n: int = 400) -> OdometryTrack:
    rng = np.random.default_rng(3)
    t = np.arange(n) * 0.2
    th = np.cumsum(rng.normal(0.0, 0.05, n))
    xy = np.cumsum(0.1 * np.stack([np.cos(th), np.sin(th)], 1), 0)
    return OdometryTrack(t, np.column_stack([xy, th]))


def _relations(odom: OdometryTrack, offset, turn=lambda k: 0.01) -> Relations:  # noqa: ANN001 - (k) -> (dx, dy), (k) -> dθ
    t1 = odom.stamps_s[:-3]
    t2 = odom.stamps_s[3:]
    poses = []
    for k, (a, b) in enumerate(zip(t1, t2, strict=True)):
        D = odom.between(float(a), float(b))
        dx, dy = offset(k)
        poses.append([D.x + dx, D.y + dy, D.theta + turn(k)])
    return Relations(t1, t2, np.array(poses))


def test_a_grid_matchers_relations_are_on_the_lattice_with_the_square_floor() -> None:
    odom = _odometry()
    rng = np.random.default_rng(4)
    steps = rng.integers(-2, 3, (len(odom), 2))
    angle = rng.uniform(0, 2 * math.pi, len(odom))  # the grid laid in any frame: only the norm is tested

    def on_grid(k: int) -> tuple[float, float]:
        v = 0.05 * steps[k]
        c, s = math.cos(angle[k]), math.sin(angle[k])
        return c * v[0] - s * v[1], s * v[0] + c * v[1]

    lat = relations_lattice(_relations(odom, on_grid), odom)
    assert lat.rate == 1.0 and lat.chance_rate < 0.1
    assert lat.floor_mean_error_m == pytest.approx(SQUARE_MEAN_DISTANCE * 0.05 * lat.grid_share, rel=1e-12)
    assert 0.018 < lat.floor_mean_error_m <= 0.0192
    assert "grid steps" in lat.summary()
    # the step is found among the candidates: the largest whose grid holds (nearly) as many as the best
    found = find_relations_grid(_relations(odom, on_grid), odom)
    assert found is not None and found.step_m == 0.05


def test_relations_with_continuous_errors_are_at_chance() -> None:
    odom = _odometry()
    rng = np.random.default_rng(5)
    noise = rng.normal(0.0, 0.02, (len(odom), 2))
    lat = relations_lattice(_relations(odom, lambda k: tuple(noise[k])), odom)
    assert abs(lat.rate - lat.chance_rate) < 0.05 and lat.grid_share < 0.05
    assert lat.floor_mean_error_m < 0.001
    assert find_relations_grid(_relations(odom, lambda k: tuple(noise[k])), odom) is None


def test_the_square_mean_distance_is_the_monte_carlo_one() -> None:
    u = np.random.default_rng(6).uniform(-0.5, 0.5, (200_000, 2))
    assert float(np.hypot(u[:, 0], u[:, 1]).mean()) == pytest.approx(SQUARE_MEAN_DISTANCE, abs=2e-3)


def test_bad_input_raises() -> None:
    odom = _odometry(20)
    rel = _relations(odom, lambda k: (0.0, 0.0))
    with pytest.raises(InputError, match="step_m"):
        relations_lattice(rel, odom, step_m=float("nan"))
    with pytest.raises(InputError, match="half the step"):
        relations_lattice(rel, odom, step_m=0.05, tolerance_m=0.03)
    with pytest.raises(InputError, match="non-empty"):
        relations_lattice(Relations(np.zeros(0), np.zeros(0), np.zeros((0, 3))), odom)
    with pytest.raises(InputError, match="OdometryTrack"):
        relations_lattice(rel, Pose2(0, 0, 0))  # type: ignore[arg-type]


def test_mit_csails_relations_are_its_odometry_on_a_5_cm_grid(shared_data: Path) -> None:
    from factorloc.datasets.rosbag import read_laser_log
    from factorloc.evaluation.relations import read_relations

    laser = shared_data / "laser"
    mit = relations_lattice(read_relations(laser / "mit-csail.relations"), read_laser_log(laser / "mit-csail.sort.bag").odometry)
    assert mit.rate > 0.85 and mit.chance_rate < 0.05  # measured: 89.1 % (1,044 of 1,172), chance 2.5 %
    assert 0.016 < mit.floor_mean_error_m < 0.018  # 1.70 cm: far above the published 0.4 cm
    intel = relations_lattice(read_relations(laser / "intel.relations"), read_laser_log(laser / "intel.sort.bag").odometry)
    assert intel.grid_share < 0.05  # measured 3.4 % at a chance of 1.5 %: no grid
    found = find_relations_grid(
        read_relations(laser / "mit-csail.relations"), read_laser_log(laser / "mit-csail.sort.bag").odometry
    )
    assert found is not None and found.step_m == 0.05
    mit_rel, mit_odom = read_relations(laser / "mit-csail.relations"), read_laser_log(laser / "mit-csail.sort.bag").odometry
    heading = find_heading_grid(mit_rel, mit_odom)  # its headings too: 1,043 of 1,172 on 0.25° steps
    assert heading is not None and heading.step_rad == pytest.approx(math.radians(0.25)) and heading.rate > 0.85
    assert truth_rounding(mit_rel, mit_odom).rounded().sum() >= 1040


def test_headings_turned_by_whole_matcher_steps_are_found_with_their_offset() -> None:
    odom = _odometry()
    rng = np.random.default_rng(7)
    k = rng.integers(-8, 9, len(odom))
    h, offset = math.radians(0.25), math.radians(0.1)  # MIT CSAIL's: 0.25° steps about a 0.1° offset
    rel = _relations(odom, lambda i: (0.0, 0.0), lambda i: offset + h * k[i])
    lat = heading_lattice(rel, odom, step_rad=h)
    assert lat.rate == 1.0 and lat.offset_rad == pytest.approx(offset, abs=1e-9) and lat.chance_rate < 0.02
    found = find_heading_grid(rel, odom)
    assert found is not None and found.step_rad == pytest.approx(h)
    noise = rng.normal(0.0, math.radians(0.5), len(odom))
    assert find_heading_grid(_relations(odom, lambda i: (0.0, 0.0), lambda i: noise[i]), odom) is None
    with pytest.raises(InputError, match="half the step"):
        heading_lattice(rel, odom, step_rad=5e-5)


def test_the_truths_rounding_is_a_uniform_cells_covariance_on_the_grid_only() -> None:
    odom = _odometry()
    rng = np.random.default_rng(8)
    steps = rng.integers(-2, 3, (len(odom), 2))
    off = rng.normal(0.0, 0.02, (len(odom), 2))
    gridded = np.arange(len(odom)) % 4 != 0  # a quarter made another way (loops, say)
    h = math.radians(0.25)
    turn = np.where(gridded, h * rng.integers(-4, 5, len(odom)), rng.normal(0.0, 0.01, len(odom)))
    rel = _relations(odom, lambda i: tuple(0.05 * steps[i]) if gridded[i] else tuple(off[i]), lambda i: turn[i])
    tr = truth_rounding(rel, odom)
    assert tr.translation is not None and tr.translation.step_m == 0.05
    assert tr.heading is not None and tr.heading.step_rad == pytest.approx(h)
    on = tr.translation.on_lattice & tr.heading.on_lattice
    off_both = ~tr.translation.on_lattice & ~tr.heading.on_lattice
    i_on, i_off = int(np.nonzero(on)[0][0]), int(np.nonzero(off_both)[0][0])
    np.testing.assert_allclose(np.diag(tr.covariance(i_on)), [0.05**2 / 12.0, 0.05**2 / 12.0, h**2 / 12.0], rtol=1e-12)
    np.testing.assert_array_equal(tr.covariance(i_off), np.zeros((3, 3)))
    assert tr.rounded().sum() == pytest.approx(gridded.sum(), abs=0.05 * len(odom))  # chance hits aside
    # a uniform error over the 5 cm cell has that variance
    u = np.random.default_rng(9).uniform(-0.025, 0.025, 400_000)
    assert float(u.var()) == pytest.approx(0.05**2 / 12.0, rel=0.01)
    assert "5 cm grid" in tr.summary()
    assert TruthRounding.none().rounded().size == 0 and "exact" in TruthRounding.none().summary()

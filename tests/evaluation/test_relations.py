"""The relations benchmark on fixed subsets of the Intel and ACES logs: ours against odometry and Open3D on the
same pairs and seeds (the full table comes from ``benchmarks/bench_icp.py``)."""

from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np
import pytest

from factorloc.datasets.rosbag import read_laser_log
from factorloc.errors import DatasetError, InputError
from factorloc.estimators.base import Hypotheses
from factorloc.estimators.icp import IcpConfig, IcpReference, estimate
from factorloc.evaluation.relations import (
    METHODS,
    RelationResult,
    Relations,
    format_table,
    read_relations,
    relations_benchmark,
    relations_config,
    summarize,
    unrecovered_breakdown,
)
from factorloc.geometry import Pose2


@pytest.fixture(scope="module")
def laser_dir(shared_data: Path) -> Path:
    return shared_data / "laser"


def _rows(laser_dir: Path, name: str, every_local: int, every_loop: int) -> list[dict]:
    """Every ``every_local``-th local relation and every ``every_loop``-th loop relation (loops are slow)."""
    log = read_laser_log(laser_dir / f"{name}.sort.bag")
    rel = read_relations(laser_dir / f"{name}.relations")
    path = np.array([log.odometry.distance_between(a, b)[0] for a, b in zip(rel.t1_s, rel.t2_s, strict=True)])
    idx = np.concatenate([np.nonzero(path < 5.0)[0][::every_local], np.nonzero(path >= 5.0)[0][::every_loop]])
    sub = Relations(rel.t1_s[idx], rel.t2_s[idx], rel.poses[idx])
    return summarize(relations_benchmark(log, sub), name)


def _get(rows: list[dict], method: str, subset: str) -> dict:
    return next(r for r in rows if r["method"] == method and r["subset"] == subset)


@pytest.fixture(scope="module")
def intel(laser_dir: Path) -> list[dict]:
    return _rows(laser_dir, "intel", 15, 60)


@pytest.fixture(scope="module")
def aces(laser_dir: Path) -> list[dict]:
    return _rows(laser_dir, "aces", 12, 30)


pytestmark = pytest.mark.slow  # ~30 s: real scans, 139 Intel, 102 ACES and 113 MIT CSAIL relations, 32 of them loops


def test_table_has_every_method_and_subset(intel: list[dict]) -> None:
    assert {(r["method"], r["subset"]) for r in intel} == {(m, s) for m in METHODS for s in ("local", "loop", "all")}
    text = format_table(intel)
    for m in METHODS:
        assert m in text


@pytest.mark.parametrize("dataset", ["intel", "aces"])
def test_local_relations_beat_open3d_point_to_plane(dataset: str, request: pytest.FixtureRequest) -> None:
    rows = request.getfixturevalue(dataset)
    ours, peer, odom = _get(rows, "ours", "local"), _get(rows, "open3d_p2plane", "local"), _get(rows, "odometry", "local")
    icp = _get(rows, "ours_icp", "local")
    assert ours["trans_mean_cm"] < 0.8 * peer["trans_mean_cm"]  # the issue's target: at least 20 % below
    assert icp["rot_mean_deg"] < 0.4
    assert icp["recovered_rate"] > 0.9  # the ICP estimate itself within 10 cm and 1°
    assert ours["trans_mean_cm"] < (0.6 if dataset == "intel" else 1.1) * odom["trans_mean_cm"]  # ACES' odometry is good locally
    assert ours["rot_mean_deg"] < 0.45
    assert ours["reliable_rate"] > 0.95


def test_loop_relations_are_recovered_by_global_initialization_or_flagged(intel: list[dict]) -> None:
    ours, icp, peer = _get(intel, "ours", "loop"), _get(intel, "ours_icp", "loop"), _get(intel, "open3d_p2plane", "loop")
    assert peer["recovered_rate"] < 0.05  # trusting the odometry seed fails on loops
    assert icp["recovered_rate"] > 0.7
    assert ours["unrecovered_flagged_rate"] > 0.8
    assert ours["confidently_wrong_rate"] < 0.06


def test_icp_covariance_on_local_relations_is_cautious_but_not_blind(intel: list[dict], aces: list[dict]) -> None:
    # the 7.5 mm floor was chosen on the worst held-out fold (with the simulator: a smaller one is confidently wrong
    # there): on Intel and ACES the position NEES is ~0.6-0.8 (docs/calibration/icp.md, the fold table)
    for rows in (intel, aces):
        icp = _get(rows, "ours_icp", "local")
        assert 0.2 < icp["nees_icp_mean"] < 2.0
        assert icp["confidently_wrong_rate"] < 0.02


@pytest.fixture(scope="module")
def mit(laser_dir: Path) -> list[dict]:
    return _rows(laser_dir, "mit-csail", 10, 16)


def test_the_log_held_out_by_the_issue_is_honest_on_its_local_relations(mit: list[dict]) -> None:
    # MIT CSAIL (360 beams at 0.5°, never used to set the rules before issue 14): before the floor the fused result was
    # confidently wrong on 4 % of its local relations and the ICP NEES 2.8; on all of them now 0.29 % and 1.25, judged
    # with its relations' rounding to a 5 cm / 0.25° grid (1.19 % and 1.93 against the relations taken as exact)
    ours, icp, peer = _get(mit, "ours", "local"), _get(mit, "ours_icp", "local"), _get(mit, "open3d_p2plane", "local")
    assert ours["confidently_wrong_rate"] < 0.03
    assert 1.0 < icp["nees_icp_mean"] < 3.5
    assert ours["trans_mean_cm"] < 0.85 * peer["trans_mean_cm"]


def _failed(est) -> list[str]:  # noqa: ANN001 - an Estimate
    return [c.code for c in est.checks if not c.passed]


@functools.lru_cache(maxsize=2)
def _log(path: Path):
    return read_laser_log(path)


def _loop_estimate(laser_dir: Path, name: str, index: int):
    """The ICP step alone on relation ``index`` without any hypothesis (a loop: the odometry is metres off)."""
    log, rel = _log(laser_dir / f"{name}.sort.bag"), read_relations(laser_dir / f"{name}.relations")
    t1, t2 = float(rel.t1_s[index]), float(rel.t2_s[index])
    assert log.odometry.distance_between(t1, t2)[0] > 5.0  # a loop relation
    cfg = relations_config().icp
    prep = IcpReference(log.scans.at(t1, 2e-3).points_m, Pose2(0.0, 0.0, 0.0), cfg)
    est = estimate(prep, log.scans.at(t2, 2e-3).points_m, Hypotheses(), cfg)
    err = Pose2.from_array(rel.poses[index]).between(Pose2.from_array(est.values))
    return est, math.hypot(err.x, err.y), abs(math.degrees(err.theta))


@pytest.mark.parametrize(
    ("index", "why"),
    [
        (1948, "a corridor (constraint below the degeneracy threshold) whose few features decide: rivals < 0.7 x"),
        (2035, "turned by 104°: the 180° scans overlap on a third of their points (score < 0.4), rivals < 0.5 x"),
    ],
)
def test_intel_loop_closures_recovered_by_global_initialization(laser_dir: Path, index: int, why: str) -> None:
    est, err_m, err_deg = _loop_estimate(laser_dir, "intel", index)
    assert est.diagnostics["used_global_init"]
    assert est.reliable, why
    assert err_m < 0.10 and err_deg < 1.0
    if index == 1948:
        assert est.diagnostics["constraint"] < IcpConfig().reliability.min_constraint
    else:
        assert est.diagnostics["global_score"] < IcpConfig().reliability.min_score
        # the points each sensor could see fit: the low fitness is the 180° field of view, not a misfit
        assert est.diagnostics["overlap_fitness"] > 0.9 > 2 * est.diagnostics["fitness"]
        assert est.diagnostics["overlap_points"] >= 30


@pytest.mark.parametrize(
    ("index", "why"),
    [
        (2833, "turned by 86°: score 0.21, fitness 0.21 < min_fitness, but 95 % of the shared view fits; rivals < 0.5 x"),
        (2711, "turned by 92°: score 0.39; a rival at 0.71 x explains its own overlap worse (0.87 vs 1.00)"),
    ],
)
def test_intel_loop_closures_accepted_on_their_overlap_fitness(laser_dir: Path, index: int, why: str) -> None:
    est, err_m, err_deg = _loop_estimate(laser_dir, "intel", index)
    cfg = IcpConfig()
    assert est.reliable, why
    assert err_m < 0.10 and err_deg < 1.0
    d = est.diagnostics
    assert d["global_score"] < cfg.reliability.min_score  # the plain score test would reject it
    assert d["overlap_fitness"] >= cfg.global_init.overlap_min_fitness
    assert d["rival_score"] < cfg.global_init.overlap_rival_ratio * d["global_score"]


@pytest.mark.parametrize(
    ("name", "index"),
    [("intel", 2381), ("intel", 2343), ("aces", 1254)],
)
def test_loop_solutions_with_a_comparable_rival_and_a_poor_overlap_are_flagged(laser_dir: Path, name: str, index: int) -> None:
    # reliable before the overlap test, and wrong: 0.9 m / 0.5 m off (Intel), a 180° flip (ACES); a distinct rival
    # scores 0.78-0.81 x and only 76-85 % of what both sensors could see fits
    est, err_m, err_deg = _loop_estimate(laser_dir, name, index)
    cfg = IcpConfig()
    assert err_m > 0.4
    assert not est.reliable
    assert "icp.global.overlap" in _failed(est)
    assert est.diagnostics["rival_score"] >= cfg.global_init.ambiguity_overlap_ratio * est.diagnostics["global_score"]
    assert est.diagnostics["overlap_fitness"] < cfg.global_init.overlap_min_fitness


def test_a_low_score_solution_is_not_accepted_when_its_rival_explains_the_overlap_as_well(laser_dir: Path) -> None:
    # Intel local relation 675 with an unreliable odometry heading (no seed at all): the best global solution is 2 m
    # off along a corridor; the rival (the truth) scores 0.58 x with the same overlap fitness (0.96 vs 0.98)
    log, rel = _log(laser_dir / "intel.sort.bag"), read_relations(laser_dir / "intel.relations")
    t1, t2 = float(rel.t1_s[675]), float(rel.t2_s[675])
    cfg = relations_config().icp
    prep = IcpReference(log.scans.at(t1, 2e-3).points_m, Pose2(0.0, 0.0, 0.0), cfg)
    est = estimate(prep, log.scans.at(t2, 2e-3).points_m, Hypotheses(), cfg)
    err = Pose2.from_array(rel.poses[675]).between(Pose2.from_array(est.values))
    d = est.diagnostics
    assert math.hypot(err.x, err.y) > 1.5
    assert d["overlap_fitness"] >= cfg.global_init.overlap_min_fitness  # the overlap alone would accept it
    assert d["rival_overlap_fitness"] > d["overlap_fitness"] - cfg.global_init.overlap_rival_margin
    assert not est.reliable and "icp.score" in _failed(est)


@pytest.mark.parametrize("index", [1242, 1223])
def test_aces_corridor_loops_with_a_near_twin_are_flagged(laser_dir: Path, index: int) -> None:
    # ACES corridors: the global solution is the corridor's 180° twin, metres off; its rivals score nearly as well
    est, err_m, err_deg = _loop_estimate(laser_dir, "aces", index)
    assert err_m > 0.5 and err_deg > 170.0
    assert not est.reliable
    assert "icp.constraint" in _failed(est)


def test_relations_reader_and_subset_reject_bad_input(tmp_path: Path) -> None:
    p = tmp_path / "r.relations"
    p.write_text("1.0 2.0 0.1 0.2 0 0 0 0.3\n3.0 4.0 0.5 0.6 0 0 0 -0.1\n")
    rel = read_relations(p)
    assert isinstance(rel, Relations)
    np.testing.assert_allclose(rel.poses, [[0.1, 0.2, 0.3], [0.5, 0.6, -0.1]])
    assert len(rel.subset(2)) == 1
    with pytest.raises(InputError, match="every"):
        rel.subset(0)
    p.write_text("1 2 3\n")
    with pytest.raises(DatasetError, match="8 columns"):
        read_relations(p)


def test_relations_config_changes_only_the_odometry_limits() -> None:
    # real laser scans get the library's own ICP default (bias_rmse_ratio 0.75): no override for the logs
    from factorloc.config import Config

    cfg, base = relations_config(), Config()
    assert cfg.icp == base.icp and cfg.icp.covariance.bias_rmse_ratio == 0.75
    assert (cfg.odometry.max_sigma_position_m, cfg.odometry.max_sigma_heading_rad) == (1.0, 0.55)


def test_unrecovered_breakdown_names_why_each_relation_was_missed() -> None:
    def res(et: float, er: float, reliable: bool, icp_et: float, icp_er: float, icp_reliable: bool, failed: str, kind="loop"):
        diag = {
            "icp_error_translation_m": icp_et,
            "icp_error_rotation_deg": icp_er,
            "icp_reliable": icp_reliable,
            "icp_failed_checks": tuple(failed.split()),
        }
        return RelationResult("ours", 0, kind, et, er, reliable, False, 0.0, diagnostics=diag)

    results = [
        res(0.02, 0.3, True, 0.02, 0.3, True, ""),  # recovered
        # ICP right but unreliable: its first failed check counts
        res(13.0, 30.0, False, 0.01, 0.4, False, "icp.global.ambiguity"),
        res(13.0, 30.0, False, 0.03, 0.2, False, "icp.constraint icp.score"),
        res(9.0, 90.0, False, 0.01, 0.2, False, "icp.score"),
        res(0.3, 5.0, True, 0.02, 0.2, True, ""),  # right and reliable, not returned: gated
        res(4.0, 89.0, False, 4.0, 89.0, False, "icp.global.ambiguity"),  # wrong, flagged
        res(0.03, 1.2, True, 0.03, 1.2, True, ""),  # reliable, 1.2° off: near
        res(1.78, 179.8, True, 1.78, 179.8, True, ""),  # reliable 180° flip: wrong
        res(0.5, 3.0, False, 0.5, 3.0, False, "icp.score", kind="local"),  # another subset
    ]
    b = unrecovered_breakdown(results, "loop")
    assert b == {
        "n": 8,
        "recovered": 1,
        "icp_correct_rejected: icp.global.ambiguity": 1,
        "icp_correct_rejected: icp.constraint": 1,
        "icp_correct_rejected: icp.score": 1,
        "icp_correct_gated": 1,
        "icp_wrong_flagged": 1,
        "not_flagged_near": 1,
        "not_flagged_wrong": 1,
    }
    assert unrecovered_breakdown(results, "all")["n"] == 9


def test_a_position_only_icp_estimate_is_scored_on_its_position(laser_dir: Path) -> None:
    """ACES with its scans cut at 5.6 m (a short-range laser's reach): on relations 821, 1214 and 1256 the ICP step
    finds the heading unconstrained and emits a position-only estimate (2×2 covariance). The benchmark used to
    fail on them (IndexError on the heading variance); they are now scored on their position, the heading not
    judged."""
    import dataclasses

    from factorloc.datasets.rosbag import ScanTrack
    from factorloc.evaluation.relations import Relations, relations_benchmark
    from factorloc.types import Scan

    log = _log(laser_dir / "aces.sort.bag")
    cut = tuple(Scan(s.points_m[np.hypot(*s.points_m.T) < 5.6]) for s in log.scans.scans)
    log = dataclasses.replace(log, scans=ScanTrack(log.scans.stamps_s, cut, log.scans.frame_id))
    rel = read_relations(laser_dir / "aces.relations")
    sel = [821, 1214, 1256]
    rows = relations_benchmark(log, Relations(rel.t1_s[sel], rel.t2_s[sel], rel.poses[sel]), methods=("ours", "ours_icp"))
    icp = [r for r in rows if r.method == "ours_icp"]
    assert [r.index for r in icp] == [0, 1, 2]
    position_only = [r for r in icp if math.isinf(r.diagnostics["icp_sigma_theta_rad"])]
    assert position_only, "the ICP step gave a full pose on every one: the case this test is about is gone"
    # measured: position errors 18 / 3 / 18 cm at position NEES 0.39 / 0.24 / 2.1: within their 3σ
    assert all(math.isfinite(r.nees_position) and not r.confidently_wrong for r in position_only)

"""Sweeps: dotted overrides of the config, the grid file, a run over a scenario and two laser logs."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

from factorloc.cli import app
from factorloc.config import Config
from factorloc.datasets import save_scenario
from factorloc.errors import ConfigError
from factorloc.evaluation import evaluate
from factorloc.evaluation.folds import fold_figures
from factorloc.evaluation.relations import read_relations, relations_benchmark, relations_config
from factorloc.evaluation.sweep import Setting, SweepSpec, apply_overrides, format_sweep, grid_settings, run_sweep


def test_overrides_replace_the_named_field_and_reject_unknown_keys() -> None:
    cfg = apply_overrides(Config(), {"icp.covariance.sigma_floor_m": 0.02, "fusion.strategy": "product"})
    assert cfg.icp.covariance.sigma_floor_m == 0.02 and cfg.fusion.strategy == "product"
    assert cfg.icp.covariance.bias_rmse_ratio == Config().icp.covariance.bias_rmse_ratio
    assert apply_overrides(Config(), {}) == Config()
    with pytest.raises(ConfigError, match="no field 'icp.covariance.floor_m'"):
        apply_overrides(Config(), {"icp.covariance.floor_m": 0.02})
    with pytest.raises(ConfigError, match="group of fields"):
        apply_overrides(Config(), {"icp.covariance": 1})
    with pytest.raises(ConfigError, match="fusion.strategy"):
        apply_overrides(Config(), {"fusion.strategy": "median"})


def test_a_grid_is_every_combination_named_by_its_leaves() -> None:
    s = grid_settings({"icp.covariance.sigma_floor_m": [0.0075, 0.01], "icp.covariance.bias_rmse_ratio": [0.5, 0.75]})
    assert [x.name for x in s] == [
        "sigma_floor_m=0.0075,bias_rmse_ratio=0.5",
        "sigma_floor_m=0.0075,bias_rmse_ratio=0.75",
        "sigma_floor_m=0.01,bias_rmse_ratio=0.5",
        "sigma_floor_m=0.01,bias_rmse_ratio=0.75",
    ]
    assert s[1].overrides == {"icp.covariance.sigma_floor_m": 0.0075, "icp.covariance.bias_rmse_ratio": 0.75}
    with pytest.raises(ConfigError, match="non-empty list"):
        grid_settings({"fusion.strategy": "graph"})


def test_a_sweep_file_is_checked_before_anything_runs(tmp_path: Path) -> None:
    (tmp_path / "g.yaml").write_text("grid:\n  icp.nope: [1, 2]\nscenarios: [s]\n")
    with pytest.raises(ConfigError, match="no field 'icp.nope'"):
        SweepSpec.from_yaml(tmp_path / "g.yaml")
    (tmp_path / "g.yaml").write_text("settings:\n  - name: a\nscenarios: [s]\nextra: 1\n")
    with pytest.raises(ConfigError, match="unknown keys"):
        SweepSpec.from_yaml(tmp_path / "g.yaml")
    with pytest.raises(ConfigError, match="scenarios: or laser:"):
        SweepSpec((Setting("a"),))


def test_a_sweep_over_a_scenario_matches_evaluate_with_each_setting(tmp_path: Path, make_room_scenario: Any) -> None:
    scen = make_room_scenario(4, 5)
    save_scenario(scen, tmp_path / "room")
    (tmp_path / "grid.yaml").write_text("grid:\n  fusion.strategy: [graph, product]\nscenarios: [room]\n")
    results = run_sweep(SweepSpec.from_yaml(tmp_path / "grid.yaml"))
    assert [r.setting.name for r in results] == ["strategy=graph", "strategy=product"]
    for r, strategy in zip(results, ("graph", "product"), strict=True):
        direct = evaluate(scen, config=apply_overrides(Config(), {"fusion.strategy": strategy})).to_json()
        got = r.to_json()["scenarios"]["room"]
        assert got["strategy"] == strategy and got["position_rmse_m"] == direct["position_rmse_m"]
        assert got["nees_mean"] == direct["nees_mean"] and got["failed_queries"] == 0
    assert "strategy=product" in format_sweep(results)
    out = CliRunner().invoke(app, ["sweep", str(tmp_path / "grid.yaml"), "--out", str(tmp_path / "out")])
    assert out.exit_code == 0, out.output
    written = json.loads((tmp_path / "out" / "strategy=product.json").read_text())
    assert written["overrides"] == {"fusion.strategy": "product"} and written["scenarios"]["room"]["strategy"] == "product"


@pytest.mark.slow  # ~15-30 s: two real logs, 8 relations each, two settings
def test_a_sweep_over_laser_logs_gives_each_setting_its_fold_table(tmp_path: Path, shared_data: Path) -> None:
    laser = shared_data / "laser"
    (tmp_path / "g.yaml").write_text(
        f"grid:\n  icp.covariance.sigma_floor_m: [0.0075, 0.02]\nlaser:\n  directory: {laser}\n  logs: [aces, mit-csail]\n"
        "  every: 150\n"
    )
    results = run_sweep(SweepSpec.from_yaml(tmp_path / "g.yaml"))
    from factorloc.datasets.rosbag import read_laser_log

    log, rel = read_laser_log(laser / "aces.sort.bag"), read_relations(laser / "aces.relations").subset(150)
    for r, floor in zip(results, (0.0075, 0.02), strict=True):
        assert [f.dataset for f in r.folds.folds] == ["aces", "mit-csail"]
        cfg = apply_overrides(relations_config(), {"icp.covariance.sigma_floor_m": floor})
        direct = fold_figures(relations_benchmark(log, rel, config=cfg), "aces", r.setting.name)
        assert r.folds.folds[0].icp_nees_position == direct.icp_nees_position
        assert r.folds.folds[0].confidently_wrong_all == direct.confidently_wrong_all
    # a larger floor can only shrink the ICP step's NEES (its covariance grows)
    assert results[1].folds.folds[0].icp_nees_position <= results[0].folds.folds[0].icp_nees_position
    assert "held out" in format_sweep(results)

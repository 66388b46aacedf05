"""The command line: fuse on the patent's worked example against a hand computation."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from typer.testing import CliRunner

import factorloc
from factorloc import cli
from factorloc.cli import app
from factorloc.cli_console import PIPED_WIDTH
from factorloc.datasets import Scenario, save_scenario

runner = CliRunner()


def test_version() -> None:
    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0 and factorloc.__version__ in result.output


def test_fuse_json_reproduces_the_hand_computed_patent_example(repo_root: Path) -> None:
    result = runner.invoke(app, ["fuse", str(repo_root / "data" / "examples" / "patent_example.json"), "--json"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    # hand computation, per axis: x = (1.00/5² + 1.03/2²) / (1/5² + 1/2²) with σ in cm
    wx1, wx4 = 1 / 0.05**2, 1 / 0.02**2  # 400, 2500
    x = (1.00 * wx1 + 1.03 * wx4) / (wx1 + wx4)  # 2975/2900 = 1.025862…
    y = (0.50 * wx1 + 0.48 * wx4) / (wx1 + wx4)  # 1400/2900 = 0.482758…
    var_xy = 1 / (wx1 + wx4)  # 1/2900 m²
    w1, w2, w3 = 1 / 3.0**2, 1 / 1.0**2, 1 / 0.5**2  # headings 10°, 12°, 11.5° (weights per deg²)
    theta_deg = (10.0 * w1 + 12.0 * w2 + 11.5 * w3) / (w1 + w2 + w3)  # 11.5652…°
    var_theta = math.radians(1.0) ** 2 / (w1 + w2 + w3)
    assert math.isclose(out["pose"]["x_m"], x, rel_tol=1e-12)
    assert math.isclose(out["pose"]["y_m"], y, rel_tol=1e-12)
    assert math.isclose(out["pose"]["theta_deg"], theta_deg, rel_tol=1e-12)
    cov = out["covariance"]
    assert math.isclose(cov[0][0], var_xy, rel_tol=1e-9) and math.isclose(cov[1][1], var_xy, rel_tol=1e-9)
    assert math.isclose(cov[2][2], var_theta, rel_tol=1e-9)
    assert abs(cov[0][1]) < 1e-15 and cov[0][2] == 0.0
    assert [s["status"] for s in out["steps"]] == ["fused"] * 4
    # the closed form prints the same numbers
    product = json.loads(
        runner.invoke(
            app, ["fuse", str(repo_root / "data/examples/patent_example.json"), "--json", "--strategy", "product"]
        ).output
    )
    assert math.isclose(product["pose"]["x_m"], x, rel_tol=1e-12)


def test_fuse_rejects_missing_and_malformed_files(tmp_path: Path) -> None:
    result = runner.invoke(app, ["fuse", str(tmp_path / "none.json")])
    assert result.exit_code == 2 and "not found" in result.output
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps([{"step": "a", "components": ["x"], "values": [1.0], "sigmas": [1.0]}]))
    result = runner.invoke(app, ["fuse", str(bad)])
    assert result.exit_code == 2 and "components" in result.output


# ----------------------------------------------------------------------------
# evaluate / bench (added by the evaluation issue)
# ----------------------------------------------------------------------------
@pytest.fixture
def room_dir(tmp_path: Path, make_room_scenario: Callable[[int, int], Scenario]) -> Callable[[int], Path]:
    """``room_dir(n)``: the shared test room (``tests/conftest.py``) with n queries, saved under ``tmp_path``."""

    def save(n: int = 4) -> Path:
        return save_scenario(make_room_scenario(n, 5), tmp_path / "room")

    return save


def test_evaluate_writes_json_with_the_stable_keys_and_the_figures(tmp_path: Path, room_dir: Callable[[int], Path]) -> None:
    scen = room_dir(4)
    result = runner.invoke(app, ["evaluate", str(scen), "--json", str(tmp_path / "out.json"), "--plot", str(tmp_path / "figs")])
    assert result.exit_code == 0, result.output
    assert "room: fused pose" in result.output and "icp" in result.output
    out = json.loads((tmp_path / "out.json").read_text())
    for key in (
        "position_rmse_m",
        "position_median_m",
        "heading_rmse_deg",
        "heading_median_deg",
        "nees_mean",
        "outside_99_rate",
        "confidently_wrong_rate",
        "latency_median_ms",
        "latency_p95_ms",
    ):
        assert key in out and key in out["by_fault"]["blur"], key
    assert out["queries"] == 4 and out["steps"]["icp"]["reliable_rate"] == 1.0
    assert out["steps"]["compass"]["gate_reasons"] == {"skipped: compass.skipped": 4}
    assert out["position_rmse_m"] < 0.01  # exact scans: ICP recovers the pose; the 5 cm odometry error is gone
    assert sorted(p.name for p in (tmp_path / "figs").iterdir()) == [
        "availability.png",
        "calibration.png",
        "error_vs_distance.png",
        "floor_plan.png",
    ]


def test_evaluate_fails_cleanly_on_a_missing_scenario(tmp_path: Path) -> None:
    result = runner.invoke(app, ["evaluate", str(tmp_path / "nowhere")])
    assert result.exit_code == 2 and "error" in result.output


def test_bench_on_a_tiny_scenario_writes_every_section(tmp_path: Path, room_dir: Callable[[int], Path]) -> None:
    scen = room_dir(2)
    result = runner.invoke(app, ["bench", "--scenario", str(scen), "--repeats", "1", "--json", str(tmp_path / "bench.json")])
    assert result.exit_code == 0, result.output
    out = json.loads((tmp_path / "bench.json").read_text())
    assert {"localize", "hierarchy", "icp_vs_open3d", "fusion", "cost_curve"} <= set(out)
    assert out["icp_vs_open3d"]["pairs"] == 2 and out["hierarchy"]["time_ratio"] > 0
    assert "Hierarchy ablation" in result.output
    fp = out["hierarchy"]["false_positives"]
    assert fp["queries"] == 2 and fp["fused"]["sigma3"]["seeded"]["count"] == 0  # exact scans: ICP is right
    assert "confidently" in result.output and "seeded" in result.output


@pytest.mark.slow
def test_demo_evaluates_the_shipped_sample_and_writes_figures_and_json(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    # the width of a piped console (pytest-xdist's workers set COLUMNS=80, which the console honours)
    monkeypatch.setattr(cli.console, "width", PIPED_WIDTH)
    result = runner.invoke(app, ["demo", "--out", str(tmp_path / "demo")])
    assert result.exit_code == 0, result.output
    assert "What each step contributed" in result.output and "Fused pose vs ground truth" in result.output
    assert "…" not in result.output  # no figure cut short
    out = json.loads((tmp_path / "demo" / "evaluation.json").read_text())
    assert out["queries"] == 30 and set(out["steps"]) == {"odometry", "compass", "correlation", "icp"}
    assert out["steps"]["odometry"]["status_rates"]["skipped"] == 0.0  # every sample query carries odometry
    assert {p.name for p in (tmp_path / "demo").glob("*.png")} == {
        "availability.png",
        "calibration.png",
        "error_vs_distance.png",
        "floor_plan.png",
    }


def _bench_report(hierarchy: Any, points: tuple[Any, ...]) -> Any:
    from factorloc.benchmarking import BenchReport, BenchSettings, CostCurve, FusionBench, IcpVsOpen3d, LocalizeBench
    from factorloc.benchmarking.results import Machine

    return BenchReport(
        scenario="s",
        queries=1,
        settings=BenchSettings(repeats=1),
        localize=LocalizeBench(1, 1, 25.5, 30.0, 26.0, {}, {}),
        hierarchy=hierarchy,
        icp_vs_open3d=IcpVsOpen3d(0),
        fusion=FusionBench(0),
        cost_curve=CostCurve(points, 1.0, {"icp": 1.0}),
        peak_memory_mb=100.0,
        wall_seconds=1.0,
        machine=Machine(2, 2, 0.5, 0.5, 2),
    )


def _mode(median_ms: float, fp: int, wrong: int, wrong_rate: float, determined: float) -> Any:
    from factorloc.benchmarking import HierarchyMode

    return HierarchyMode(
        median_ms, math.nan, math.nan, {}, 10, fp, fp / 10, {}, {}, {}, {}, wrong_rate, wrong, determined, 0.01, 0.1
    )


def _fp_comparison(queries: int, after_first: Any = None, fused: Any = None, steps: Any = None) -> Any:
    from factorloc.benchmarking import FalsePositiveComparison

    return FalsePositiveComparison("sigma3", 0.95, 5.0, 0.1, 5.0, queries, after_first or {}, fused or {}, steps or {})


def test_bench_tables_render_a_cost_curve_with_panorama_and_cloud_sizes() -> None:
    from rich.console import Console

    from factorloc.benchmarking import HierarchyBench
    from factorloc.benchmarking.results import CostPoint
    from factorloc.cli_bench import bench_tables

    point = CostPoint(1.0, 2048, 10240, 360, 4800.0, 25.5, {"icp": 3.25})
    doubled = CostPoint(2.0, 4096, 10240, 360, 4800.0, 51.0, {"icp": 3.25})
    hierarchy = HierarchyBench(
        _mode(10.0, 0, 0, 0.0, 0.9), _mode(40.0, 3, 2, 0.1, 0.8), 4.0, 3.0, True, 2.0, True, _fp_comparison(0)
    )
    console = Console(width=100, record=True)
    for t in bench_tables(_bench_report(hierarchy, (point, doubled))):
        console.print(t)
    text = console.export_text()
    assert "4096" in text and "10240" in text and "≥ 3.0×" in text and "4.0×" in text and "≥ 2.0×" in text


def test_evaluate_uses_the_given_config(tmp_path: Path, room_dir: Callable[[int], Path]) -> None:
    scen = room_dir(2)
    (tmp_path / "c.yaml").write_text("compass:\n  enabled: false\ncorrelation:\n  enabled: false\nfusion:\n  strategy: product\n")
    result = runner.invoke(app, ["evaluate", str(scen), "--config", str(tmp_path / "c.yaml"), "--json", str(tmp_path / "o.json")])
    assert result.exit_code == 0, result.output
    out = json.loads((tmp_path / "o.json").read_text())
    assert list(out["steps"]) == ["odometry", "icp"] and out["strategy"] == "product"
    bad = runner.invoke(app, ["evaluate", str(scen), "--config", str(tmp_path / "none.yaml")])
    assert bad.exit_code == 2 and "config file not found" in bad.output


def test_localize_one_sample_query_prints_the_steps_and_the_fused_pose(repo_root: Path) -> None:
    sample = repo_root / "data" / "sample"
    result = runner.invoke(app, ["localize", str(sample), "q0000", "--json"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    assert [s["name"] for s in out["steps"]] == ["odometry", "compass", "correlation", "icp"]
    assert out["query_id"] == "q0000" and out["truth"] is not None
    if not out["undetermined"]:  # a determined pose is close to the truth
        err = math.hypot(out["pose"]["x_m"] - out["truth"]["x_m"], out["pose"]["y_m"] - out["truth"]["y_m"])
        assert err < 0.10
    table = runner.invoke(app, ["localize", str(sample), "q0000"])
    assert table.exit_code == 0 and "Fused pose" in table.output and "Error against ground truth" in table.output


def test_localize_unknown_query_or_scenario_fails_cleanly(repo_root: Path, tmp_path: Path) -> None:
    result = runner.invoke(app, ["localize", str(repo_root / "data" / "sample"), "no-such-query"])
    assert result.exit_code == 2 and "no query 'no-such-query'" in result.output
    result = runner.invoke(app, ["localize", str(tmp_path), "q0000"])
    assert result.exit_code == 2 and "error" in result.output.lower()


def test_bench_hierarchy_table_shows_exact_intervals_the_ratio_bound_and_the_sample_needed() -> None:
    from rich.console import Console

    from factorloc.benchmarking import HierarchyBench, compare_counts
    from factorloc.cli_bench import hierarchy_table

    none, two = compare_counts(0, 0, 300), compare_counts(0, 2, 300)
    odometry = {"odometry": {"sigma3": compare_counts(6, 6, 300, seeded_reliable=250, blind_reliable=250)}}
    fp = _fp_comparison(300, {"sigma3": none, "tolerance": none}, {"sigma3": two, "tolerance": two}, odometry)
    h = HierarchyBench(_mode(25.0, 0, 0, 0.0, 0.97), _mode(158.0, 0, 0, 0.0, 0.97), 6.3, math.nan, False, math.nan, False, fp)
    console = Console(width=160, record=True)
    console.print(hierarchy_table(h))
    text = console.export_text()
    # 2 of 300 blind, 0 seeded: the rates' exact intervals, an unbounded ratio whose one-sided bound is 0.29×,
    # and the 2465 queries at which 0.67 % blind vs 0 seeded would show 5×
    assert "0 [0.0–1.2 %]" in text and "2 [0.1–2.4 %]" in text and "∞ (≥ 0.29×)" in text
    assert "steps after odometry: false + (> 3σ)" in text and "steps: no blind false +" in text
    assert "fused ≈ 2465 (3049 for 80 %)" in text and "6.3×" in text
    assert "6 / 250" in text and "1.0× (≥ 0.33×)" in text


def test_library_errors_are_one_line_on_stderr_with_exit_status_2(tmp_path: Path) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps([{"step": "a", "components": ["x"], "values": [1.0], "sigmas": [1.0]}]))
    result = runner.invoke(app, ["fuse", str(bad)])
    assert result.exit_code == 2 and result.stdout == ""
    assert result.stderr.startswith("error: ") and result.stderr.count("\n") == 1 and "Traceback" not in result.stderr
    assert result.exception is None or isinstance(result.exception, SystemExit)


def test_simulate_into_an_existing_scenario_fails_before_rendering_and_names_the_flag(
    tmp_path: Path, room_dir: Callable[[int], Path], monkeypatch: pytest.MonkeyPatch
) -> None:
    import factorloc.sim

    scen = room_dir(1)

    def no_rendering(*args: Any, **kwargs: Any) -> None:
        raise AssertionError("rendered before checking the target directory")

    monkeypatch.setattr(factorloc.sim, "generate_scenario", no_rendering)
    result = runner.invoke(app, ["simulate", str(scen), "--queries", "1"])
    assert result.exit_code == 2 and "use --overwrite to replace it" in result.stderr and "overwrite=True" not in result.stderr


def test_steps_without_their_inputs_are_shown_as_absent(tmp_path: Path, room_dir: Callable[[int], Path]) -> None:
    room = room_dir(2)
    result = runner.invoke(app, ["evaluate", str(room)], terminal_width=160)
    assert result.exit_code == 0, result.output
    compass = next(line for line in result.output.splitlines() if line.strip().startswith("compass"))
    assert "absent" in compass and "%" not in compass  # not "0 % reliable": the scan-only room has no camera
    localized = runner.invoke(app, ["localize", str(room), "q0"], terminal_width=200)
    assert any("compass" in line and "absent" in line for line in localized.output.splitlines())

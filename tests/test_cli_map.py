"""``factorloc map LOG OUT_DIR`` on a prefix of the real Intel log."""

from __future__ import annotations

import json
from pathlib import Path

from typer.testing import CliRunner

from factorloc.cli import app

runner = CliRunner()


def test_map_writes_the_places_the_trajectory_and_the_figure(shared_data: Path, tmp_path: Path) -> None:
    out = tmp_path / "map"
    bag = shared_data / "laser" / "intel.sort.bag"
    result = runner.invoke(app, ["map", str(bag), str(out), "--max-scans", "400"])
    assert result.exit_code == 0, result.output
    assert "places from 400 scans" in result.output
    data = json.loads((out / "places.json").read_text())
    assert len(data["places"]) >= 10 and len(data["places"][0]["covariance"]) == 3
    assert len((out / "trajectory.tum").read_text().splitlines()) == 401  # header + every scan
    assert (out / "map.png").stat().st_size > 10_000


def test_map_reports_a_bad_option_as_one_error_line(tmp_path: Path) -> None:
    result = runner.invoke(app, ["map", str(tmp_path / "missing.bag"), str(tmp_path / "out"), "--robust", "tukey"])
    assert result.exit_code == 2
    assert "error:" in result.output and "robust" in result.output

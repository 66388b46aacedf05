"""``factorloc map LOG OUT_DIR`` on a prefix of the real Intel log."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from typer.testing import CliRunner

from factorloc.cli import app
from factorloc.places import PlaceMap

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


def test_map_writes_local_place_covariances_on_request(shared_data: Path, tmp_path: Path) -> None:
    """--place-covariance local: place_map/'s places carry their covariance relative to their neighbours, below the
    marginal's (which grows with the distance from the first place)."""
    bag = shared_data / "laser" / "intel.sort.bag"
    paths = {}
    for kind in ("marginal", "local"):
        out = tmp_path / kind
        result = runner.invoke(app, ["map", str(bag), str(out), "--max-scans", "400", "--no-figure", "--place-covariance", kind])
        assert result.exit_code == 0, result.output
        paths[kind] = out / "place_map"
    marginal, local = (PlaceMap.load(paths[k]) for k in ("marginal", "local"))
    last_m, last_l = list(marginal)[-1].covariance, list(local)[-1].covariance
    assert np.trace(last_l[:2, :2]) < np.trace(last_m[:2, :2])
    assert np.all(np.linalg.eigvalsh(last_l) > 0.0)
    bad = runner.invoke(app, ["map", str(bag), str(tmp_path / "bad"), "--max-scans", "50", "--place-covariance", "absolute"])
    assert bad.exit_code == 2 and "--place-covariance must be one of" in bad.output
    assert not (tmp_path / "bad").exists()

"""``factorloc track``: JSON lines per query, a TUM trajectory that evo's ``evo_ape tum`` reads and scores the same
as we do, and one-line errors."""

from __future__ import annotations

import json
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from typer.testing import CliRunner

from factorloc.cli import app


@pytest.fixture(scope="module")
def track_scenario(tmp_path_factory) -> Path:
    from factorloc.datasets import save_scenario
    from factorloc.evaluation.places import simulated_place_map, simulated_track
    from factorloc.sim import apartment

    world = apartment()
    pm = simulated_place_map(world, 1.0, seed=0)
    path = tmp_path_factory.mktemp("track") / "drive"
    save_scenario(simulated_track(world, pm, 30, seed=21), path)
    return path


def test_track_writes_json_lines_and_a_tum_file_that_evo_ape_reads(track_scenario: Path, tmp_path: Path) -> None:
    est, truth, lines = tmp_path / "est.tum", tmp_path / "truth.tum", tmp_path / "track.jsonl"
    res = CliRunner().invoke(
        app, ["track", str(track_scenario), "--tum", str(est), "--truth-tum", str(truth), "--jsonl", str(lines)]
    )
    assert res.exit_code == 0, res.output
    rows = [json.loads(x) for x in lines.read_text().splitlines()]
    assert len(rows) == 30
    assert {"pose", "covariance", "state", "places_used", "checks", "steps"} <= set(rows[0])
    assert rows[0]["state"] == "relocalized" and all(r["state"] in ("tracking", "relocalized", "lost") for r in rows)
    ours = np.loadtxt(est)
    gt = np.loadtxt(truth)
    assert ours.shape == (30, 8) and gt.shape == (30, 8)
    rmse = math.sqrt(np.mean(np.sum((ours[:, 1:3] - gt[:, 1:3]) ** 2, axis=1)))
    evo_ape = Path(sys.executable).with_name("evo_ape")
    assert evo_ape.exists(), "evo_ape is missing: evo is in the dev extra that make setup installs"
    out = subprocess.run([str(evo_ape), "tum", str(truth), str(est)], capture_output=True, text=True, check=True).stdout
    m = re.search(r"rmse\s+([0-9.eE+-]+)", out)
    assert m, out
    # evo's APE of the translation part, no alignment: the same number as ours
    assert float(m.group(1)) == pytest.approx(rmse, abs=1e-6)  # evo prints 6 decimals
    assert rmse < 0.05


def test_track_reports_a_bad_scenario_in_one_line(tmp_path: Path) -> None:
    res = CliRunner().invoke(app, ["track", str(tmp_path / "missing")])
    assert res.exit_code == 2
    assert "error:" in res.output and "Traceback" not in res.output

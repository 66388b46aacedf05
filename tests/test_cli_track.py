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


def test_simulate_track_writes_a_tour_that_track_follows_through_a_kidnapping(tmp_path: Path) -> None:
    from factorloc.datasets import load_scenario
    from factorloc.sim import world_by_name
    from factorloc.sim.track import room_of, rooms

    out = tmp_path / "tour"
    res = CliRunner().invoke(app, ["simulate", str(out), "--track", "--queries", "20", "--kidnaps", "1", "--seed", "5"])
    assert res.exit_code == 0, res.output
    scen = load_scenario(out)
    world = world_by_name("apartment")
    assert {room_of(world, r.reference.T_world_reference.translation)[0] for r in scen.references} == {r for r, _ in rooms(world)}
    truth = np.array([q.truth.as_array() for q in scen.queries])
    assert world.is_free(truth[:, :2], 0.25).all()
    k = next(i for i, q in enumerate(scen.queries) if "kidnapped" in q.faults)
    assert math.dist(truth[k, :2], truth[k - 1, :2]) > 1.0
    odo = [q.query.odometry.T_world_robot for q in scen.queries]
    assert math.dist(odo[k].translation, odo[k - 1].translation) < 0.3  # the odometry did not see it
    lines = tmp_path / "track.jsonl"
    res = CliRunner().invoke(app, ["track", str(out), "--jsonl", str(lines), "--tum", str(tmp_path / "est.tum")])
    assert res.exit_code == 0, res.output
    rows = [json.loads(x) for x in lines.read_text().splitlines()]
    assert len(rows) == 20
    back = [
        j
        for j in range(k, k + 3)
        if rows[j]["state"] == "relocalized"
        and math.hypot(rows[j]["pose"]["x_m"] - truth[j, 0], rows[j]["pose"]["y_m"] - truth[j, 1]) < 0.1
    ]
    assert back, [(r["state"], r["pose"]) for r in rows[k : k + 3]]  # re-localized within 3 queries of the kidnapping
    after = np.array([[r["pose"]["x_m"], r["pose"]["y_m"]] for r in rows[back[0] :]])
    assert np.max(np.hypot(*(after - truth[back[0] :, :2]).T)) < 0.1  # and tracking from there on
    report = tmp_path / "report.json"
    res = CliRunner().invoke(app, ["evaluate", str(out), "--json", str(report)])  # one query against its nearest place
    assert res.exit_code == 0, res.output
    assert json.loads(report.read_text())["queries_with_truth"] == 20

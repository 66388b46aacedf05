"""docs/own-data.md runs as written: its two commands on the Intel bag, and its Python examples.

The page's paths are the ones a user types from the repository's root (``../shared/data/…``); the
test runs them from a scratch directory that has ``../shared`` beside it, so nothing is written
into the checkout.
"""

from __future__ import annotations

import re
import shlex
from pathlib import Path

import pytest
from typer.testing import CliRunner

from factorloc.cli import app

#: the "all" row of `factorloc evaluate`'s summary: n, position RMSE and p95 (cm), heading RMSE and p95 (°), NEES,
#: confidently wrong, full pose (the time column is left out)
ROW = re.compile(r"^\s*all\s+(\d+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+([\d.]+)\s+(\d+)%\s+(\d+)%", re.M)


def _block(repo_root: Path, marker: str, lang: str) -> str:
    text = (repo_root / "docs" / "own-data.md").read_text()
    match = re.search(rf"```{lang}\n# docs-example: {marker}\n(.*?)```", text, re.S)
    assert match, f"the {marker} example is missing from docs/own-data.md"
    return match.group(1)


@pytest.fixture
def workdir(shared_data: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    (tmp_path / "shared").symlink_to(shared_data.parent)
    work = tmp_path / "repo"
    work.mkdir()
    monkeypatch.chdir(work)
    return work


@pytest.mark.slow
def test_the_two_commands_convert_the_intel_bag_and_print_its_accuracy(repo_root: Path, workdir: Path) -> None:
    commands = [shlex.split(line) for line in _block(repo_root, "convert-evaluate", "bash").splitlines() if line.strip()]
    assert [c[:2] for c in commands] == [["factorloc", "convert"], ["factorloc", "evaluate"]], "the guide shows two commands"
    runner = CliRunner()
    convert = runner.invoke(app, commands[0][1:], env={"COLUMNS": "200"})
    assert convert.exit_code == 0, convert.output
    assert "66 references, 145 queries (145 with ground truth)" in convert.output
    evaluate = runner.invoke(app, commands[1][1:], env={"COLUMNS": "200"})
    assert evaluate.exit_code == 0, evaluate.output
    row = ROW.search(evaluate.output)
    assert row, evaluate.output
    n, pos_rmse_cm, _, head_rmse_deg, _, nees, wrong_pct, full_pct = row.groups()
    # accuracy against the relations' ground truth (the figures the page quotes)
    assert int(n) == 145 and float(pos_rmse_cm) < 3.0 and float(head_rmse_deg) < 0.6
    assert float(nees) < 3.0 and int(wrong_pct) <= 1 and int(full_pct) >= 90
    quoted = ROW.search((repo_root / "docs" / "own-data.md").read_text())
    assert quoted and quoted.groups() == row.groups(), "the page quotes the figures this run prints"


def test_the_fit_odometry_example_writes_a_model_the_conversion_reads(repo_root: Path, workdir: Path) -> None:
    exec(compile(_block(repo_root, "fit-odometry", "python"), "own-data.md", "exec"), {})
    import yaml

    import factorloc as fl

    model = fl.OdometryModel.from_dict(yaml.safe_load((workdir / "odometry.yaml").read_text()))
    assert model != fl.OdometryModel() and 0.01 < model.min_sigma_m < 0.2


def test_the_stitching_example_makes_a_full_panorama(repo_root: Path, workdir: Path) -> None:
    scope: dict = {}
    exec(compile(_block(repo_root, "stitch", "python"), "own-data.md", "exec"), scope)
    pano = scope["reference"].panorama
    assert pano.width_px == 2048 and pano.seen_columns is None


@pytest.mark.slow
def test_the_python_conversion_example_runs(repo_root: Path, workdir: Path) -> None:
    exec(compile(_block(repo_root, "convert-python", "python"), "own-data.md", "exec"), {})
    from factorloc.datasets import load_scenario

    assert len(load_scenario(workdir / "intel").queries) == 145

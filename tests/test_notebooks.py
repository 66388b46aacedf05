"""The notebooks in git are committed clean: no outputs, no execution counts (they are executed in CI by
``pytest --nbmake notebooks/``); each draws at least one figure."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def _notebooks() -> list[Path]:
    try:
        out = subprocess.run(
            ["git", "ls-files", "*.ipynb"], cwd=REPO, capture_output=True, text=True, check=True, timeout=30
        ).stdout.split()
        tracked = [REPO / p for p in out]
    except (OSError, subprocess.SubprocessError):
        tracked = []
    return sorted(set(tracked) | set((REPO / "notebooks").glob("*.ipynb")))


NOTEBOOKS = _notebooks()


def test_the_six_notebooks_are_there() -> None:
    names = {p.name for p in NOTEBOOKS}
    for n in (
        "01_quickstart",
        "02_fusion_strategies",
        "03_hierarchy_ablation",
        "04_faults_and_gating",
        "05_real_laser_logs",
        "06_tracking",
    ):
        assert f"{n}.ipynb" in names


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_is_output_stripped(path: Path) -> None:
    nb = json.loads(path.read_text(encoding="utf-8"))
    dirty = [
        i
        for i, c in enumerate(nb["cells"])
        if c["cell_type"] == "code" and (c.get("outputs") or c.get("execution_count") is not None)
    ]
    assert dirty == [], f"{path.name}: cells {dirty} have outputs or execution counts; strip them before committing"


@pytest.mark.parametrize("path", NOTEBOOKS, ids=lambda p: p.name)
def test_notebook_draws_a_figure(path: Path) -> None:
    nb = json.loads(path.read_text(encoding="utf-8"))
    code = "\n".join("".join(c["source"]) for c in nb["cells"] if c["cell_type"] == "code")
    assert "plt.subplots(" in code

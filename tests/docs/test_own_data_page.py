"""The conversion example of docs/own-data.md runs as written on the real Intel laser log."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np

import factorloc as fl
from factorloc.datasets import load_scenario


def _example(repo_root: Path) -> str:
    text = (repo_root / "docs" / "own-data.md").read_text()
    match = re.search(r"```python\n(# docs-example: convert-rosbag\n.*?)```", text, re.S)
    assert match, "the convert-rosbag example is missing from docs/own-data.md"
    return match.group(1)


def test_the_rosbag_conversion_example_writes_a_scenario_that_localizes(
    repo_root: Path, shared_data: Path, tmp_path: Path
) -> None:
    out = tmp_path / "my-robot"
    exec(
        compile(_example(repo_root), "own-data.md", "exec"),
        {"BAG_PATH": shared_data / "laser" / "intel.sort.bag", "OUT_DIR": out},
    )
    scenario = load_scenario(out)
    assert len(scenario.queries) == 9
    localizer = fl.Localizer(scenario.reference)
    locs = [localizer.localize(q.query) for q in scenario.queries]
    # every query is fully determined, ICP is fused on (nearly) all of them, and it stays within the
    # odometry's own uncertainty of the dead-reckoned pose (0.3–2.6 m driven, 5 % drift)
    assert all(loc.determined for loc in locs)
    assert sum(loc.step("icp").fused for loc in locs) >= 8
    for loc, q in zip(locs, scenario.queries, strict=True):
        odo = q.query.odometry
        assert np.hypot(*(loc.pose.translation - odo.T_world_robot.translation)) < 3 * odo.sigma_x_m + 0.02

"""The scenario format keeps a stitched panorama's seen columns (runs of columns in the manifest)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

import factorloc as fl
from factorloc.datasets import Scenario, ScenarioQuery, ScenarioReference, load_scenario, save_scenario
from factorloc.errors import DatasetError


def _scenario(seen: np.ndarray | None) -> Scenario:
    img = np.random.default_rng(0).integers(0, 256, (16, 64, 3), dtype=np.uint8)
    ref = fl.Reference(panorama=fl.Panorama(img, seen_columns=seen))
    q = fl.Query(scan=fl.Scan(np.array([[1.0, 0.0], [0.0, 1.0]])), id="q0")
    return Scenario("mask", (ScenarioReference("ref0", ref),), (ScenarioQuery(q),))


def test_seen_columns_round_trip_as_runs(tmp_path: Path) -> None:
    seen = np.zeros(64, bool)
    seen[3:20] = seen[40:64] = True
    path = save_scenario(_scenario(seen), tmp_path / "s")
    manifest = yaml.safe_load((path / "scenario.yaml").read_text())
    assert manifest["references"][0]["panorama"]["seen_columns"] == [[3, 20], [40, 64]]
    back = load_scenario(path)
    assert np.array_equal(back.reference.panorama.seen_columns, seen) and back == _scenario(seen)
    assert load_scenario(save_scenario(_scenario(None), tmp_path / "all")).reference.panorama.seen_columns is None
    assert _scenario(None) != _scenario(seen)


def test_malformed_runs_are_errors_naming_the_field(tmp_path: Path) -> None:
    path = save_scenario(_scenario(None), tmp_path / "s")
    manifest = yaml.safe_load((path / "scenario.yaml").read_text())
    for bad in ([[5, 3]], [[0, 65]], [["a", 2]], [[1]]):
        manifest["references"][0]["panorama"]["seen_columns"] = bad
        (path / "scenario.yaml").write_text(yaml.safe_dump(manifest))
        with pytest.raises(DatasetError, match=r"references\[0\]\.panorama\.seen_columns"):
            load_scenario(path)

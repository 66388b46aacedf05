"""save_map (places.json, trajectory.tum, map.png) and the map figure."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

from factorloc.datasets.tum import read_tum_trajectory
from factorloc.mapping import MapResult
from factorloc.mapping.figure import map_figure
from factorloc.mapping.io import save_map
from factorloc.places import PlaceMap


def test_save_map_writes_the_places_the_trajectory_and_the_figure(sim_map: MapResult, tmp_path: Path) -> None:
    paths = save_map(sim_map, tmp_path / "out")
    assert [p.name for p in paths] == ["places.json", "trajectory.tum", "place_map", "map.png"]
    data = json.loads(paths[0].read_text())
    assert len(data["places"]) == len(sim_map)
    p3 = data["places"][3]
    assert np.allclose(p3["pose"], sim_map.place_poses[3]) and np.allclose(p3["covariance"], sim_map.place_covariances[3])
    assert sum(c["accepted"] for c in data["closures"]) == sim_map.stats["closures_accepted"]
    track = read_tum_trajectory(paths[1])
    assert len(track) == len(sim_map.scan_poses)
    assert np.allclose(track.poses[:, :2], sim_map.scan_poses[:, :2], atol=1e-6)
    assert len(PlaceMap.load(paths[2])) == len(sim_map)
    assert paths[3].stat().st_size > 10_000


def test_the_figure_draws_every_place_scan(sim_map: MapResult) -> None:
    fig = map_figure(sim_map)
    assert isinstance(fig, Figure)
    ax = fig.axes[0]
    n_points = sum(len(p) for p in sim_map.place_points)
    assert ax.collections[0].get_offsets().shape[0] == n_points
    assert "loop closures accepted" in ax.get_title()

"""Write a built map to a directory: the places (JSON), the trajectory of every scan (TUM) and a figure (PNG)."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from factorloc.datasets.tum import write_tum_trajectory
from factorloc.mapping.result import MapResult, PlaceCovariance

__all__ = ["map_to_dict", "save_map"]


def map_to_dict(result: MapResult) -> dict[str, Any]:
    """Plain dict of the map: places (id, stamp, scan index, pose ``[x_m, y_m, θ_rad]`` in the map frame,
    3×3 world-frame covariance), closures (places, measured pose, verdict, back-end weight) and stats."""
    places = [
        {
            "id": int(p.id),
            "stamp_s": p.stamp_s,
            "scan_index": p.scan_index,
            "pose": [p.T_world_place.x, p.T_world_place.y, p.T_world_place.theta],
            "covariance": np.asarray(p.covariance).tolist(),
        }
        for p in result.places()
    ]
    closures = [
        {
            "place_from": c.place_from,
            "place_to": c.place_to,
            "T_from_to": [c.T_from_to.x, c.T_from_to.y, c.T_from_to.theta],
            "reliable": c.reliable,
            "accepted": c.accepted,
            "weight": None if math.isnan(c.weight) else c.weight,
            "used_global": c.used_global,
            "proposed_by": c.proposed_by,
            "reason": c.reason,
        }
        for c in result.closures
    ]
    return {"frame": "odometry frame at the first place", "places": places, "closures": closures, "stats": dict(result.stats)}


def save_map(
    result: MapResult, out_dir: str | Path, *, figure: bool = True, place_covariance: PlaceCovariance = "marginal"
) -> list[Path]:
    """Write ``places.json`` (:func:`map_to_dict`), ``trajectory.tum`` (every scan's pose), ``place_map/`` (the map
    as a :class:`~factorloc.places.PlaceMap` scenario directory, :meth:`MapResult.place_map` with
    ``place_covariance``; what ``factorloc track --map`` and ``PlaceMap.load`` read) and, with ``figure``,
    ``map.png`` (:func:`factorloc.mapping.figure.map_figure`) into ``out_dir``; returns the paths written."""
    place_map = result.place_map(covariance=place_covariance)  # a wrong choice fails before anything is written
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    paths = [out / "places.json"]
    paths[0].write_text(json.dumps(map_to_dict(result), indent=1), encoding="utf-8")
    paths.append(write_tum_trajectory(out / "trajectory.tum", result.scan_stamps_s, result.scan_poses))
    paths.append(place_map.save(out / "place_map", name="map", overwrite=True))
    if figure:
        from factorloc.mapping.figure import map_figure

        fig = map_figure(result)
        p = out / "map.png"
        fig.savefig(p, dpi=150)
        paths.append(p)
    return paths

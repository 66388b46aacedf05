"""The figure of a built map (matplotlib, no pyplot state: safe on the Agg backend), as :mod:`factorloc.plotting`:
:func:`plot_map_on_axes` draws on given axes, :func:`map_figure` makes a new figure."""

from __future__ import annotations

import numpy as np
from matplotlib.axes import Axes
from matplotlib.figure import Figure

from factorloc.geometry import Pose2
from factorloc.mapping.result import MapResult

__all__ = ["map_figure", "plot_map_on_axes"]

SCAN_COLOR = "#333333"
PATH_COLOR = "#1f4e79"
CLOSURE_COLOR = "#2e9d5b"
REJECTED_COLOR = "#d9534f"


def plot_map_on_axes(ax: Axes, result: MapResult, *, max_points: int = 200_000, closures: bool = True) -> Axes:
    """The places' scans drawn at their optimized poses (map frame, metres), the path of the places and, with
    ``closures``, the accepted loop closures (green) and those the back end rejected (red)."""
    pts = [Pose2.from_array(result.place_poses[k]).transform_points(p) for k, p in enumerate(result.place_points)]
    cloud = np.vstack(pts) if pts else np.zeros((0, 2))
    if len(cloud) > max_points:
        cloud = cloud[:: int(np.ceil(len(cloud) / max_points))]
    ax.scatter(cloud[:, 0], cloud[:, 1], s=0.3, c=SCAN_COLOR, linewidths=0, rasterized=True)
    ax.plot(result.place_poses[:, 0], result.place_poses[:, 1], "-", color=PATH_COLOR, lw=0.4, alpha=0.7)
    if closures:
        for c in result.closures:
            if not c.reliable:
                continue
            a, b = result.place_poses[c.place_from], result.place_poses[c.place_to]
            ax.plot([a[0], b[0]], [a[1], b[1]], "-", color=CLOSURE_COLOR if c.accepted else REJECTED_COLOR, lw=0.3)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    n_acc = sum(c.accepted for c in result.closures)
    ax.set_title(f"{len(result)} places, {n_acc} loop closures accepted")
    return ax


def map_figure(result: MapResult, *, size_in: float = 8.0) -> Figure:
    """A new figure of :func:`plot_map_on_axes`."""
    fig = Figure(figsize=(size_in, size_in))
    plot_map_on_axes(fig.add_subplot(1, 1, 1), result)
    fig.tight_layout()
    return fig

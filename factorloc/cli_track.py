"""``factorloc track SCENARIO``: follow a robot along a scenario's queries through a map of places (registered by
:func:`register`).

The command loads the scenario (a trajectory: queries in time order with odometry; e.g. one written by
``factorloc convert`` from a bag, or :func:`factorloc.evaluation.places.simulated_track`) and the map of places
(``--map``, a map directory written by :meth:`factorloc.places.PlaceMap.save`; default: the scenario's own
references), runs :class:`factorloc.places.Tracker` on every query with a progress bar, and writes one JSON line per
query (pose, covariance, state, places used, verdicts) and, with ``--tum``, the TUM trajectory
(``timestamp tx ty tz qx qy qz qw``) that ``evo_ape`` / ``evo_traj`` read; ``--truth-tum`` writes the queries'
ground truth the same way. Only typer and rich are imported at module level.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer

from factorloc.cli_console import console_for

console = console_for(stderr=True)


def track(
    scenario: Annotated[Path, typer.Argument(help="A scenario directory whose queries form a trajectory (docs/data-format.md).")],
    place_map: Annotated[
        Path | None,
        typer.Option("--map", help="A map of places (a scenario without queries); default: the scenario's references."),
    ] = None,
    jsonl: Annotated[Path | None, typer.Option("--jsonl", help="Write the JSON lines here instead of stdout.")] = None,
    tum: Annotated[Path | None, typer.Option("--tum", help="Write the estimated trajectory as a TUM file (evo).")] = None,
    truth_tum: Annotated[
        Path | None, typer.Option("--truth-tum", help="Write the queries' ground truth as a TUM file (evo).")
    ] = None,
    start_at_truth: Annotated[
        bool, typer.Option("--start-at-truth", help="Start from the first query's true pose instead of place recognition.")
    ] = False,
) -> None:
    """Track a robot through a map of places: one JSON line per query, a TUM trajectory for evo."""
    import numpy as np

    from factorloc._json import json_ready
    from factorloc.cli_render import progress
    from factorloc.datasets import load_scenario
    from factorloc.datasets.tum import write_tum_trajectory
    from factorloc.errors import InputError
    from factorloc.places import PlaceMap, Tracker, TrackerConfig, TrackState

    scen = load_scenario(scenario)
    if not scen.queries:
        raise InputError(f"scenario {str(scenario)!r} has no queries to track")
    pm = PlaceMap.load(place_map) if place_map is not None else PlaceMap.from_scenario(scen)
    queries = sorted(scen.queries, key=lambda q: q.timestamp_s)
    truths = [q.truth for q in queries]
    if (truth_tum is not None or start_at_truth) and any(t is None for t in truths):
        raise InputError("--truth-tum / --start-at-truth need a ground-truth pose on every query")
    config = TrackerConfig(initial_pose=truths[0] if start_at_truth else None)
    tracker = Tracker(pm, config)
    out = jsonl.open("w", encoding="utf-8") if jsonl is not None else None
    stamps, poses, states = [], [], []
    try:
        with progress(console) as advance:
            for i, q in enumerate(queries):
                r = tracker.update(q.query)
                line = {"timestamp_s": q.timestamp_s, **r.to_dict()}
                text = json.dumps(json_ready(line), allow_nan=False)
                if out is not None:
                    out.write(text + "\n")
                else:
                    typer.echo(text)
                stamps.append(q.timestamp_s)
                poses.append(r.pose.as_array())
                states.append(r.state)
                advance("tracking", i + 1, len(queries))
    finally:
        if out is not None:
            out.close()
    if tum is not None:
        write_tum_trajectory(tum, np.array(stamps), np.array(poses))
    if truth_tum is not None:
        write_tum_trajectory(truth_tum, np.array(stamps), np.array([t.as_array() for t in truths]))  # type: ignore[union-attr]
    counts = {s.value: sum(x is s for x in states) for s in TrackState}
    console.print(
        f"[bold green]✓[/] {len(queries)} queries through {len(pm)} places: "
        + ", ".join(f"{k} {v}" for k, v in counts.items())
        + (f"; trajectory in [bold]{tum}[/]" if tum is not None else "")
    )


def register(app: typer.Typer) -> None:
    """Add ``track`` to the ``factorloc`` app (with the app's one-line error handling)."""
    from factorloc.cli import one_line_errors

    app.command("track")(one_line_errors(track))

"""``factorloc map LOG OUT_DIR``: a laser log → a pose graph of places (registered by :func:`register`).

The command parses, reads the log (a ROS 1/2 bag with :func:`~factorloc.datasets.rosbag.read_laser_log`, or a
CARMEN ``.log``/``.clf`` with :func:`~factorloc.datasets.carmen.read_carmen`), calls
:func:`factorloc.mapping.build_map` and :func:`factorloc.mapping.io.save_map`, and prints what was built. Only
typer and rich are imported at module level, so that ``factorloc --help`` stays fast.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Annotated

import typer

from factorloc.cli_console import console_for

console = console_for()


def read_log(path: Path, scan_topic: str = "/scan", odom_topic: str = "/odom", max_scans: int | None = None):  # noqa: ANN201
    """The laser log at ``path`` (bag or CARMEN by suffix), optionally cut to its first ``max_scans`` scans."""
    from factorloc.datasets.rosbag import LaserLog, ScanTrack, read_laser_log

    if path.suffix in (".log", ".clf", ".gfs"):
        from factorloc.datasets.carmen import read_carmen

        log = read_carmen(path)
    else:
        log = read_laser_log(path, scan_topic, odom_topic)
    if max_scans is not None and max_scans < len(log.scans):
        log = LaserLog(log.odometry, ScanTrack(log.scans.stamps_s[:max_scans], log.scans.scans[:max_scans]), log.source)
    return log


def map_command(
    log_path: Annotated[Path, typer.Argument(metavar="LOG", help="A ROS 1 .bag / ROS 2 bag directory, or a CARMEN log.")],
    out: Annotated[
        Path,
        typer.Argument(metavar="OUT_DIR", help="Directory for places.json, trajectory.tum, place_map/ (track --map), map.png."),
    ],
    spacing: Annotated[float, typer.Option("--spacing", help="Metres of odometry path between places.")] = 0.5,
    turn_deg: Annotated[float, typer.Option("--turn-deg", help="Degrees of rotation between places.")] = 20.0,
    robust: Annotated[str, typer.Option("--robust", help="Back end: gnc, huber, cauchy or none.")] = "gnc",
    no_refine: Annotated[bool, typer.Option("--no-refine", help="Hang scans from their place by odometry only.")] = False,
    recognition_every: Annotated[
        int,
        typer.Option(
            "--recognition-every",
            help="Also propose loop closures by place recognition at every N-th place (0: off; docs/mapping.md).",
        ),
    ] = 0,
    max_scans: Annotated[int | None, typer.Option("--max-scans", help="Use only the first N scans.")] = None,
    scan_topic: Annotated[str, typer.Option("--scan-topic", help="sensor_msgs/LaserScan topic of a bag.")] = "/scan",
    odom_topic: Annotated[str, typer.Option("--odom-topic", help="nav_msgs/Odometry topic of a bag.")] = "/odom",
    no_figure: Annotated[bool, typer.Option("--no-figure", help="Do not draw map.png.")] = False,
    place_covariance: Annotated[
        str,
        typer.Option(
            "--place-covariance",
            help="What place_map/'s places carry: marginal (the graph's, map frame), local (relative to their "
            "neighbours) or none (docs/mapping.md).",
        ),
    ] = "marginal",
) -> None:
    """Map a building from one run: places, loop closures verified by ICP, a robust pose graph (docs/mapping.md)."""
    from factorloc.errors import FactorlocError, InputError
    from factorloc.mapping import MapConfig, build_map
    from factorloc.mapping.io import save_map
    from factorloc.mapping.result import PLACE_COVARIANCES

    t0 = time.perf_counter()
    try:
        if place_covariance not in PLACE_COVARIANCES:
            raise InputError(f"--place-covariance must be one of {', '.join(PLACE_COVARIANCES)}, got {place_covariance!r}")
        config = MapConfig(
            place_spacing_m=spacing,
            place_turn_rad=math.radians(turn_deg),
            robust=robust,
            refine_scans=not no_refine,
            recognition_every=recognition_every,
        )
        log = read_log(log_path, scan_topic, odom_topic, max_scans)
        t_read = time.perf_counter() - t0
        result = build_map(log, config)
        paths = save_map(result, out, figure=not no_figure, place_covariance=place_covariance)
    except FactorlocError as exc:
        console.print(f"[bold red]error:[/] {exc}")
        raise typer.Exit(code=2) from None
    s = result.stats
    console.print(
        f"[bold green]✓[/] {s['places']} places from {len(log.scans)} scans (read {t_read:.1f} s, mapped "
        f"{s['seconds_total']:.1f} s): {s['scan_factors']} consecutive scan matches, "
        f"{s['closures_accepted']} loop closures accepted of {s['closures_proposed']} proposed "
        f"({s['closures_reliable']} reliable), {s['scans_refined']} scans refined by ICP"
    )
    console.print(f"wrote {', '.join(str(p) for p in paths)}")
    console.print("[dim]Next: factorloc evaluate; benchmarks/bench_map.py --log intel; docs/mapping.md[/]")


def register(app: typer.Typer) -> None:
    """Add ``map`` to the ``factorloc`` app."""
    app.command("map")(map_command)

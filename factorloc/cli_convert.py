"""``factorloc convert BAG OUT``: a robot's bag → a scenario directory (registered by :func:`register`).

The command parses, calls :func:`factorloc.datasets.bag.convert_bag` and
:func:`factorloc.datasets.save_scenario`, and prints what was converted. Only
typer and rich are imported at module level: the library is imported when the
command runs, so that ``factorloc --help`` stays fast.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Annotated, Any

import typer

from factorloc.cli_console import console_for

console = console_for()


def _extrinsics(values: list[str]) -> dict[str, Any]:
    """``FRAME=x,y,yaw`` or ``FRAME=x,y,z,roll,pitch,yaw`` (m, degrees) → ``{frame: Rigid3 T_robot_frame}``."""
    from factorloc.datasets.bag import Rigid3
    from factorloc.errors import InputError

    out = {}
    for v in values:
        frame, sep, rest = v.partition("=")
        try:
            nums = [float(x) for x in rest.split(",")] if sep else []
        except ValueError:
            nums = []
        if not frame or len(nums) not in (3, 6) or not all(math.isfinite(x) for x in nums):
            raise InputError(f"--extrinsic {v!r}: expected FRAME=x,y,yaw or FRAME=x,y,z,roll,pitch,yaw (metres, degrees)")
        x, y, z, r, p, w = (nums[0], nums[1], 0.0, 0.0, 0.0, nums[2]) if len(nums) == 3 else nums
        out[frame.lstrip("/")] = Rigid3.from_xyz_rpy(x, y, z, math.radians(r), math.radians(p), math.radians(w))
    return out


def _times(text: str | None, start_s: float) -> tuple[float, ...]:
    """``"12.5,+30"``: absolute stamps (s), or with ``+`` seconds after the bag's first odometry message."""
    from factorloc.errors import InputError

    if not text:
        return ()
    out = []
    for part in text.split(","):
        p = part.strip()
        try:
            out.append(start_s + float(p[1:]) if p.startswith("+") else float(p))
        except ValueError as exc:
            raise InputError(f"--reference-times: {p!r} is not a time in seconds") from exc
    return tuple(out)


def convert(
    bag: Annotated[Path, typer.Argument(help="A ROS 1 .bag file, or a ROS 2 bag directory (sqlite3 or MCAP).")],
    out: Annotated[Path, typer.Argument(help="The scenario directory to write (docs/data-format.md).")],
    relations: Annotated[
        Path | None, typer.Option("--relations", help="Ground truth: a .relations file (t1 t2 x y z roll pitch yaw per line).")
    ] = None,
    tum: Annotated[
        Path | None, typer.Option("--tum", help="Ground truth: a TUM trajectory (t x y z qx qy qz qw per line, world frame).")
    ] = None,
    reference_every: Annotated[float, typer.Option("--reference-every", help="Metres of path between references.")] = 5.0,
    reference_times: Annotated[
        str | None,
        typer.Option("--reference-times", help="Comma-separated reference times (s; '+12' = 12 s after the bag's start)."),
    ] = None,
    query_every: Annotated[float, typer.Option("--query-every", help="Metres of path between queries (0: all).")] = 0.5,
    odometry_topic: Annotated[str | None, typer.Option("--odometry-topic", help="nav_msgs/Odometry topic.")] = None,
    scan_topic: Annotated[str | None, typer.Option("--scan-topic", help="sensor_msgs/LaserScan topic ('' for none).")] = None,
    cloud_topic: Annotated[str | None, typer.Option("--cloud-topic", help="sensor_msgs/PointCloud2 topic ('' for none).")] = None,
    camera_topic: Annotated[
        list[str] | None, typer.Option("--camera-topic", help="Image/CompressedImage topic (repeat; default: all colour ones).")
    ] = None,
    no_cameras: Annotated[bool, typer.Option("--no-cameras", help="Convert no camera topic.")] = False,
    robot_frame: Annotated[str | None, typer.Option("--robot-frame", help="Frame to move the sensors into.")] = None,
    extrinsic: Annotated[
        list[str] | None,
        typer.Option("--extrinsic", help="FRAME=x,y,yaw or FRAME=x,y,z,roll,pitch,yaw (m, deg): T_robot_FRAME, wins over TF."),
    ] = None,
    sync_tolerance: Annotated[float, typer.Option("--sync-tolerance", help="Seconds between a keyframe and its sensors.")] = 0.05,
    hfov_deg: Annotated[float | None, typer.Option("--hfov-deg", help="Horizontal FOV of cameras without CameraInfo.")] = None,
    max_range: Annotated[float | None, typer.Option("--max-range", help="Drop laser returns beyond this (m).")] = None,
    cloud_voxel: Annotated[float | None, typer.Option("--cloud-voxel", help="Keep one cloud point per cube (m).")] = None,
    odometry_model: Annotated[
        Path | None,
        typer.Option("--odometry-model", help="YAML of factorloc.OdometryModel's five numbers (default: the defaults)."),
    ] = None,
    image_format: Annotated[str, typer.Option("--image-format", help="png (lossless) or jpg query images.")] = "png",
    overwrite: Annotated[bool, typer.Option("--overwrite", help="Replace an existing scenario directory.")] = False,
    json_out: Annotated[Path | None, typer.Option("--json", help="Write the conversion report as JSON.")] = None,
) -> None:
    """Convert a robot's bag into a scenario: odometry, laser, clouds and cameras in the robot frame, ground truth."""
    import yaml
    from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

    from factorloc import OdometryModel
    from factorloc.datasets import save_scenario
    from factorloc.datasets.bag import ConvertConfig, SensorConfig, bag_topics, convert_bag, resolve_topics
    from factorloc.datasets.rosbag import read_odometry
    from factorloc.errors import FactorlocError, InputError

    try:
        if out.exists() and out.is_dir() and any(out.iterdir()) and not overwrite:
            raise InputError(f"{out} exists and is not empty: pass --overwrite to replace it")
        if relations is not None and tum is not None:
            raise InputError("give one ground truth: --relations or --tum, not both")
        truth = None
        if relations is not None:
            from factorloc.evaluation.relations import read_relations

            truth = read_relations(relations)
        elif tum is not None:
            from factorloc.datasets.tum import read_tum_trajectory

            truth = read_tum_trajectory(tum)
        model = OdometryModel()
        if odometry_model is not None:
            if not odometry_model.is_file():
                raise InputError(f"--odometry-model: {odometry_model} does not exist")
            model = OdometryModel.from_dict(yaml.safe_load(odometry_model.read_text()) or {})
        start = 0.0
        if reference_times and "+" in reference_times:
            topic = odometry_topic or resolve_topics(bag_topics(bag), scan="", cloud="", cameras=()).odometry
            start = float(read_odometry(bag, topic).stamps_s[0])
        sensors = SensorConfig(
            odometry_topic=odometry_topic,
            scan_topic=scan_topic,
            cloud_topic=cloud_topic,
            camera_topics=() if no_cameras else (tuple(camera_topic) if camera_topic else None),
            robot_frame=robot_frame,
            extrinsics=_extrinsics(extrinsic or []),
            sync_tolerance_s=sync_tolerance,
            max_range_m=max_range,
            hfov_rad=None if hfov_deg is None else math.radians(hfov_deg),
            cloud_voxel_m=cloud_voxel,
        )
        config = ConvertConfig(
            sensors=sensors,
            reference_every_m=reference_every,
            reference_times_s=_times(reference_times, start),
            query_every_m=query_every,
            odometry_model=model,
        )
        with Progress(
            TextColumn("[bold]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(), console=console
        ) as bar:
            task = bar.add_task("reading the bag", total=None)

            def progress(stage: str, done: int, total: int) -> None:
                bar.update(task, description=stage, completed=done, total=total)

            result = convert_bag(bag, config, truth, progress=progress)
        path = save_scenario(result.scenario, out, image_format=image_format, overwrite=overwrite)
    except FactorlocError as exc:
        typer.echo("error: " + " ".join(str(exc).split()), err=True)  # one line, never wrapped (cli.error_line)
        raise typer.Exit(code=2) from None
    r = result.report
    cams = ", ".join(r.topics["cameras"]) or "none"
    console.print(
        f"wrote [bold]{path}[/]: {r.references} references, {r.queries} queries ({r.queries_with_truth} with ground truth) "
        f"from {r.keyframes} {r.topics['keyframes']} keyframes"
    )
    console.print(
        f"  odometry {r.topics['odometry']}, scan {r.topics['scan'] or 'none'}, cloud {r.topics['cloud'] or 'none'}, "
        f"cameras {cams}; robot frame {r.robot_frame}"
    )
    for frame, (x, y, z, roll, pitch, yaw) in r.extrinsics.items():
        console.print(
            f"  {frame} in {r.robot_frame}: ({x:.3f}, {y:.3f}, {z:.3f}) m, "
            f"roll {math.degrees(roll):.1f}° pitch {math.degrees(pitch):.1f}° yaw {math.degrees(yaw):.1f}°"
        )
    for sensor, n in r.missing.items():
        console.print(f"  [yellow]{n} queries have no {sensor} within {sync_tolerance} s[/]")
    for note in r.notes:
        console.print(f"  [dim]{note}[/]")
    if json_out is not None:
        json_out.parent.mkdir(parents=True, exist_ok=True)
        json_out.write_text(json.dumps(r.to_dict(), indent=2))
    console.print(f"[dim]Next: factorloc evaluate {out}[/]")


def register(app: typer.Typer) -> None:
    """Add ``convert`` to the ``factorloc`` app."""
    app.command("convert")(convert)

"""A robot's bag → a scenario: references along its path, queries between them, ground truth when known.

:func:`convert_bag` is what ``factorloc convert BAG OUT`` runs. It

1. finds the topics (:func:`~factorloc.datasets.bag.read.resolve_topics`) and reads the
   odometry, the TF tree, the cameras' intrinsics and the laser scans
   (:func:`~factorloc.datasets.bag.read.read_bag_index`);
2. picks *keyframes*: the stamps of the first sensor of laser scan, point cloud, camera,
   where the odometry has a message within ``sync_tolerance_s``; every other sensor
   of a keyframe is the message stamped nearest to it within the same tolerance (else the
   query lacks that sensor, and the report counts it);
3. moves every sensor into the robot frame: the extrinsics come from the bag's
   ``/tf_static`` (or ``/tf``, interpolated at the message's time for a moving head), or from
   ``ConvertConfig.extrinsics``; the robot's motion between a sensor's stamp and its
   keyframe (odometry) is compensated;
4. places references every ``reference_every_m`` metres of path (or at
   ``reference_times_s``), each with the keyframe's scan, the clouds of the time the robot
   stood within ``stationary_radius_m`` of that spot (a depth camera turning on the spot
   gives a 360° cloud) and, when the cameras saw the spot from several yaws while the robot
   stood there, a panorama stitched from those views
   (:func:`factorloc.vision.panoramas.panorama_from_images`);
5. makes a query of every keyframe ``query_every_m`` metres apart, localized against the
   reference nearest along the path, with the odometry dead-reckoned from that reference
   and σ from ``odometry_model`` (:class:`factorloc.OdometryModel`).

Ground truth (``truth``): a trajectory ``T_world_robot`` (an
:class:`~factorloc.datasets.rosbag.OdometryTrack`, e.g. read by
:func:`factorloc.datasets.tum.read_tum_trajectory`) places the references at their true
poses and gives each query its true pose; relations (``t1 t2 x y yaw``, e.g.
:func:`factorloc.evaluation.relations.read_relations`) make each relation ``t1 → t2`` a
query at ``t2`` against a reference at ``t1`` (``reference_every_m`` then spaces the
``t1`` kept) — the world frame is then the odometry's, and the truth is
``odom(t1)·T_12``. Without truth, the world frame is the odometry's.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from factorloc._validate import nonnegative_float, positive_float
from factorloc.datasets.bag.sensors import BagSensors, SensorConfig, open_bag_sensors
from factorloc.datasets.rosbag import OdometryTrack
from factorloc.datasets.scenario import Scenario, ScenarioQuery, ScenarioReference
from factorloc.errors import DatasetError, InputError
from factorloc.geometry import Pose2
from factorloc.odometry_model import OdometryModel, RelativePoses
from factorloc.types import Query

_log = logging.getLogger(__name__)

__all__ = ["Conversion", "ConversionReport", "ConvertConfig", "convert_bag"]

Progress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class ConvertConfig:
    """How :func:`convert_bag` makes a scenario of a bag (see the module docstring).

    Parameters
    ----------
    sensors
        Topics, frames, extrinsics and the sync tolerance (:class:`~factorloc.datasets.bag.sensors.SensorConfig`).
    reference_every_m
        Path length between references (m); ignored when ``reference_times_s`` is given.
    reference_times_s
        Times of the references (bag stamps, s); each must be within the sync tolerance of a keyframe.
    query_every_m
        Path length between queries (m; 0: every keyframe). Not used with relations.
    odometry_model
        σ of the odometry as a function of the path since the reference (:class:`factorloc.OdometryModel`).
    relation_tolerance_s
        Largest time between a relation's ``t1``/``t2`` and the keyframe it names (relations are
        defined at sensor stamps; a relation whose sensor message has no odometry near it is left out).
    name
        The scenario's name (default: the bag's file name).
    """

    sensors: SensorConfig = field(default_factory=SensorConfig)
    reference_every_m: float = 5.0
    reference_times_s: tuple[float, ...] = ()
    query_every_m: float = 0.5
    odometry_model: OdometryModel = field(default_factory=OdometryModel)
    relation_tolerance_s: float = 2e-3
    name: str = ""

    def __post_init__(self) -> None:
        if not isinstance(self.sensors, SensorConfig):
            raise InputError(f"ConvertConfig.sensors must be a SensorConfig, got {type(self.sensors).__name__}")
        positive_float("ConvertConfig.reference_every_m", self.reference_every_m)
        nonnegative_float("ConvertConfig.query_every_m", self.query_every_m)
        positive_float("ConvertConfig.relation_tolerance_s", self.relation_tolerance_s)
        if not isinstance(self.odometry_model, OdometryModel):
            raise InputError(f"ConvertConfig.odometry_model must be an OdometryModel, got {type(self.odometry_model).__name__}")
        object.__setattr__(self, "reference_times_s", tuple(float(t) for t in self.reference_times_s))


@dataclass(frozen=True)
class ConversionReport:
    """What a conversion found and did: the topics, frames and extrinsics used, and what was left out.

    ``missing`` counts, per sensor, the queries that got no message of it within the tolerance;
    ``notes`` are sentences for people (skipped camera topics, references without panorama, …).
    """

    bag: str
    topics: Mapping[str, Any]
    robot_frame: str
    extrinsics: Mapping[str, list[float]]
    keyframes: int
    references: int
    queries: int
    queries_with_truth: int
    missing: Mapping[str, int]
    notes: tuple[str, ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {
            "bag": self.bag,
            "topics": dict(self.topics),
            "robot_frame": self.robot_frame,
            "extrinsics": dict(self.extrinsics),
            "keyframes": self.keyframes,
            "references": self.references,
            "queries": self.queries,
            "queries_with_truth": self.queries_with_truth,
            "missing": dict(self.missing),
            "notes": list(self.notes),
        }


@dataclass(frozen=True, eq=False)
class Conversion:
    """The scenario made from a bag, and the report of how."""

    scenario: Scenario
    report: ConversionReport


def _is_relations(truth: Any) -> bool:
    return all(hasattr(truth, k) for k in ("t1_s", "t2_s", "poses"))


def _spaced(stamps: np.ndarray, odometry: OdometryTrack, every_m: float) -> list[int]:
    """Indices of ``stamps`` (sorted) at least ``every_m`` of path apart, starting with the first."""
    path = np.asarray(odometry.path_length_m(stamps))
    out, last = [], -math.inf
    for i, s in enumerate(path):
        if s - last >= every_m - 1e-9:
            out.append(i)
            last = s
    return out


def _match(stamps: np.ndarray, t_s: float, tol: float) -> int | None:
    i = int(np.searchsorted(stamps, t_s))
    cands = [j for j in (i - 1, i) if 0 <= j < len(stamps)]
    if not cands:
        return None
    j = min(cands, key=lambda k: (abs(stamps[k] - t_s), k))
    return j if abs(stamps[j] - t_s) <= tol else None


def _references_and_queries(
    sensors: BagSensors, stamps: np.ndarray, kind: str, config: ConvertConfig, truth: Any
) -> tuple[list[float], list[tuple[float, int, Pose2 | None]]]:
    """Reference times and ``(query time, reference index, truth relative to the reference or None)``."""
    odo, tol = sensors.odometry, sensors.tol
    if truth is not None and _is_relations(truth):
        rel_t1 = np.asarray(truth.t1_s, dtype=np.float64)
        rel_t2 = np.asarray(truth.t2_s, dtype=np.float64)
        rel_p = np.asarray(truth.poses, dtype=np.float64)
        rtol = config.relation_tolerance_s
        k1 = [_match(stamps, t, rtol) for t in rel_t1]
        k2 = [_match(stamps, t, rtol) for t in rel_t2]
        ok = [i for i in range(len(rel_t1)) if k1[i] is not None and k2[i] is not None]
        if not ok:
            raise DatasetError(f"no relation's times are within {rtol} s of a {kind} keyframe with odometry")
        if len(ok) < len(rel_t1):
            sensors.notes.append(
                f"{len(rel_t1) - len(ok)} of {len(rel_t1)} relations name a time with no {kind} keyframe within {rtol} s "
                "(or no odometry around it): left out"
            )
        candidates = np.array(sorted({float(stamps[k1[i]]) for i in ok}))  # type: ignore[index]
        what = "the start of a relation"
    else:
        candidates, what = stamps, f"a {kind} keyframe with odometry"
    if config.reference_times_s:
        ref_times = []
        for t in config.reference_times_s:
            j = _match(candidates, t, tol)
            if j is None:
                raise DatasetError(f"reference time {t!r} s is not within {tol} s of {what}")
            ref_times.append(float(candidates[j]))
        ref_times = sorted(set(ref_times))
    else:
        ref_times = [float(candidates[i]) for i in _spaced(candidates, odo, config.reference_every_m)]
    if truth is not None and _is_relations(truth):
        where = {t: r for r, t in enumerate(ref_times)}
        pairs = []
        for i in ok:
            r = where.get(float(stamps[k1[i]]))  # type: ignore[index]
            if r is not None:
                pairs.append((float(stamps[k2[i]]), r, Pose2.from_array(rel_p[i])))  # type: ignore[index]
        return ref_times, pairs
    q_idx = _spaced(stamps, odo, config.query_every_m) if config.query_every_m > 0 else range(len(stamps))
    ref_path = np.asarray(odo.path_length_m(np.array(ref_times)))
    ref_set = set(ref_times)
    pairs = []
    for i in q_idx:
        t = float(stamps[i])
        if t not in ref_set:  # a query at the reference itself would be trivial
            pairs.append((t, int(np.argmin(np.abs(ref_path - odo.path_length_m(t)))), None))
    return ref_times, pairs


def convert_bag(
    path: str | Path,
    config: ConvertConfig = ConvertConfig(),
    truth: OdometryTrack | RelativePoses | None = None,
    *,
    progress: Progress | None = None,
) -> Conversion:
    """Convert a ROS 1 or ROS 2 bag into a :class:`~factorloc.datasets.Scenario` (see the module docstring).

    Parameters
    ----------
    path
        A ROS 1 ``.bag`` file or a ROS 2 bag directory (sqlite3 or MCAP).
    config
        Topics, frames, tolerances and spacing (:class:`ConvertConfig`).
    truth
        Ground truth: a trajectory ``T_world_robot`` (:class:`~factorloc.datasets.rosbag.OdometryTrack`)
        or relative poses (anything with ``t1_s``, ``t2_s``, ``poses``), or None.
    progress
        Called as ``progress(stage, done, total)``.

    Returns
    -------
    Conversion
        The scenario (save it with :func:`factorloc.datasets.save_scenario`) and a :class:`ConversionReport`.

    Raises
    ------
    DatasetError
        For an unreadable bag, a missing odometry, ambiguous topics, sensor frames the TF does not
        reach (give ``SensorConfig.extrinsics``), reference times far from every keyframe, a camera
        without intrinsics.
    """
    if not isinstance(config, ConvertConfig):
        raise InputError(f"config must be a ConvertConfig, got {type(config).__name__}")
    sensors = open_bag_sensors(path, config.sensors)
    odo, tol = sensors.odometry, sensors.tol
    kind, stamps = sensors.keyframes()
    relations = truth is not None and _is_relations(truth)
    ref_times, pairs = _references_and_queries(sensors, stamps, kind, config, truth)

    # pass 2: the clouds and images the references and queries use
    wanted: dict[str, set[int]] = {}
    for near in [sensors.wanted_within(sensors.stationary_window(t)) for t in ref_times] + [
        sensors.wanted_near(t) for t in ref_times + [t for t, _, _ in pairs]
    ]:
        for topic, times in near.items():
            wanted.setdefault(topic, set()).update(times)
    if progress:
        progress("reading clouds and images", 0, 1)
    sensors.load(wanted)

    T_world_refs: list[Pose2] = []
    references = []
    for r, t in enumerate(ref_times):
        if truth is not None and not relations:
            if truth.gap_s(t) > tol:  # type: ignore[union-attr]
                raise DatasetError(f"the ground-truth trajectory has no pose within {tol} s of reference time {t!r} s")
            T = truth.pose_at(t)  # type: ignore[union-attr]
        else:
            T = odo.pose_at(t)
        T_world_refs.append(T)
        rid = f"r{r:04d}"
        references.append(ScenarioReference(rid, sensors.reference(t, T, f"{rid} t={t:.3f}"), {"time_s": t}))
        if progress:
            progress("references", r + 1, len(ref_times))

    data = sensors.data
    missing = {"scan": 0, "cloud": 0, "images": 0, "truth": 0}
    queries = []
    for n, (t, r, rel) in enumerate(pairs):
        t_ref, T_ref = ref_times[r], T_world_refs[r]
        dist, rot = odo.distance_between(t_ref, t)
        odometry = config.odometry_model.odometry(T_ref * odo.between(t_ref, t), dist, rot)
        scan, cloud, images = sensors.scan(t), sensors.cloud_near(t), sensors.images_near(t)
        missing["scan"] += data.scans is not None and scan is None
        missing["cloud"] += data.clouds is not None and cloud is None
        missing["images"] += len(images) < len(data.cameras)
        if rel is not None:
            true = T_ref * rel
        elif truth is not None and truth.gap_s(t) <= tol:  # type: ignore[union-attr]
            true = truth.pose_at(t)  # type: ignore[union-attr]
        else:
            true = None
        missing["truth"] += truth is not None and true is None
        if scan is None and cloud is None and not images:
            continue
        q = Query(images=images, cloud=cloud, scan=scan, odometry=odometry, id=f"q{n:05d}")
        d_ref = None if true is None else math.hypot(true.x - T_ref.x, true.y - T_ref.y)
        meta = {"time_s": t, "path_from_reference_m": dist}
        queries.append(ScenarioQuery(q, t, true, (), references[r].id, d_ref, meta))
        if progress:
            progress("queries", n + 1, len(pairs))

    extr = {f: [*map(float, T.t), *map(float, T.rpy)] for f, T in sorted(sensors.used_frames.items())}
    notes = [f"camera topic {c} left out: {why}" for c, why in data.skipped.items()] + sensors.notes
    topic_info = {
        "odometry": data.topics.odometry,
        "scan": data.topics.scan,
        "cloud": data.topics.cloud,
        "cameras": list(data.cameras),
        "keyframes": kind,
    }
    meta = {
        "source": str(path),
        "topics": topic_info,
        "robot_frame": sensors.robot_frame,
        "sync_tolerance_s": tol,
        "odometry_model": config.odometry_model.to_dict(),
        "extrinsics_xyz_rpy": extr,
        "truth": "relations" if relations else ("trajectory" if truth is not None else None),
    }
    name = config.name or Path(path).name.split(".")[0] or "bag"
    scenario = Scenario(name, tuple(references), tuple(queries), description=f"converted from {path}", metadata=meta)
    report = ConversionReport(
        str(path),
        topic_info,
        sensors.robot_frame,
        extr,
        int(len(stamps)),
        len(references),
        len(queries),
        sum(q.truth is not None for q in queries),
        {k: int(v) for k, v in missing.items() if v},
        tuple(notes),
    )
    _log.info(
        "converted %s: %d references, %d queries (%d with truth)",
        path,
        report.references,
        report.queries,
        report.queries_with_truth,
    )
    return Conversion(scenario, report)

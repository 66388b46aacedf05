"""Reading a scenario directory: :func:`load_scenario` validates every field and file it reads.

Values are checked with the library's input rules (:mod:`factorloc._validate`); every problem raises a
:class:`~factorloc.errors.DatasetError` naming the manifest, the field and, for data files, the file.
"""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import yaml

from factorloc._validate import _short, keys_problem, number_problem
from factorloc._yaml import load_yaml
from factorloc.datasets.points_io import read_points
from factorloc.datasets.scenario import FORMAT_NAME, FORMAT_VERSION, Scenario, ScenarioQuery, ScenarioReference
from factorloc.errors import DatasetError, InputError
from factorloc.geometry import Pose2
from factorloc.types import CameraImage, Odometry, Panorama, PointCloud, Query, Reference, Scan

__all__ = ["load_scenario", "scenario_files"]

# The keys each mapping of a manifest may hold (what :func:`factorloc.datasets.save_scenario` writes); any other
# is an error naming it and the nearest known one (a misspelt ``odometery:`` must not load a query without odometry).
POSE_KEYS = frozenset({"x_m", "y_m", "theta_rad"})
MANIFEST_KEYS = {
    "": frozenset({"format", "format_version", "name", "description", "seed", "world", "metadata", "references", "queries"}),
    "reference": frozenset({"id", "name", "T_world_reference", "panorama", "cloud", "scan", "metadata"}),
    "query": frozenset(
        {
            "id",
            "timestamp_s",
            "reference",
            "truth",
            "odometry",
            "faults",
            "distance_from_reference_m",
            "images",
            "panorama",
            "cloud",
            "scan",
            "metadata",
        }
    ),  # fmt: skip
    "pose": POSE_KEYS,
    "odometry": POSE_KEYS | {"sigma_x_m", "sigma_y_m", "sigma_theta_rad"},
    "image": frozenset({"file", "width_px", "height_px", "hfov_rad", "yaw_in_robot_rad", "pitch_rad", "cx_px"}),
    "panorama": frozenset({"file", "width_px", "height_px", "fov_v_rad", "azimuth_col0_rad", "seen_columns"}),
    "points": frozenset({"file", "points"}),
}


class _Ctx:
    """Reads the fields of one manifest; a bad value raises a :class:`DatasetError` naming the manifest and the field."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.manifest = root / "scenario.yaml"

    def fail(self, fieldname: str, message: str) -> DatasetError:
        return DatasetError(f"{self.manifest}: field '{fieldname}': {message}")

    @contextlib.contextmanager
    def at(self, fieldname: str) -> Iterator[None]:
        """Turn an :class:`InputError` raised by a constructor into a :class:`DatasetError` naming the field."""
        try:
            yield
        except DatasetError:
            raise
        except InputError as exc:
            raise self.fail(fieldname, str(exc)) from exc

    def keys(self, d: Any, where: str, kind: str) -> None:
        """Raise naming the first key of the mapping ``d`` that a ``kind`` mapping does not hold (:data:`MANIFEST_KEYS`)."""
        if not isinstance(d, Mapping):
            raise self.fail(where or "(top level)", f"must be a mapping, got {type(d).__name__}")
        problem = keys_problem(d, MANIFEST_KEYS[kind])
        if problem:
            raise self.fail(where or "(top level)", problem)

    def ident(self, d: Any, where: str) -> str:
        """The ``id`` of an entry: a string (or an integer written as one), never null or a boolean."""
        v = self.get(d, "id", where)
        if v is None or isinstance(v, bool) or not isinstance(v, (str, int)):
            raise self.fail(f"{where}.id", f"must be a string, got {type(v).__name__} {v!r}")
        return str(v)

    def get(self, d: Any, key: str, where: str, *, required: bool = True, default: Any = None) -> Any:
        if not isinstance(d, Mapping):
            raise self.fail(where, f"must be a mapping, got {type(d).__name__}")
        if key not in d:
            if required:
                raise self.fail(f"{where}.{key}" if where else key, "is missing")
            return default
        return d[key]

    def number(self, d: Any, key: str, where: str, *, required: bool = True, default: Any = None, positive: bool = False) -> Any:
        v = self.get(d, key, where, required=required, default=default)
        if v is None and not required:
            return default
        problem = number_problem(v, positive=positive)
        if problem:
            raise self.fail(f"{where}.{key}" if where else key, problem)
        return float(v)

    def pose(self, d: Any, where: str, kind: str = "pose") -> Pose2:
        self.keys(d, where, kind)
        x, y, t = self.number(d, "x_m", where), self.number(d, "y_m", where), self.number(d, "theta_rad", where)
        with self.at(where):
            return Pose2(x, y, t)

    def file(self, d: Any, where: str) -> Path:
        rel = self.get(d, "file", where)
        if not isinstance(rel, str) or not rel:
            raise self.fail(f"{where}.file", f"must be a relative path, got {rel!r}")
        p = (self.root / rel).resolve()
        if not p.is_relative_to(self.root.resolve()):
            raise self.fail(f"{where}.file", f"{rel!r} points outside the scenario directory")
        if not p.is_file():
            raise DatasetError(f"{self.manifest}: field '{where}.file': file {str(self.root / rel)!r} does not exist")
        return p

    def image(self, d: Any, where: str, kind: str = "image") -> np.ndarray:
        self.keys(d, where, kind)
        p = self.file(d, where)
        img = cv2.imread(str(p), cv2.IMREAD_COLOR)
        if img is None:
            raise DatasetError(f"{self.manifest}: field '{where}.file': {str(p)!r} is not a readable image")
        w = self.get(d, "width_px", where, required=False)
        h = self.get(d, "height_px", where, required=False)
        if (w is not None and w != img.shape[1]) or (h is not None and h != img.shape[0]):
            raise DatasetError(
                f"{self.manifest}: field '{where}': wrong image size: {str(p)!r} is {img.shape[1]}×{img.shape[0]} px, "
                f"the manifest says {w}×{h}"
            )
        return img

    def points(self, d: Any, where: str, ncols: int) -> np.ndarray:
        self.keys(d, where, "points")
        p = self.file(d, where)
        try:
            arr = read_points(p, ncols)
        except DatasetError as exc:
            raise DatasetError(f"{self.manifest}: field '{where}.file': {exc}") from exc
        except OSError as exc:
            raise DatasetError(f"{self.manifest}: field '{where}.file': {str(p)!r} cannot be read: {exc}") from exc
        if arr.ndim != 2 or arr.shape[1] != ncols or arr.shape[0] < 1:
            raise DatasetError(
                f"{self.manifest}: field '{where}.file': {str(p)!r} must hold an N×{ncols} array, got shape {arr.shape}"
            )
        if not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
            raise DatasetError(f"{self.manifest}: field '{where}.file': {str(p)!r} must hold numbers, got dtype {arr.dtype}")
        if not np.all(np.isfinite(arr)):
            raise DatasetError(f"{self.manifest}: field '{where}.file': {str(p)!r} contains NaN or infinite values")
        n = self.get(d, "points", where, required=False)
        if n is not None and n != arr.shape[0]:
            raise DatasetError(
                f"{self.manifest}: field '{where}.points': says {_short(n)} points, {str(p)!r} holds {arr.shape[0]}"
            )
        return arr


def load_scenario(path: str | Path) -> Scenario:
    """Read a scenario directory (or its ``scenario.yaml``) written by :func:`save_scenario` or by hand.

    Raises
    ------
    DatasetError
        With the manifest path and the field, for: a missing directory, manifest
        or data file; an unknown format or version; a missing or non-numeric
        field; NaN/infinite poses or sigmas; an image whose size differs from
        the manifest; a cloud/scan of the wrong shape or with NaNs; duplicate
        ids; a query naming an unknown reference.
    """
    root = Path(path)
    if root.is_file() and root.name.endswith((".yaml", ".yml")):
        root = root.parent
    ctx = _Ctx(root)
    if not root.is_dir():
        raise DatasetError(f"scenario directory {str(root)!r} does not exist")
    if not ctx.manifest.is_file():
        raise DatasetError(f"{ctx.manifest}: the manifest scenario.yaml does not exist")
    try:
        m = load_yaml(ctx.manifest.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise DatasetError(f"{ctx.manifest}: cannot be parsed as YAML: {exc}") from exc
    if not isinstance(m, Mapping):
        raise DatasetError(f"{ctx.manifest}: the manifest must be a mapping, got {type(m).__name__}")
    ctx.keys(m, "", "")
    fmt = ctx.get(m, "format", "")
    if fmt != FORMAT_NAME:
        raise ctx.fail("format", f"must be {FORMAT_NAME!r}, got {fmt!r}")
    version = ctx.get(m, "format_version", "")
    if version != FORMAT_VERSION:
        raise ctx.fail("format_version", f"unknown version {version!r}; this factorloc reads version {FORMAT_VERSION}")

    world = None
    wref = ctx.get(m, "world", "", required=False)
    if wref is not None:
        from factorloc.sim.world import load_world, world_by_name

        if not isinstance(wref, str):
            raise ctx.fail("world", f"must be a file name or a built-in world name, got {wref!r}")
        wpath = root / wref
        with ctx.at("world"):
            world = load_world(wpath) if wpath.suffix.lower() in (".yaml", ".yml", ".json") else world_by_name(wref)

    refs = ctx.get(m, "references", "")
    if not isinstance(refs, list) or not refs:
        raise ctx.fail("references", f"must be a non-empty list, got {refs!r}")
    references = [_load_reference(ctx, r, f"references[{i}]") for i, r in enumerate(refs)]
    qs = ctx.get(m, "queries", "")
    if not isinstance(qs, list):
        raise ctx.fail("queries", f"must be a list, got {type(qs).__name__}")
    queries = [_load_query(ctx, e, f"queries[{i}]", references[0].id) for i, e in enumerate(qs)]
    with ctx.at("(scenario)"):
        return Scenario(
            name=str(ctx.get(m, "name", "")),
            references=tuple(references),
            queries=tuple(queries),
            world=world,
            seed=ctx.get(m, "seed", "", required=False),
            description=str(ctx.get(m, "description", "", required=False, default="") or ""),
            metadata=ctx.get(m, "metadata", "", required=False, default={}) or {},
        )


def _optional_sensors(ctx: _Ctx, d: Any, where: str) -> tuple[Panorama | None, PointCloud | None, Scan | None]:
    pano = cloud = scan = None
    if ctx.get(d, "panorama", where, required=False) is not None:
        pano = _read_panorama(ctx, d["panorama"], f"{where}.panorama")
    if ctx.get(d, "cloud", where, required=False) is not None:
        pts = ctx.points(d["cloud"], f"{where}.cloud", 3)
        with ctx.at(f"{where}.cloud"):
            cloud = PointCloud(pts)
    if ctx.get(d, "scan", where, required=False) is not None:
        pts = ctx.points(d["scan"], f"{where}.scan", 2)
        with ctx.at(f"{where}.scan"):
            scan = Scan(pts)
    return pano, cloud, scan


def _load_reference(ctx: _Ctx, r: Any, where: str) -> ScenarioReference:
    ctx.keys(r, where, "reference")
    rid = ctx.ident(r, where)
    pano, cloud, scan = _optional_sensors(ctx, r, where)
    T = ctx.pose(ctx.get(r, "T_world_reference", where), f"{where}.T_world_reference")
    name = str(ctx.get(r, "name", where, required=False, default="reference"))
    with ctx.at(where):
        ref = Reference(pano, cloud, scan, T, name)
        return ScenarioReference(rid, ref, ctx.get(r, "metadata", where, required=False, default={}) or {})


def _load_query(ctx: _Ctx, e: Any, where: str, default_reference: str) -> ScenarioQuery:
    ctx.keys(e, where, "query")
    qid = ctx.ident(e, where)
    images = []
    ims = ctx.get(e, "images", where, required=False, default=[]) or []
    if not isinstance(ims, list):
        raise ctx.fail(f"{where}.images", f"must be a list, got {type(ims).__name__}")
    for j, im in enumerate(ims):
        w2 = f"{where}.images[{j}]"
        img = ctx.image(im, w2)
        hfov = ctx.number(im, "hfov_rad", w2, positive=True)
        yaw = ctx.number(im, "yaw_in_robot_rad", w2, required=False, default=0.0)
        pitch = ctx.number(im, "pitch_rad", w2, required=False, default=0.0)
        cx = ctx.number(im, "cx_px", w2, required=False, default=None)
        with ctx.at(w2):
            images.append(CameraImage(img, hfov, yaw, pitch, cx))
    odo = None
    o = ctx.get(e, "odometry", where, required=False)
    if o is not None:
        wo = f"{where}.odometry"
        pose = ctx.pose(o, wo, "odometry")
        sig = [ctx.number(o, k, wo, positive=True) for k in ("sigma_x_m", "sigma_y_m", "sigma_theta_rad")]
        with ctx.at(wo):
            odo = Odometry(pose, *sig)
    pano, cloud, scan = _optional_sensors(ctx, e, where)
    t = ctx.get(e, "truth", where, required=False)
    truth = None if t is None else ctx.pose(t, f"{where}.truth")
    faults = ctx.get(e, "faults", where, required=False, default=[]) or []
    if not isinstance(faults, list):
        raise ctx.fail(f"{where}.faults", f"must be a list of tags, got {faults!r}")
    dist = ctx.number(e, "distance_from_reference_m", where, required=False, default=None)
    timestamp = ctx.number(e, "timestamp_s", where, required=False, default=0.0)
    ref_id = str(ctx.get(e, "reference", where, required=False, default=default_reference))
    metadata = ctx.get(e, "metadata", where, required=False, default={}) or {}
    with ctx.at(where):
        query = Query(tuple(images), pano, cloud, scan, odo, str(qid))
        return ScenarioQuery(query, timestamp, truth, tuple(faults), ref_id, dist, metadata)


def _read_panorama(ctx: _Ctx, d: Any, where: str) -> Panorama:
    img = ctx.image(d, where, "panorama")
    fov = ctx.number(d, "fov_v_rad", where, positive=True)
    az0 = ctx.number(d, "azimuth_col0_rad", where, required=False, default=math.pi)
    seen = _seen_columns(ctx, ctx.get(d, "seen_columns", where, required=False), img.shape[1], where)
    with ctx.at(where):
        return Panorama(img, fov, az0, seen)


def _seen_columns(ctx: _Ctx, runs: Any, width: int, where: str) -> np.ndarray | None:
    """``Panorama.seen_columns`` from its manifest form, ``[[start, stop), …]`` column runs (None: all seen)."""
    if runs is None:
        return None
    ok = isinstance(runs, list) and all(
        isinstance(r, list)
        and len(r) == 2
        and all(isinstance(v, int) and not isinstance(v, bool) for v in r)
        and 0 <= r[0] < r[1] <= width
        for r in runs
    )
    if not ok:
        raise ctx.fail(f"{where}.seen_columns", f"must be a list of [start, stop) column runs within [0, {width}], got {runs!r}")
    seen = np.zeros(width, dtype=bool)
    for a, b in runs:
        seen[a:b] = True
    return seen


def scenario_files(path: str | Path) -> Sequence[Path]:
    """Every file of the scenario directory at ``path`` (manifest first), for hashing or copying."""
    root = Path(path)
    files = sorted(p for p in root.rglob("*") if p.is_file())
    return [root / "scenario.yaml"] + [p for p in files if p.name != "scenario.yaml" or p.parent != root]

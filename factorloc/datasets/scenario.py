"""The on-disk scenario format: references, queries with ground truth and fault tags, and the world.

A scenario is a directory (format described in ``docs/data-format.md``)::

    scenario.yaml                 manifest: format, version, name, references, queries
    world.yaml                    the floor plan (optional; factorloc.sim world format)
    references/<id>/panorama.png  reference panorama (BGR, lossless)
    references/<id>/cloud.npy     reference cloud, N×3 float32/float64, robot frame (z from the floor)
    references/<id>/scan.npy      reference scan, N×2
    queries/<id>/image0.png       camera images (PNG, or JPEG when saved so)
    queries/<id>/cloud.npy        query cloud (.npy, .npz with key ``points_m``, or .ply)

:func:`save_scenario` and :func:`load_scenario` round-trip exactly (PNG and
``.npy`` are lossless; clouds are stored as float32 when that is exact, else
float64). Loading validates everything and raises
:class:`~factorloc.errors.DatasetError` naming the file and the field.
"""

from __future__ import annotations

import contextlib
import math
import re
import shutil
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from types import MappingProxyType
from typing import Any

import cv2
import numpy as np
import yaml

from factorloc.errors import DatasetError, InputError, UnknownIdError
from factorloc.geometry import Pose2
from factorloc.sim.world import World
from factorloc.types import CameraImage, Odometry, Panorama, PointCloud, Query, Reference, Scan

#: The value of ``format`` in every manifest.
FORMAT_NAME = "factorloc-scenario"
#: The manifest version this module writes and reads.
FORMAT_VERSION = 1
#: Fault tags the simulator writes (a scenario may carry others).
FAULT_TAGS = ("kidnapped", "occlusion", "lighting", "blur", "depth_dropout", "glass", "corridor")

_ID = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.-]*$")


# --------------------------------------------------------------------------
# In memory
# --------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class ScenarioReference:
    """One reference of a scenario: a :class:`~factorloc.Reference` with an id and free metadata.

    ``metadata`` holds JSON/YAML-able values (e.g. the panorama camera's
    ``height_m``); it is stored verbatim in the manifest.
    """

    id: str
    reference: Reference
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        _check_id("ScenarioReference.id", self.id)
        if not isinstance(self.reference, Reference):
            raise InputError(
                f"ScenarioReference({self.id}).reference must be a factorloc.Reference, got {type(self.reference).__name__}"
            )
        object.__setattr__(self, "metadata", _frozen_metadata(f"ScenarioReference({self.id}).metadata", self.metadata))

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ScenarioReference):
            return NotImplemented
        return (
            self.id == other.id
            and _reference_equal(self.reference, other.reference)
            and dict(self.metadata) == dict(other.metadata)
        )

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True, eq=False)
class ScenarioQuery:
    """One query of a scenario.

    Parameters
    ----------
    query
        What the robot sensed (:class:`~factorloc.Query`; its ``id`` is the query's id).
        ``query.odometry`` is the dead-reckoned pose in the world frame with its sigmas.
    timestamp_s
        Time of the query (s, any epoch; non-decreasing along the scenario is not required).
    truth
        Ground-truth ``T_world_robot`` (None when unknown).
    faults
        Fault tags (see :data:`FAULT_TAGS`); empty when clean.
    reference_id
        Id of the reference this query is localized against.
    distance_from_reference_m
        Distance between the true pose and the reference pose (m), when known.
    metadata
        Free YAML-able values (fault parameters, path length since the last odometry reset, …).
    """

    query: Query
    timestamp_s: float = 0.0
    truth: Pose2 | None = None
    faults: tuple[str, ...] = ()
    reference_id: str = "ref0"
    distance_from_reference_m: float | None = None
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.query, Query):
            raise InputError(f"ScenarioQuery.query must be a factorloc.Query, got {type(self.query).__name__}")
        _check_id("ScenarioQuery.query.id", self.query.id)
        t = self.timestamp_s
        if isinstance(t, bool) or not isinstance(t, (int, float, np.integer, np.floating)) or not math.isfinite(float(t)):
            raise InputError(f"ScenarioQuery({self.query.id}).timestamp_s must be a finite number, got {t!r}")
        object.__setattr__(self, "timestamp_s", float(t))
        if self.truth is not None and not isinstance(self.truth, Pose2):
            raise InputError(f"ScenarioQuery({self.query.id}).truth must be a Pose2 or None, got {type(self.truth).__name__}")
        faults = (self.faults,) if isinstance(self.faults, str) else tuple(self.faults)
        for f in faults:
            if not isinstance(f, str) or not _ID.match(f):
                raise InputError(f"ScenarioQuery({self.query.id}).faults must be identifier-like strings, got {f!r}")
        object.__setattr__(self, "faults", faults)
        _check_id(f"ScenarioQuery({self.query.id}).reference_id", self.reference_id)
        d = self.distance_from_reference_m
        if d is not None:
            if (
                isinstance(d, bool)
                or not isinstance(d, (int, float, np.integer, np.floating))
                or not (math.isfinite(float(d)) and d >= 0)
            ):
                raise InputError(
                    f"ScenarioQuery({self.query.id}).distance_from_reference_m must be a finite number >= 0 or None, got {d!r}"
                )
            object.__setattr__(self, "distance_from_reference_m", float(d))
        object.__setattr__(self, "metadata", _frozen_metadata(f"ScenarioQuery({self.query.id}).metadata", self.metadata))

    @property
    def id(self) -> str:
        return self.query.id

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, ScenarioQuery):
            return NotImplemented
        return (
            _query_equal(self.query, other.query)
            and self.timestamp_s == other.timestamp_s
            and self.truth == other.truth
            and self.faults == other.faults
            and self.reference_id == other.reference_id
            and self.distance_from_reference_m == other.distance_from_reference_m
            and dict(self.metadata) == dict(other.metadata)
        )

    __hash__ = None  # type: ignore[assignment]


@dataclass(frozen=True, eq=False)
class Scenario:
    """A localization scenario: references, queries (with ground truth and faults), the world.

    Parameters
    ----------
    name
        A short name.
    references
        One or more :class:`ScenarioReference` with distinct ids.
    queries
        :class:`ScenarioQuery` objects with distinct ids, each naming an existing reference.
    world
        The floor plan the data came from (:class:`factorloc.sim.World`), or None.
    seed
        The seed it was generated from (None for recorded data).
    description
        Free text.
    metadata
        Free YAML-able values (generator parameters, sensor heights, …).
    """

    name: str
    references: tuple[ScenarioReference, ...]
    queries: tuple[ScenarioQuery, ...]
    world: World | None = None
    seed: int | None = None
    description: str = ""
    metadata: Mapping[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise InputError(f"Scenario.name must be a non-empty string, got {self.name!r}")
        refs = tuple(self.references)
        if not refs:
            raise InputError(f"Scenario({self.name}).references is empty: a scenario needs at least one reference")
        for i, r in enumerate(refs):
            if not isinstance(r, ScenarioReference):
                raise InputError(f"Scenario({self.name}).references[{i}] must be a ScenarioReference, got {type(r).__name__}")
        ref_ids = [r.id for r in refs]
        if len(set(ref_ids)) != len(ref_ids):
            raise InputError(f"Scenario({self.name}).references have duplicate ids: {ref_ids}")
        queries = tuple(self.queries)
        seen: set[str] = set()
        for i, q in enumerate(queries):
            if not isinstance(q, ScenarioQuery):
                raise InputError(f"Scenario({self.name}).queries[{i}] must be a ScenarioQuery, got {type(q).__name__}")
            if q.id in seen:
                raise InputError(f"Scenario({self.name}).queries[{i}] repeats the id {q.id!r}")
            seen.add(q.id)
            if q.reference_id not in ref_ids:
                raise InputError(
                    f"Scenario({self.name}).queries[{i}] ({q.id}) names reference {q.reference_id!r}, not one of {ref_ids}"
                )
        object.__setattr__(self, "references", refs)
        object.__setattr__(self, "queries", queries)
        if self.world is not None and not isinstance(self.world, World):
            raise InputError(
                f"Scenario({self.name}).world must be a factorloc.sim.World or None, got {type(self.world).__name__}"
            )
        if self.seed is not None and (
            isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or self.seed < 0
        ):
            raise InputError(f"Scenario({self.name}).seed must be a non-negative integer or None, got {self.seed!r}")
        if self.seed is not None:
            object.__setattr__(self, "seed", int(self.seed))
        if not isinstance(self.description, str):
            raise InputError(f"Scenario({self.name}).description must be a string, got {type(self.description).__name__}")
        object.__setattr__(self, "metadata", _frozen_metadata(f"Scenario({self.name}).metadata", self.metadata))

    # --- access ----------------------------------------------------------------
    @property
    def reference(self) -> Reference:
        """The scenario's reference when it has exactly one (raises otherwise: use :meth:`reference_of`)."""
        if len(self.references) != 1:
            raise InputError(
                f"Scenario({self.name}) has {len(self.references)} references {[r.id for r in self.references]}; "
                "use reference_of(query) or references"
            )
        return self.references[0].reference

    def reference_by_id(self, reference_id: str) -> ScenarioReference:
        for r in self.references:
            if r.id == reference_id:
                return r
        ids = [r.id for r in self.references]
        raise UnknownIdError(f"no reference {reference_id!r} in scenario {self.name!r}; ids are {ids}")

    def reference_of(self, query: ScenarioQuery) -> Reference:
        """The reference ``query`` is localized against."""
        return self.reference_by_id(query.reference_id).reference

    def query_by_id(self, query_id: str) -> ScenarioQuery:
        for q in self.queries:
            if q.id == query_id:
                return q
        ids = [q.id for q in self.queries]
        raise UnknownIdError(f"no query {query_id!r} in scenario {self.name!r}; ids are {ids[:5]}{' …' if len(ids) > 5 else ''}")

    def __len__(self) -> int:
        return len(self.queries)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Scenario):
            return NotImplemented
        return (
            self.name == other.name
            and self.references == other.references
            and self.queries == other.queries
            and self.world == other.world
            and self.seed == other.seed
            and self.description == other.description
            and dict(self.metadata) == dict(other.metadata)
        )

    __hash__ = None  # type: ignore[assignment]


# --------------------------------------------------------------------------
# Equality of the (identity-compared) sensor types
# --------------------------------------------------------------------------
def _arr_eq(a: np.ndarray | None, b: np.ndarray | None) -> bool:
    if a is None or b is None:
        return a is b
    return a.shape == b.shape and a.dtype == b.dtype and bool(np.array_equal(a, b))


def _panorama_equal(a: Panorama | None, b: Panorama | None) -> bool:
    if a is None or b is None:
        return a is b
    return (
        _arr_eq(a.image_bgr, b.image_bgr)
        and a.fov_v_rad == b.fov_v_rad
        and a.azimuth_col0_rad == b.azimuth_col0_rad
        and _arr_eq(a.seen_columns, b.seen_columns)
    )


def _camera_equal(a: CameraImage, b: CameraImage) -> bool:
    return (
        _arr_eq(a.image_bgr, b.image_bgr)
        and a.hfov_rad == b.hfov_rad
        and a.yaw_in_robot_rad == b.yaw_in_robot_rad
        and a.pitch_rad == b.pitch_rad
        and a.cx_px == b.cx_px
    )


def _points_equal(a: PointCloud | Scan | None, b: PointCloud | Scan | None) -> bool:
    if a is None or b is None:
        return a is b
    return type(a) is type(b) and _arr_eq(a.points_m, b.points_m)


def _reference_equal(a: Reference, b: Reference) -> bool:
    return (
        _panorama_equal(a.panorama, b.panorama)
        and _points_equal(a.cloud, b.cloud)
        and _points_equal(a.scan, b.scan)
        and a.T_world_reference == b.T_world_reference
        and a.name == b.name
    )


def _query_equal(a: Query, b: Query) -> bool:
    return (
        a.id == b.id
        and len(a.images) == len(b.images)
        and all(_camera_equal(x, y) for x, y in zip(a.images, b.images, strict=True))
        and _panorama_equal(a.panorama, b.panorama)
        and _points_equal(a.cloud, b.cloud)
        and _points_equal(a.scan, b.scan)
        and a.odometry == b.odometry
    )


# --------------------------------------------------------------------------
# Writing
# --------------------------------------------------------------------------
def save_scenario(
    scenario: Scenario,
    path: str | Path,
    *,
    image_format: str = "png",
    jpeg_quality: int = 90,
    overwrite: bool = False,
) -> Path:
    """Write ``scenario`` as a directory at ``path``; returns the path.

    Parameters
    ----------
    image_format
        ``"png"`` (lossless: :func:`load_scenario` gives back an equal scenario) or
        ``"jpg"`` for query camera images (smaller, lossy; panoramas stay PNG).
    jpeg_quality
        JPEG quality 1–100 when ``image_format="jpg"``.
    overwrite
        Replace an existing scenario directory (one that holds a ``scenario.yaml``).
    """
    if not isinstance(scenario, Scenario):
        raise InputError(f"save_scenario needs a Scenario, got {type(scenario).__name__}")
    if image_format not in ("png", "jpg"):
        raise InputError(f"image_format must be 'png' or 'jpg', got {image_format!r}")
    if isinstance(jpeg_quality, bool) or not isinstance(jpeg_quality, int) or not 1 <= jpeg_quality <= 100:
        raise InputError(f"jpeg_quality must be an integer in [1, 100], got {jpeg_quality!r}")
    root = Path(path)
    if root.exists():
        if not root.is_dir():
            raise InputError(f"scenario path {str(root)!r} exists and is not a directory")
        if any(root.iterdir()):
            if not overwrite:
                raise InputError(f"scenario directory {str(root)!r} is not empty (pass overwrite=True to replace it)")
            if not (root / "scenario.yaml").is_file():
                raise InputError(f"refusing to overwrite {str(root)!r}: it is not empty and holds no scenario.yaml")
            for sub in ("references", "queries"):
                if (root / sub).is_dir():
                    shutil.rmtree(root / sub)
            for f in ("scenario.yaml", "world.yaml"):
                (root / f).unlink(missing_ok=True)
    root.mkdir(parents=True, exist_ok=True)

    manifest: dict[str, Any] = {
        "format": FORMAT_NAME,
        "format_version": FORMAT_VERSION,
        "name": scenario.name,
        "description": scenario.description,
        "seed": scenario.seed,
        "world": None,
        "metadata": _plain(scenario.metadata),
        "references": [],
        "queries": [],
    }
    if scenario.world is not None:
        from factorloc.sim.world import save_world

        save_world(scenario.world, root / "world.yaml")
        manifest["world"] = "world.yaml"

    for ref_entry in scenario.references:
        ref = ref_entry.reference
        rdir = Path("references") / ref_entry.id
        (root / rdir).mkdir(parents=True, exist_ok=True)
        r: dict[str, Any] = {"id": ref_entry.id, "name": ref.name, "T_world_reference": _pose_dict(ref.T_world_reference)}
        if ref.panorama is not None:
            r["panorama"] = _write_panorama(root, rdir / "panorama.png", ref.panorama)
        if ref.cloud is not None:
            r["cloud"] = _write_points(root, rdir / "cloud.npy", ref.cloud.points_m)
        if ref.scan is not None:
            r["scan"] = _write_points(root, rdir / "scan.npy", ref.scan.points_m)
        r["metadata"] = _plain(ref_entry.metadata)
        manifest["references"].append(r)

    ext = ".png" if image_format == "png" else ".jpg"
    for qe in scenario.queries:
        q = qe.query
        qdir = Path("queries") / q.id
        (root / qdir).mkdir(parents=True, exist_ok=True)
        e: dict[str, Any] = {
            "id": q.id,
            "timestamp_s": qe.timestamp_s,
            "reference": qe.reference_id,
            "truth": None if qe.truth is None else _pose_dict(qe.truth),
            "odometry": None,
            "faults": list(qe.faults),
            "distance_from_reference_m": qe.distance_from_reference_m,
            "images": [],
        }
        if q.odometry is not None:
            o = q.odometry
            e["odometry"] = {
                **_pose_dict(o.T_world_robot),
                "sigma_x_m": o.sigma_x_m,
                "sigma_y_m": o.sigma_y_m,
                "sigma_theta_rad": o.sigma_theta_rad,
            }
        for i, im in enumerate(q.images):
            rel = qdir / f"image{i}{ext}"
            _write_image(root / rel, im.image_bgr, jpeg_quality)
            e["images"].append(
                {
                    "file": rel.as_posix(),
                    "width_px": im.width_px,
                    "height_px": im.height_px,
                    "hfov_rad": im.hfov_rad,
                    "yaw_in_robot_rad": im.yaw_in_robot_rad,
                    "pitch_rad": im.pitch_rad,
                    "cx_px": im.cx_px,
                }
            )
        if q.panorama is not None:
            e["panorama"] = _write_panorama(root, qdir / "panorama.png", q.panorama)
        if q.cloud is not None:
            e["cloud"] = _write_points(root, qdir / "cloud.npy", q.cloud.points_m)
        if q.scan is not None:
            e["scan"] = _write_points(root, qdir / "scan.npy", q.scan.points_m)
        e["metadata"] = _plain(qe.metadata)
        manifest["queries"].append(e)

    text = yaml.safe_dump(manifest, sort_keys=False, allow_unicode=True, width=140)
    (root / "scenario.yaml").write_text(text, encoding="utf-8")
    return root


def _pose_dict(p: Pose2) -> dict[str, float]:
    return {"x_m": p.x, "y_m": p.y, "theta_rad": p.theta}


def _write_image(path: Path, image_bgr: np.ndarray, jpeg_quality: int) -> None:
    if path.suffix == ".png":
        ok, buf = cv2.imencode(".png", image_bgr, [cv2.IMWRITE_PNG_COMPRESSION, 9])
    else:
        ok, buf = cv2.imencode(".jpg", image_bgr, [cv2.IMWRITE_JPEG_QUALITY, jpeg_quality])
    if not ok:
        raise DatasetError(f"could not encode image {str(path)!r}")
    path.write_bytes(buf.tobytes())


def _write_panorama(root: Path, rel: Path, pano: Panorama) -> dict[str, Any]:
    _write_image(root / rel, pano.image_bgr, 100)
    entry = {
        "file": rel.as_posix(),
        "width_px": pano.width_px,
        "height_px": pano.height_px,
        "fov_v_rad": pano.fov_v_rad,
        "azimuth_col0_rad": pano.azimuth_col0_rad,
    }
    if pano.seen_columns is not None:  # absent: every column seen (manifests without the field read the same)
        entry["seen_columns"] = _column_runs(pano.seen_columns)
    return entry


def _column_runs(seen: np.ndarray) -> list[list[int]]:
    """``[[start, stop), …]`` of the runs of True in a bool mask (the manifest form of ``Panorama.seen_columns``)."""
    d = np.diff(np.concatenate([[0], seen.astype(np.int8), [0]]))
    return [[int(a), int(b)] for a, b in zip(np.flatnonzero(d == 1), np.flatnonzero(d == -1), strict=True)]


def _write_points(root: Path, rel: Path, points: np.ndarray) -> dict[str, Any]:
    p32 = points.astype(np.float32)
    data = p32 if np.array_equal(p32.astype(np.float64), points) else np.asarray(points, np.float64)
    np.save(root / rel, data, allow_pickle=False)
    return {"file": rel.as_posix(), "points": int(points.shape[0])}


def _plain(value: Any) -> Any:
    if isinstance(value, Mapping):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    return value


def _frozen_metadata(name: str, value: Any) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise InputError(f"{name} must be a mapping, got {type(value).__name__}")
    plain = _plain(value)
    bad = _first_non_yaml(plain)
    if bad is not None:
        raise InputError(f"{name} must hold only YAML-able values (numbers, strings, lists, mappings), got {bad!r}")
    return MappingProxyType(plain)


def _first_non_yaml(value: Any) -> Any:
    """The first value in a nested structure that YAML cannot represent, or None."""
    if value is None or isinstance(value, (bool, int, float, str)):
        return None
    if isinstance(value, list):
        for v in value:
            bad = _first_non_yaml(v)
            if bad is not None:
                return bad
        return None
    if isinstance(value, dict):
        for k, v in value.items():
            for item in (k, v):
                bad = _first_non_yaml(item)
                if bad is not None:
                    return bad
        return None
    return value


def _check_id(name: str, value: Any) -> None:
    if not isinstance(value, str) or not _ID.match(value):
        raise InputError(f"{name} must be a non-empty identifier of letters, digits, '_', '.', '-' (a file name), got {value!r}")


# --------------------------------------------------------------------------
# Reading
# --------------------------------------------------------------------------
class _Ctx:
    """Where we are in the manifest, for error messages."""

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
        name = f"{where}.{key}" if where else key
        if isinstance(v, bool) or not isinstance(v, (int, float)):
            raise self.fail(name, f"must be a number, got {v!r}")
        v = float(v)
        if not math.isfinite(v):
            raise self.fail(name, f"must be finite, got {v!r}")
        if positive and v <= 0:
            raise self.fail(name, f"must be > 0, got {v!r}")
        return v

    def pose(self, d: Any, where: str) -> Pose2:
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

    def image(self, d: Any, where: str) -> np.ndarray:
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
        p = self.file(d, where)
        try:
            if p.suffix == ".npy":
                arr = np.load(p, allow_pickle=False)
            elif p.suffix == ".npz":
                with np.load(p, allow_pickle=False) as z:
                    if "points_m" not in z:
                        raise DatasetError(
                            f"{self.manifest}: field '{where}.file': {str(p)!r} has no array 'points_m' (has {list(z.keys())})"
                        )
                    arr = z["points_m"]
            elif p.suffix == ".ply":
                import open3d as o3d

                arr = np.asarray(o3d.io.read_point_cloud(str(p)).points)
                if ncols == 2 and arr.ndim == 2:
                    arr = arr[:, :2]
            else:
                raise DatasetError(f"{self.manifest}: field '{where}.file': {str(p)!r} must be .npy, .npz or .ply")
        except (OSError, ValueError) as exc:
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
            raise DatasetError(f"{self.manifest}: field '{where}.points': says {n} points, {str(p)!r} holds {arr.shape[0]}")
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
        loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
        m = yaml.load(ctx.manifest.read_text(encoding="utf-8"), Loader=loader)  # noqa: S506 - a safe loader
    except (OSError, UnicodeDecodeError, yaml.YAMLError) as exc:
        raise DatasetError(f"{ctx.manifest}: cannot be parsed as YAML: {exc}") from exc
    if not isinstance(m, Mapping):
        raise DatasetError(f"{ctx.manifest}: the manifest must be a mapping, got {type(m).__name__}")
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
    rid = ctx.get(r, "id", where)
    pano, cloud, scan = _optional_sensors(ctx, r, where)
    T = ctx.pose(ctx.get(r, "T_world_reference", where), f"{where}.T_world_reference")
    name = str(ctx.get(r, "name", where, required=False, default="reference"))
    with ctx.at(where):
        ref = Reference(pano, cloud, scan, T, name)
        return ScenarioReference(rid, ref, ctx.get(r, "metadata", where, required=False, default={}) or {})


def _load_query(ctx: _Ctx, e: Any, where: str, default_reference: str) -> ScenarioQuery:
    qid = ctx.get(e, "id", where)
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
        pose = ctx.pose(o, wo)
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
    img = ctx.image(d, where)
    fov = ctx.number(d, "fov_v_rad", where, positive=True)
    az0 = ctx.number(d, "azimuth_col0_rad", where, required=False, default=math.pi)
    runs = ctx.get(d, "seen_columns", where, required=False)
    seen = None
    if runs is not None:
        w = img.shape[1]
        ok = isinstance(runs, list) and all(
            isinstance(r, list)
            and len(r) == 2
            and all(isinstance(v, int) and not isinstance(v, bool) for v in r)
            and 0 <= r[0] < r[1] <= w
            for r in runs
        )
        if not ok:
            raise ctx.fail(f"{where}.seen_columns", f"must be a list of [start, stop) column runs within [0, {w}], got {runs!r}")
        seen = np.zeros(w, dtype=bool)
        for a, b in runs:
            seen[a:b] = True
    with ctx.at(where):
        return Panorama(img, fov, az0, seen)


def scenario_files(path: str | Path) -> Sequence[Path]:
    """Every file of the scenario directory at ``path`` (manifest first), for hashing or copying."""
    root = Path(path)
    files = sorted(p for p in root.rglob("*") if p.is_file())
    return [root / "scenario.yaml"] + [p for p in files if p.name != "scenario.yaml" or p.parent != root]

"""A scenario in memory: references, queries with ground truth and fault tags, and the world.

Its on-disk format is written by :func:`~factorloc.datasets.writer.save_scenario` and read by
:func:`~factorloc.datasets.reader.load_scenario`.

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

import math
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

import numpy as np

from factorloc._json import json_ready
from factorloc.errors import InputError, UnknownIdError
from factorloc.geometry import Pose2
from factorloc.types import Query, Reference

__all__ = ["FAULT_TAGS", "FORMAT_NAME", "FORMAT_VERSION", "Scenario", "ScenarioQuery", "ScenarioReference"]

#: The value of ``format`` in every manifest.
FORMAT_NAME = "factorloc-scenario"
#: The manifest version this module writes and reads.
FORMAT_VERSION = 1
#: Fault tags the simulator writes (a scenario may carry others).
FAULT_TAGS = ("kidnapped", "occlusion", "lighting", "blur", "depth_dropout", "glass", "corridor")

if TYPE_CHECKING:  # pragma: no cover
    from factorloc.sim.world import World


def _is_world(value: Any) -> bool:
    """Whether ``value`` is a :class:`factorloc.sim.World` (the simulator is imported only when a world is given)."""
    from factorloc.sim.world import World

    return isinstance(value, World)


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
        return self.id == other.id and self.reference.same_as(other.reference) and dict(self.metadata) == dict(other.metadata)

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
            self.query.same_as(other.query)
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
        if self.world is not None and not _is_world(self.world):
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


def plain(value: Any) -> Any:
    """``value`` as the plain types YAML writes (numpy values as Python ones, tuples as lists, NaN kept)."""
    return json_ready(value, finite=False)


def _frozen_metadata(name: str, value: Any) -> Mapping[str, Any]:
    if not isinstance(value, Mapping):
        raise InputError(f"{name} must be a mapping, got {type(value).__name__}")
    data = plain(value)
    bad = _first_non_yaml(data)
    if bad is not None:
        raise InputError(f"{name} must hold only YAML-able values (numbers, strings, lists, mappings), got {bad!r}")
    return MappingProxyType(data)


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

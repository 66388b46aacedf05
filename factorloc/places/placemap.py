"""A map of places: the references a robot knows, each with its world pose (:class:`Place`, :class:`PlaceMap`).

A *place* is one :class:`~factorloc.types.Reference` (panorama and/or scan/cloud taken at one spot) with an id,
its pose ``T_world_reference`` in the map's world frame and, optionally, the 3×3 covariance of that pose (world
frame, order x, y, θ; m², rad²) — the uncertainty a mapper (a pose graph of places) leaves on it. A place without
covariance is taken as exactly known.

On disk a map is a scenario directory without queries (``docs/data-format.md``, "Maps of places"): one
reference entry per place; a place's covariance is the reference's ``metadata.place_covariance`` (a 3×3 list).
:meth:`PlaceMap.save` / :meth:`PlaceMap.load` round-trip exactly; :meth:`PlaceMap.from_scenario` takes the
references of any scenario (its queries are ignored).
"""

from __future__ import annotations

from collections.abc import Iterable, Iterator, Sequence
from dataclasses import dataclass, replace
from functools import cached_property
from pathlib import Path

import numpy as np

from factorloc.errors import DatasetError, InputError, UnknownIdError
from factorloc.geometry import Pose2
from factorloc.types import Reference

__all__ = ["PLACE_COVARIANCE_KEY", "Place", "PlaceMap"]

#: The key of a reference's metadata that holds its place covariance (3×3, world frame, x, y, θ).
PLACE_COVARIANCE_KEY = "place_covariance"


def _place_covariance(name: str, value: object) -> np.ndarray:
    try:
        cov = np.array(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"{name} must be a 3×3 array of numbers, got {value!r}") from exc
    if cov.shape != (3, 3) or not np.all(np.isfinite(cov)):
        raise InputError(f"{name} must be a finite 3×3 array, got shape {cov.shape}")
    if not np.allclose(cov, cov.T, rtol=1e-9, atol=1e-15):
        raise InputError(f"{name} must be symmetric, got {cov.tolist()}")
    cov = 0.5 * (cov + cov.T)
    if float(np.linalg.eigvalsh(cov)[0]) <= 0.0:
        raise InputError(f"{name} must be positive definite, got eigenvalues {np.linalg.eigvalsh(cov).tolist()}")
    cov.setflags(write=False)
    return cov


@dataclass(frozen=True, eq=False)
class Place:
    """One place of a :class:`PlaceMap`.

    Parameters
    ----------
    id
        The place's id (a file name: letters, digits, ``_``, ``.``, ``-``).
    reference
        What the robot sensed there (panorama, scan and/or cloud in the robot frame at the place).
    T_world_reference
        Pose of the place (of the robot that captured ``reference``) in the map's world frame. The stored
        ``reference`` carries this pose (its own ``T_world_reference`` is replaced by it), so that the
        hierarchy run against ``place.reference`` answers in the world frame.
    covariance
        3×3 covariance of ``T_world_reference`` (world frame, x, y, θ; m², rad²), or None for a place whose pose
        is taken as exact.
    """

    id: str
    reference: Reference
    T_world_reference: Pose2
    covariance: np.ndarray | None = None

    def __post_init__(self) -> None:
        from factorloc.datasets.scenario import _check_id

        _check_id("Place.id", self.id)
        if not isinstance(self.reference, Reference):
            raise InputError(f"Place({self.id}).reference must be a factorloc.Reference, got {type(self.reference).__name__}")
        if not isinstance(self.T_world_reference, Pose2):
            raise InputError(f"Place({self.id}).T_world_reference must be a Pose2, got {type(self.T_world_reference).__name__}")
        if self.reference.T_world_reference != self.T_world_reference:
            object.__setattr__(self, "reference", replace(self.reference, T_world_reference=self.T_world_reference))
        if self.covariance is not None:
            object.__setattr__(self, "covariance", _place_covariance(f"Place({self.id}).covariance", self.covariance))

    @property
    def position_m(self) -> np.ndarray:
        """(2,) world position of the place (m)."""
        return self.T_world_reference.translation

    def planar_points_m(self) -> np.ndarray | None:
        """The reference's planar points (N×2, place frame, m): its scan, else its cloud's x, y; None without either."""
        ref = self.reference
        if ref.scan is not None and len(ref.scan):
            return ref.scan.points_m
        if ref.cloud is not None and len(ref.cloud):
            return ref.cloud.points_m[:, :2]
        return None

    @cached_property
    def footprint_m(self) -> float:
        """:meth:`footprint_radius_m` at its default quantile, computed once."""
        return self.footprint_radius_m()

    def footprint_radius_m(self, quantile: float = 0.9) -> float:
        """How far the place's reference scan/cloud reaches (m): the ``quantile`` of its points' planar ranges.

        A query farther than this from the place hardly sees what the place saw. 0 when the reference holds
        no scan or cloud (a panorama only).
        """
        ranges = []
        if self.reference.scan is not None and len(self.reference.scan):
            ranges.append(np.hypot(*self.reference.scan.points_m.T))
        if self.reference.cloud is not None and len(self.reference.cloud):
            ranges.append(np.hypot(self.reference.cloud.points_m[:, 0], self.reference.cloud.points_m[:, 1]))
        if not ranges:
            return 0.0
        return float(np.quantile(np.concatenate(ranges), quantile))

    def same_as(self, other: object) -> bool:
        """Whether ``other`` is a place with the same id, reference data, pose and covariance."""
        if not isinstance(other, Place) or other.id != self.id or not self.reference.same_as(other.reference):
            return False
        if (self.covariance is None) != (other.covariance is None):
            return False
        return self.covariance is None or bool(np.array_equal(self.covariance, other.covariance))


class PlaceMap:
    """The places a robot knows, in one world frame.

    ``PlaceMap(places)`` takes any sequence of :class:`Place` with distinct ids; :meth:`add` adds one more.
    Iterating gives the places in the order they were added; ``place_map[id]`` looks one up.
    """

    def __init__(self, places: Sequence[Place] = ()) -> None:
        self._places: dict[str, Place] = {}
        for i, p in enumerate(places):
            if not isinstance(p, Place):
                raise InputError(f"PlaceMap places[{i}] must be a Place, got {type(p).__name__}")
            self.add(p)

    # --- building --------------------------------------------------------------------
    def add(self, place: Place) -> None:
        """Add ``place``; its id must be new."""
        if not isinstance(place, Place):
            raise InputError(f"PlaceMap.add needs a Place, got {type(place).__name__}")
        if place.id in self._places:
            raise InputError(f"PlaceMap already holds a place {place.id!r}")
        self._places[place.id] = place

    @classmethod
    def from_scenario(cls, scenario: object) -> PlaceMap:
        """The places of a :class:`~factorloc.datasets.Scenario`: one per reference (its queries are ignored).

        A reference's ``metadata.place_covariance`` (3×3) becomes the place's covariance.
        """
        from factorloc.datasets.scenario import Scenario

        if not isinstance(scenario, Scenario):
            raise InputError(f"PlaceMap.from_scenario needs a Scenario, got {type(scenario).__name__}")
        places = []
        for r in scenario.references:
            cov = r.metadata.get(PLACE_COVARIANCE_KEY)
            places.append(Place(r.id, r.reference, r.reference.T_world_reference, None if cov is None else cov))
        return cls(places)

    def to_scenario(self, name: str = "places", description: str = "") -> object:
        """This map as a :class:`~factorloc.datasets.Scenario` without queries (what :meth:`save` writes)."""
        from factorloc.datasets.scenario import Scenario, ScenarioReference

        if not self._places:
            raise InputError("an empty PlaceMap cannot be written: a scenario needs at least one reference")
        refs = tuple(
            ScenarioReference(p.id, p.reference, {} if p.covariance is None else {PLACE_COVARIANCE_KEY: p.covariance.tolist()})
            for p in self
        )
        return Scenario(name, refs, (), description=description, metadata={"kind": "place-map"})

    def save(self, path: str | Path, *, name: str = "places", overwrite: bool = False) -> Path:
        """Write the map as a scenario directory without queries (lossless); returns the path."""
        from factorloc.datasets import save_scenario

        return save_scenario(self.to_scenario(name), path, overwrite=overwrite)  # type: ignore[arg-type]

    @classmethod
    def load(cls, path: str | Path) -> PlaceMap:
        """Read a map written by :meth:`save`, or the references of any scenario directory."""
        from factorloc.datasets import load_scenario

        try:
            return cls.from_scenario(load_scenario(path))
        except InputError as exc:
            if isinstance(exc, DatasetError):
                raise
            raise DatasetError(f"{path}: {exc}") from exc

    # --- access --------------------------------------------------------------------------
    def __len__(self) -> int:
        return len(self._places)

    def __iter__(self) -> Iterator[Place]:
        return iter(self._places.values())

    def __contains__(self, place_id: object) -> bool:
        return place_id in self._places

    def __getitem__(self, place_id: str) -> Place:
        try:
            return self._places[place_id]
        except KeyError:
            ids = list(self._places)
            raise UnknownIdError(f"no place {place_id!r} in the map; ids are {ids[:5]}{' …' if len(ids) > 5 else ''}") from None

    @property
    def ids(self) -> tuple[str, ...]:
        return tuple(self._places)

    def positions_m(self, ids: Iterable[str] | None = None) -> np.ndarray:
        """(N, 2) world positions of the places (all, in order, or those of ``ids``)."""
        chosen = list(self._places.values()) if ids is None else [self[i] for i in ids]
        return np.array([p.position_m for p in chosen], dtype=np.float64).reshape(-1, 2)

    def same_as(self, other: object) -> bool:
        """Whether ``other`` holds the same places in the same order."""
        return (
            isinstance(other, PlaceMap) and self.ids == other.ids and all(a.same_as(b) for a, b in zip(self, other, strict=True))
        )

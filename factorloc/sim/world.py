"""The simulated world: a 2.5D floor plan of textured wall segments and polygon obstacles.

Frames and units: world frame x, y in metres on the floor, z up from the floor
(REP-103). A :class:`Wall` is a thin, double-sided segment; each side is a
*face* with its own :class:`Material` and :class:`Decal` list (posters, closed
doors, windows). An :class:`Obstacle` is a closed polygon (pillar, cabinet,
sofa, counter) extruded from the floor to its ``height_m``; a low obstacle has
a visible top. Floor and ceiling carry their own materials.

Worlds load from and save to a small YAML (or JSON) file, see
``docs/data-format.md`` (:func:`load_world`, :func:`save_world`); :func:`apartment` is the built-in ~10 × 8 m plan. What a face
looks like is :mod:`factorloc.sim.appearance`, walls and obstacles :mod:`factorloc.sim.walls`, the plan as
arrays for the renderers :mod:`factorloc.sim.plan`.

Texture convention of a face: seen by a viewer standing in front of it, the
texture's column ``u`` grows from the viewer's left to right and its row from
the top of the face (``z = height``) down to the floor, so photographs are
never mirrored. For a wall from ``start`` to ``end`` the *left* face is the
one whose normal points to the left of ``start → end``; obstacle vertices are
counter-clockwise and their faces point outward.
"""

from __future__ import annotations

import functools
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from factorloc._validate import finite_float, mapping, positive_float, sequence
from factorloc._yaml import load_yaml
from factorloc.errors import InputError
from factorloc.sim.appearance import Decal, Face, Material
from factorloc.sim.plan import Segments, point_in_polygon, point_segment_distance, segments_of
from factorloc.sim.walls import Obstacle, Wall

__all__ = [
    "WORLD_FORMAT_VERSION",
    "Decal",
    "Face",
    "Material",
    "Obstacle",
    "Wall",
    "World",
    "apartment",
    "builtin_worlds",
    "load_world",
    "save_world",
    "world_by_name",
]

#: Version of the world-file format written by :func:`save_world`.
WORLD_FORMAT_VERSION = 1


# --------------------------------------------------------------------------
# Geometry
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class World:
    """A floor plan: walls, obstacles, wall (= ceiling) height, floor and ceiling materials.

    ``texture_px_per_m`` is the resolution of the baked wall textures (texels
    per metre of face). Baking is deterministic, so a world always renders the same.
    ``regions`` names axis-aligned rectangles ``(x0, y0, x1, y1)`` the scenario
    generator uses: ``"reference"`` (where the reference is taken: its centre)
    and ``"corridor"`` (where ICP is degenerate along the corridor's axis).
    """

    name: str
    walls: tuple[Wall, ...]
    obstacles: tuple[Obstacle, ...] = ()
    wall_height_m: float = 2.5
    floor: Material = field(default_factory=lambda: Material("parquet", (1.0, 1.0, 1.0), 2.0))
    ceiling: Material = field(default_factory=lambda: Material("ceiling", (1.0, 1.0, 1.0), 2.0))
    texture_px_per_m: float = 128.0
    regions: tuple[tuple[str, tuple[float, float, float, float]], ...] = ()

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise InputError(f"World.name must be a non-empty string, got {self.name!r}")
        walls = tuple(self.walls)
        obstacles = tuple(self.obstacles)
        if not walls and not obstacles:
            raise InputError(f"World({self.name}) needs at least one wall or obstacle")
        for i, w in enumerate(walls):
            if not isinstance(w, Wall):
                raise InputError(f"World({self.name}).walls[{i}] must be a Wall, got {type(w).__name__}")
        for i, o in enumerate(obstacles):
            if not isinstance(o, Obstacle):
                raise InputError(f"World({self.name}).obstacles[{i}] must be an Obstacle, got {type(o).__name__}")
        object.__setattr__(self, "walls", walls)
        object.__setattr__(self, "obstacles", obstacles)
        h = positive_float(f"World({self.name}).wall_height_m", self.wall_height_m)
        object.__setattr__(self, "wall_height_m", h)
        for i, o in enumerate(obstacles):
            if o.height_m > h + 1e-9:
                raise InputError(f"World({self.name}).obstacles[{i}].height_m = {o.height_m} exceeds wall_height_m = {h}")
        for name in ("floor", "ceiling"):
            if not isinstance(getattr(self, name), Material):
                raise InputError(f"World({self.name}).{name} must be a Material")
        ppm = positive_float(f"World({self.name}).texture_px_per_m", self.texture_px_per_m)
        if not 16.0 <= ppm <= 512.0:
            raise InputError(f"World({self.name}).texture_px_per_m must be in [16, 512], got {ppm}")
        object.__setattr__(self, "texture_px_per_m", ppm)
        regions = []
        items = self.regions.items() if isinstance(self.regions, dict) else self.regions
        for item in items:
            try:
                rname, box = item
                box = tuple(
                    finite_float(f"World({self.name}).regions[{rname}]", v) for v in sequence(f"World.regions[{rname}]", box, 4)
                )
            except (TypeError, ValueError) as exc:
                raise InputError(f"World({self.name}).regions must map names to (x0, y0, x1, y1), got {item!r}") from exc
            if not (box[2] > box[0] and box[3] > box[1]):
                raise InputError(f"World({self.name}).regions[{rname}] needs x0 < x1 and y0 < y1, got {box}")
            regions.append((str(rname), box))
        object.__setattr__(self, "regions", tuple(regions))

    # --- geometry -------------------------------------------------------------
    @functools.cached_property
    def segments(self) -> Segments:
        """The plan as flat arrays of segments (what the renderers ray-cast against)."""
        return segments_of(self)

    @property
    def bounds_xy(self) -> tuple[float, float, float, float]:
        """``(xmin, ymin, xmax, ymax)`` of all walls and obstacles (metres)."""
        s = self.segments
        pts = np.vstack([s.p0, s.p1])
        return (float(pts[:, 0].min()), float(pts[:, 1].min()), float(pts[:, 0].max()), float(pts[:, 1].max()))

    def clearance(self, xy: np.ndarray) -> np.ndarray:
        """Distance (m) from each of N×2 points to the nearest wall or obstacle edge; 0 inside an obstacle."""
        pts = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        s = self.segments
        d = point_segment_distance(pts, s.p0, s.p1).min(axis=1)
        inside = self.inside_obstacle(pts)
        d[inside] = 0.0
        return d

    def inside_obstacle(self, xy: np.ndarray) -> np.ndarray:
        """Whether each of N×2 points lies inside an obstacle polygon (even–odd rule)."""
        pts = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        out = np.zeros(len(pts), dtype=bool)
        for ob in self.obstacles:
            v = np.asarray(ob.vertices_xy)
            out |= point_in_polygon(pts, v)
        return out

    def is_free(self, xy: np.ndarray, clearance_m: float = 0.3) -> np.ndarray:
        """Whether points are inside the plan's bounds, outside obstacles, ≥ ``clearance_m`` from any surface."""
        pts = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        x0, y0, x1, y1 = self.bounds_xy
        inb = (pts[:, 0] > x0) & (pts[:, 0] < x1) & (pts[:, 1] > y0) & (pts[:, 1] < y1)
        return inb & (self.clearance(pts) >= clearance_m)

    def region(self, name: str) -> tuple[float, float, float, float] | None:
        """The rectangle ``(x0, y0, x1, y1)`` named ``name``, or None."""
        for rname, box in self.regions:
            if rname == name:
                return box
        return None

    def line_of_sight(self, a_xy: np.ndarray, b_xy: np.ndarray) -> np.ndarray:
        """Whether the straight segments from points ``a`` (N×2) to ``b`` (N×2) cross no wall or obstacle edge."""
        a = np.atleast_2d(np.asarray(a_xy, np.float64))
        b = np.atleast_2d(np.asarray(b_xy, np.float64))
        s = self.segments
        d = b - a  # N×2
        e = s.p1 - s.p0  # S×2
        w = s.p0[None, :, :] - a[:, None, :]  # N×S×2
        den = d[:, None, 0] * e[None, :, 1] - d[:, None, 1] * e[None, :, 0]
        with np.errstate(divide="ignore", invalid="ignore"):
            t = (w[..., 0] * e[None, :, 1] - w[..., 1] * e[None, :, 0]) / den
            u = (w[..., 0] * d[:, None, 1] - w[..., 1] * d[:, None, 0]) / den
        cross = (np.abs(den) > 1e-12) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
        return ~cross.any(axis=1)

    # --- (de)serialisation -----------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        return {
            "format_version": WORLD_FORMAT_VERSION,
            "name": self.name,
            "wall_height_m": self.wall_height_m,
            "texture_px_per_m": self.texture_px_per_m,
            "floor": self.floor.to_dict(),
            "ceiling": self.ceiling.to_dict(),
            "walls": [w.to_dict() for w in self.walls],
            "obstacles": [o.to_dict() for o in self.obstacles],
            "regions": {name: list(box) for name, box in self.regions},
        }

    @classmethod
    def from_dict(cls, data: Any, where: str = "world") -> World:
        keys = {
            "format_version",
            "name",
            "wall_height_m",
            "texture_px_per_m",
            "floor",
            "ceiling",
            "walls",
            "obstacles",
            "regions",
        }
        d = mapping(where, data, keys)
        version = d.get("format_version", WORLD_FORMAT_VERSION)
        if version != WORLD_FORMAT_VERSION:
            raise InputError(
                f"{where}.format_version: unknown world format version {version!r} (this factorloc reads {WORLD_FORMAT_VERSION})"
            )
        if "name" not in d:
            raise InputError(f"{where} is missing the field 'name'")
        kwargs: dict[str, Any] = {}
        for key in ("wall_height_m", "texture_px_per_m"):
            if key in d:
                kwargs[key] = finite_float(f"{where}.{key}", d[key])
        for key in ("floor", "ceiling"):
            if key in d:
                kwargs[key] = Material.from_dict(d[key], f"{where}.{key}")
        if d.get("regions"):
            if not isinstance(d["regions"], dict):
                raise InputError(f"{where}.regions must be a mapping of name: [x0, y0, x1, y1], got {d['regions']!r}")
            kwargs["regions"] = tuple(d["regions"].items())
        return cls(
            name=d["name"],
            walls=tuple(
                Wall.from_dict(w, f"{where}.walls[{i}]") for i, w in enumerate(sequence(f"{where}.walls", d.get("walls", [])))
            ),
            obstacles=tuple(
                Obstacle.from_dict(o, f"{where}.obstacles[{i}]")
                for i, o in enumerate(sequence(f"{where}.obstacles", d.get("obstacles", [])))
            ),
            **kwargs,
        )


# --------------------------------------------------------------------------
# Files
# --------------------------------------------------------------------------
def load_world(path: str | Path) -> World:
    """Load a world from a YAML (``.yaml``/``.yml``) or JSON (``.json``) file.

    Raises
    ------
    InputError
        Naming the file and the field when the file is missing, unreadable, or malformed.
    """
    p = Path(path)
    if not p.is_file():
        raise InputError(f"world file {str(p)!r} does not exist")
    try:
        text = p.read_text(encoding="utf-8")
        data = json.loads(text) if p.suffix.lower() == ".json" else load_yaml(text)
    except (OSError, UnicodeDecodeError, yaml.YAMLError, json.JSONDecodeError, RecursionError) as exc:
        raise InputError(f"world file {str(p)!r} cannot be parsed: {exc}") from exc
    try:
        return World.from_dict(data)
    except InputError as exc:
        raise InputError(f"world file {str(p)!r}: {exc}") from exc


def save_world(world: World, path: str | Path) -> Path:
    """Write ``world`` as YAML (or JSON if the suffix is ``.json``); returns the path."""
    p = Path(path)
    data = world.to_dict()
    if p.suffix.lower() == ".json":
        p.write_text(json.dumps(data, indent=1) + "\n", encoding="utf-8")
    else:
        p.write_text(yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=140), encoding="utf-8")
    return p


_WORLDS_DIR = Path(__file__).resolve().parent / "worlds"


def builtin_worlds() -> tuple[str, ...]:
    """Names of the worlds shipped with factorloc (usable with :func:`world_by_name`)."""
    return tuple(sorted(p.stem for p in _WORLDS_DIR.glob("*.yaml")))


def world_by_name(name_or_path: str | Path) -> World:
    """A built-in world by name (``"apartment"``) or a world file by path."""
    s = str(name_or_path)
    if s in builtin_worlds():
        return load_world(_WORLDS_DIR / f"{s}.yaml")
    p = Path(s)
    if p.suffix.lower() in (".yaml", ".yml", ".json"):
        return load_world(p)
    raise InputError(f"world {s!r} is neither a built-in world {builtin_worlds()} nor a .yaml/.json world file")


@functools.lru_cache(maxsize=4)
def apartment() -> World:
    """The built-in apartment: ~10 × 8 m, living room, open kitchen, a 1.2 m corridor, bedroom, bathroom, office."""
    return load_world(_WORLDS_DIR / "apartment.yaml")

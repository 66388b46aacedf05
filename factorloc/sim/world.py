"""The simulated world: a 2.5D floor plan of textured wall segments and polygon obstacles.

Frames and units: world frame x, y in metres on the floor, z up from the floor
(REP-103). A :class:`Wall` is a thin, double-sided segment; each side is a
*face* with its own :class:`Material` and :class:`Decal` list (posters, closed
doors, windows). An :class:`Obstacle` is a closed polygon (pillar, cabinet,
sofa, counter) extruded from the floor to its ``height_m``; a low obstacle has
a visible top. Floor and ceiling carry their own materials.

Worlds load from and save to a small YAML (or JSON) file, see
``docs/data-format.md``; :func:`apartment` is the built-in ~10 × 8 m plan.

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
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from factorloc._validate import finite_float, mapping, point2, positive_float, sequence
from factorloc.errors import InputError

#: Version of the world-file format written by :func:`save_world`.
WORLD_FORMAT_VERSION = 1


def _build(cls: type, where: str, d: dict[str, Any]) -> Any:
    try:
        return cls(**d)
    except TypeError as exc:
        raise InputError(f"{where}: {exc}") from exc


# --------------------------------------------------------------------------
# Appearance
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class Material:
    """What a surface looks like: a tiled texture from :mod:`factorloc.sim.textures`.

    Parameters
    ----------
    texture
        Name of a base texture (``"brick"``, ``"plain"``, ``"gravel"``, ``"grass"``,
        ``"tiles"``, ``"wood"``, ``"parquet"``, ``"wallpaper"``, ``"stars"``, ``"coins"``, …;
        see :data:`factorloc.sim.textures.BASE_TEXTURES`).
    tint_bgr
        Per-channel gain (B, G, R) applied to the texture, each in [0, 2].
    tile_m
        Width (and height) of one texture tile in metres.
    """

    texture: str = "plain"
    tint_bgr: tuple[float, float, float] = (1.0, 1.0, 1.0)
    tile_m: float = 1.0

    def __post_init__(self) -> None:
        if not isinstance(self.texture, str) or not self.texture:
            raise InputError(f"Material.texture must be a non-empty string, got {self.texture!r}")
        tint = tuple(finite_float("Material.tint_bgr", t) for t in sequence("Material.tint_bgr", self.tint_bgr, 3))
        if any(t < 0.0 or t > 2.0 for t in tint):
            raise InputError(f"Material.tint_bgr gains must be in [0, 2], got {tint}")
        object.__setattr__(self, "tint_bgr", tint)
        object.__setattr__(self, "tile_m", positive_float("Material.tile_m", self.tile_m))

    def to_dict(self) -> dict[str, Any]:
        return {"texture": self.texture, "tint_bgr": list(self.tint_bgr), "tile_m": self.tile_m}

    @classmethod
    def from_dict(cls, data: Any, where: str = "material") -> Material:
        if isinstance(data, str):
            return cls(texture=data)
        d = mapping(where, data, {"texture", "tint_bgr", "tile_m"})
        return _build(cls, where, d)


@dataclass(frozen=True)
class Decal:
    """A rectangular picture on a face: a poster, a closed door, a window.

    ``u0_m``–``u1_m`` run along the face from the viewer's left edge, ``z0_m``–``z1_m``
    up from the floor (metres). ``image`` names a picture of
    :data:`factorloc.sim.textures.DECAL_IMAGES` (``"astronaut"``, ``"coffee"``, ``"door"``, …).
    """

    image: str
    u0_m: float
    u1_m: float
    z0_m: float
    z1_m: float

    def __post_init__(self) -> None:
        if not isinstance(self.image, str) or not self.image:
            raise InputError(f"Decal.image must be a non-empty string, got {self.image!r}")
        for name in ("u0_m", "u1_m", "z0_m", "z1_m"):
            object.__setattr__(self, name, finite_float(f"Decal({self.image}).{name}", getattr(self, name)))
        if not (self.u1_m > self.u0_m and self.z1_m > self.z0_m):
            raise InputError(f"Decal({self.image}) needs u0_m < u1_m and z0_m < z1_m, got {self}")

    def to_dict(self) -> dict[str, Any]:
        return {"image": self.image, "u0_m": self.u0_m, "u1_m": self.u1_m, "z0_m": self.z0_m, "z1_m": self.z1_m}

    @classmethod
    def from_dict(cls, data: Any, where: str = "decal") -> Decal:
        return _build(cls, where, mapping(where, data, {"image", "u0_m", "u1_m", "z0_m", "z1_m"}))


@dataclass(frozen=True)
class Face:
    """One visible side of a wall or obstacle edge: a material and its decals.

    ``glass=True`` marks a transparent pane: cameras see its texture, depth
    sensors get no return from it (the glass-wall fault).
    """

    material: Material = field(default_factory=Material)
    decals: tuple[Decal, ...] = ()
    glass: bool = False

    def __post_init__(self) -> None:
        if not isinstance(self.material, Material):
            raise InputError(f"Face.material must be a Material, got {type(self.material).__name__}")
        decals = tuple(self.decals)
        for d in decals:
            if not isinstance(d, Decal):
                raise InputError(f"Face.decals must hold Decal objects, got {type(d).__name__}")
        object.__setattr__(self, "decals", decals)
        object.__setattr__(self, "glass", bool(self.glass))

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"material": self.material.to_dict()}
        if self.decals:
            out["decals"] = [d.to_dict() for d in self.decals]
        if self.glass:
            out["glass"] = True
        return out

    @classmethod
    def from_dict(cls, data: Any, where: str = "face") -> Face:
        if isinstance(data, str):
            return cls(Material(texture=data))
        d = mapping(where, data, {"material", "decals", "glass"})
        return cls(
            material=Material.from_dict(d.get("material", "plain"), f"{where}.material"),
            decals=tuple(
                Decal.from_dict(x, f"{where}.decals[{i}]") for i, x in enumerate(sequence(f"{where}.decals", d.get("decals", [])))
            ),
            glass=bool(d.get("glass", False)),
        )


# --------------------------------------------------------------------------
# Geometry
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class Wall:
    """A thin double-sided wall from ``start_xy`` to ``end_xy`` (metres), floor to ceiling.

    ``left``/``right`` are the faces whose normals point to the left/right of
    the direction ``start → end``.
    """

    start_xy: tuple[float, float]
    end_xy: tuple[float, float]
    left: Face = field(default_factory=Face)
    right: Face = field(default_factory=Face)

    def __post_init__(self) -> None:
        object.__setattr__(self, "start_xy", point2("Wall.start_xy", self.start_xy))
        object.__setattr__(self, "end_xy", point2("Wall.end_xy", self.end_xy))
        if math.dist(self.start_xy, self.end_xy) < 1e-6:
            raise InputError(f"Wall has zero length: start_xy = end_xy = {self.start_xy}")
        for side in ("left", "right"):
            if not isinstance(getattr(self, side), Face):
                raise InputError(f"Wall.{side} must be a Face, got {type(getattr(self, side)).__name__}")

    @property
    def length_m(self) -> float:
        return math.dist(self.start_xy, self.end_xy)

    def to_dict(self) -> dict[str, Any]:
        return {
            "start_xy": list(self.start_xy),
            "end_xy": list(self.end_xy),
            "left": self.left.to_dict(),
            "right": self.right.to_dict(),
        }

    @classmethod
    def from_dict(cls, data: Any, where: str = "wall") -> Wall:
        d = mapping(where, data, {"start_xy", "end_xy", "left", "right"})
        for key in ("start_xy", "end_xy"):
            if key not in d:
                raise InputError(f"{where} is missing the field '{key}'")
        return cls(
            start_xy=point2(f"{where}.start_xy", d["start_xy"]),
            end_xy=point2(f"{where}.end_xy", d["end_xy"]),
            left=Face.from_dict(d.get("left", "plain"), f"{where}.left"),
            right=Face.from_dict(d.get("right", "plain"), f"{where}.right"),
        )


@dataclass(frozen=True)
class Obstacle:
    """A prism: a simple polygon (counter-clockwise vertices, metres) extruded to ``height_m``.

    ``faces`` gives one :class:`Face` per edge (edge ``i`` runs from vertex ``i``
    to ``i+1``), or a single face used for all edges. ``top`` is the material
    of its top (visible when the obstacle is lower than the camera).
    """

    vertices_xy: tuple[tuple[float, float], ...]
    height_m: float
    faces: tuple[Face, ...] = (Face(),)
    top: Material = field(default_factory=lambda: Material("wood", (0.8, 0.9, 1.0), 0.8))
    name: str = ""

    def __post_init__(self) -> None:
        verts = tuple(
            point2(f"Obstacle({self.name}).vertices_xy[{i}]", v)
            for i, v in enumerate(sequence("Obstacle.vertices_xy", self.vertices_xy))
        )
        if len(verts) < 3:
            raise InputError(f"Obstacle({self.name}).vertices_xy needs at least 3 vertices, got {len(verts)}")
        area2 = sum(
            verts[i][0] * verts[(i + 1) % len(verts)][1] - verts[(i + 1) % len(verts)][0] * verts[i][1] for i in range(len(verts))
        )
        if area2 <= 0.0:
            raise InputError(
                f"Obstacle({self.name}).vertices_xy must be counter-clockwise with positive area, "
                f"got signed area {area2 / 2:.4f} m²"
            )
        object.__setattr__(self, "vertices_xy", verts)
        object.__setattr__(self, "height_m", positive_float(f"Obstacle({self.name}).height_m", self.height_m))
        faces = tuple(self.faces)
        if len(faces) == 1:
            faces = faces * len(verts)
        if len(faces) != len(verts) or not all(isinstance(f, Face) for f in faces):
            raise InputError(f"Obstacle({self.name}).faces must be 1 or {len(verts)} Face objects, got {len(faces)}")
        object.__setattr__(self, "faces", faces)
        if not isinstance(self.top, Material):
            raise InputError(f"Obstacle({self.name}).top must be a Material, got {type(self.top).__name__}")

    @classmethod
    def box(
        cls, x0: float, y0: float, x1: float, y1: float, height_m: float, face: Face | None = None, **kwargs: Any
    ) -> Obstacle:
        """An axis-aligned box over [x0, x1] × [y0, y1]."""
        verts = ((x0, y0), (x1, y0), (x1, y1), (x0, y1))
        return cls(verts, height_m, (face or Face(),), **kwargs)

    def to_dict(self) -> dict[str, Any]:
        faces = [f.to_dict() for f in self.faces]
        if all(f == self.faces[0] for f in self.faces):
            faces = faces[:1]
        return {
            "name": self.name,
            "vertices_xy": [list(v) for v in self.vertices_xy],
            "height_m": self.height_m,
            "faces": faces,
            "top": self.top.to_dict(),
        }

    @classmethod
    def from_dict(cls, data: Any, where: str = "obstacle") -> Obstacle:
        d = mapping(where, data, {"name", "vertices_xy", "height_m", "faces", "top"})
        for key in ("vertices_xy", "height_m"):
            if key not in d:
                raise InputError(f"{where} is missing the field '{key}'")
        kwargs: dict[str, Any] = {}
        if "top" in d:
            kwargs["top"] = Material.from_dict(d["top"], f"{where}.top")
        faces = tuple(
            Face.from_dict(f, f"{where}.faces[{i}]") for i, f in enumerate(sequence(f"{where}.faces", d.get("faces", ["plain"])))
        )
        return cls(
            vertices_xy=tuple(
                point2(f"{where}.vertices_xy[{i}]", v) for i, v in enumerate(sequence(f"{where}.vertices_xy", d["vertices_xy"]))
            ),
            height_m=finite_float(f"{where}.height_m", d["height_m"]),
            faces=faces,
            name=str(d.get("name", "")),
            **kwargs,
        )


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
        return _segments(self)

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
        d = _point_segment_distance(pts, s.p0, s.p1).min(axis=1)
        inside = self.inside_obstacle(pts)
        d[inside] = 0.0
        return d

    def inside_obstacle(self, xy: np.ndarray) -> np.ndarray:
        """Whether each of N×2 points lies inside an obstacle polygon (even–odd rule)."""
        pts = np.atleast_2d(np.asarray(xy, dtype=np.float64))
        out = np.zeros(len(pts), dtype=bool)
        for ob in self.obstacles:
            v = np.asarray(ob.vertices_xy)
            out |= _point_in_polygon(pts, v)
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


@dataclass(frozen=True, eq=False)
class Segments:
    """The plan flattened into S face-carrying segments (read-only arrays).

    ``p0``, ``p1``: S×2 endpoints (m). ``height_m``: S top heights. ``obstacle``:
    S obstacle index (−1 for a wall). ``face_left``/``face_right``: S indices into
    ``faces`` (−1 where a side is not visible: the inside of an obstacle).
    """

    p0: np.ndarray
    p1: np.ndarray
    height_m: np.ndarray
    obstacle: np.ndarray
    face_left: np.ndarray
    face_right: np.ndarray
    faces: tuple[Face, ...]
    face_length_m: np.ndarray  # per entry of ``faces``
    face_height_m: np.ndarray
    face_glass: np.ndarray

    @property
    def count(self) -> int:
        return int(self.p0.shape[0])


def _segments(world: World) -> Segments:
    p0, p1, hs, obs, fl, fr = [], [], [], [], [], []
    faces: list[Face] = []
    flen: list[float] = []
    fh: list[float] = []
    for w in world.walls:
        p0.append(w.start_xy)
        p1.append(w.end_xy)
        hs.append(world.wall_height_m)
        obs.append(-1)
        fl.append(len(faces))
        faces.append(w.left)
        fr.append(len(faces))
        faces.append(w.right)
        flen += [w.length_m, w.length_m]
        fh += [world.wall_height_m, world.wall_height_m]
    for k, ob in enumerate(world.obstacles):
        n = len(ob.vertices_xy)
        for i in range(n):
            a, b = ob.vertices_xy[i], ob.vertices_xy[(i + 1) % n]
            p0.append(a)
            p1.append(b)
            hs.append(ob.height_m)
            obs.append(k)
            fl.append(-1)  # CCW polygon: the interior is on the left
            fr.append(len(faces))
            faces.append(ob.faces[i])
            flen.append(math.dist(a, b))
            fh.append(ob.height_m)

    def ro(a: Any, dtype: Any = np.float64) -> np.ndarray:
        arr = np.asarray(a, dtype=dtype)
        arr.setflags(write=False)
        return arr

    return Segments(
        p0=ro(np.reshape(p0, (-1, 2))),
        p1=ro(np.reshape(p1, (-1, 2))),
        height_m=ro(hs),
        obstacle=ro(obs, np.int64),
        face_left=ro(fl, np.int64),
        face_right=ro(fr, np.int64),
        faces=tuple(faces),
        face_length_m=ro(flen),
        face_height_m=ro(fh),
        face_glass=ro([f.glass for f in faces], bool),
    )


def _point_segment_distance(pts: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """N×S distances from points to segments."""
    e = p1 - p0  # S×2
    rel = pts[:, None, :] - p0[None, :, :]  # N×S×2
    t = np.clip(np.einsum("nsk,sk->ns", rel, e) / np.maximum(np.einsum("sk,sk->s", e, e), 1e-300), 0.0, 1.0)
    closest = p0[None] + t[..., None] * e[None]
    return np.linalg.norm(pts[:, None, :] - closest, axis=2)


def _point_in_polygon(pts: np.ndarray, v: np.ndarray) -> np.ndarray:
    x, y = pts[:, 0:1], pts[:, 1:2]
    a, b = v, np.roll(v, -1, axis=0)
    cond = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xcross = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return (np.count_nonzero(cond & (x < xcross), axis=1) % 2) == 1


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
        loader = getattr(yaml, "CSafeLoader", yaml.SafeLoader)
        data = json.loads(text) if p.suffix.lower() == ".json" else yaml.load(text, Loader=loader)  # noqa: S506 - a safe loader
    except (OSError, UnicodeDecodeError, yaml.YAMLError, json.JSONDecodeError) as exc:
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

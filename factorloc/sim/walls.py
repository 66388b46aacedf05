"""The solid parts of a floor plan: a :class:`Wall` (a thin, double-sided segment) and an :class:`Obstacle`
(a closed polygon extruded from the floor). World frame, metres; obstacle vertices counter-clockwise.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from factorloc._validate import finite_float, mapping, point2, positive_float, sequence
from factorloc.errors import InputError
from factorloc.sim.appearance import Face, Material

__all__ = ["Obstacle", "Wall"]


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

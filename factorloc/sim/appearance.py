"""What a face of the simulated world looks like: its :class:`Material`, its :class:`Decal` list, :class:`Face`.

Texture convention of a face: seen by a viewer standing in front of it, the texture's column ``u`` grows from
the viewer's left to right and its row from the top of the face (``z = height``) down to the floor, so
photographs are never mirrored.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from factorloc._validate import construct, finite_float, mapping, positive_float, sequence
from factorloc.errors import InputError

__all__ = ["Decal", "Face", "Material"]


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
        return construct(cls, where, d)


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
        return construct(cls, where, mapping(where, data, {"image", "u0_m", "u1_m", "z0_m", "z1_m"}))


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

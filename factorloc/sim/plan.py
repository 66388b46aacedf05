"""The floor plan as arrays for the renderers: :class:`Segments`, and the point–segment and point-in-polygon tests."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from factorloc.sim.appearance import Face

if TYPE_CHECKING:  # pragma: no cover
    from factorloc.sim.world import World

__all__ = ["Segments", "point_in_polygon", "point_segment_distance", "segments_of"]


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


def segments_of(world: World) -> Segments:
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


def point_segment_distance(pts: np.ndarray, p0: np.ndarray, p1: np.ndarray) -> np.ndarray:
    """N×S distances from points to segments."""
    e = p1 - p0  # S×2
    rel = pts[:, None, :] - p0[None, :, :]  # N×S×2
    t = np.clip(np.einsum("nsk,sk->ns", rel, e) / np.maximum(np.einsum("sk,sk->s", e, e), 1e-300), 0.0, 1.0)
    closest = p0[None] + t[..., None] * e[None]
    return np.linalg.norm(pts[:, None, :] - closest, axis=2)


def point_in_polygon(pts: np.ndarray, v: np.ndarray) -> np.ndarray:
    x, y = pts[:, 0:1], pts[:, 1:2]
    a, b = v, np.roll(v, -1, axis=0)
    cond = (a[:, 1] > y) != (b[:, 1] > y)
    with np.errstate(divide="ignore", invalid="ignore"):
        xcross = a[:, 0] + (y - a[:, 1]) * (b[:, 0] - a[:, 0]) / (b[:, 1] - a[:, 1])
    return (np.count_nonzero(cond & (x < xcross), axis=1) % 2) == 1

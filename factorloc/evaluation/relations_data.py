"""Ground-truth relations of the benchmark of Kümmerle et al. (2009): the data and its reader.

(Kept apart from :mod:`factorloc.evaluation.relations`, which runs the benchmark, so that the tests of the relations
themselves, :mod:`factorloc.evaluation.relations_lattice`, need not import it.)
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from factorloc.errors import DatasetError, InputError

__all__ = ["Relations", "read_relations"]


@dataclass(frozen=True, eq=False)
class Relations:
    """Ground-truth relations: (N,) ``t1_s``, ``t2_s`` and (N, 3) ``poses``.

    ``poses[i] = [x_m, y_m, yaw_rad]`` is the robot at ``t2_s[i]`` in the robot frame at ``t1_s[i]``.
    """

    t1_s: np.ndarray
    t2_s: np.ndarray
    poses: np.ndarray

    def __len__(self) -> int:
        return int(self.t1_s.shape[0])

    def subset(self, every: int = 1, offset: int = 0) -> Relations:
        """Every ``every``-th relation starting at ``offset`` (a fixed, reproducible subset)."""
        if every < 1:
            raise InputError(f"every must be >= 1, got {every!r}")
        sl = slice(offset, None, every)
        return Relations(self.t1_s[sl], self.t2_s[sl], self.poses[sl])


def read_relations(path: str | Path) -> Relations:
    """Read a ``.relations`` file: lines ``t1 t2 x y z roll pitch yaw`` (s, m, rad)."""
    p = Path(path)
    if not p.is_file():
        raise DatasetError(f"relations file not found: {p}")
    try:
        a = np.loadtxt(p, ndmin=2)
    except ValueError as exc:
        raise DatasetError(f"relations file {p} is malformed: {exc}") from exc
    if a.shape[1] != 8:
        raise DatasetError(f"relations file {p} must have 8 columns (t1 t2 x y z roll pitch yaw), got {a.shape[1]}")
    return Relations(a[:, 0].copy(), a[:, 1].copy(), a[:, [2, 3, 7]].copy())

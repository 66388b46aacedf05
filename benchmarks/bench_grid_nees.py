"""The ICP step's position NEES against the relations, and against the true motion where the relations are gridded.

Where a log's relations are its odometry moved by whole grid steps of ``s``
(:func:`factorloc.evaluation.relations_lattice.find_relations_grid`; MIT CSAIL's local relations, 5 cm), the relation
is the true motion plus a rounding error uniform over the grid cell, independent of the step's own error: its
covariance is ``s²/12 · I``, and the NEES measured against the relation is the NEES against the true motion plus
``s²/12 · tr(Σ⁻¹)`` on average. This prints, per log and kind (local / loop), over the reliable ICP estimates of
every ``--every``-th relation: the measured NEES (2 dof), that grid part, their difference (the NEES against the
true motion), and the rms σ of the estimates::

    nice -n 10 .venv/bin/python benchmarks/bench_grid_nees.py --every 3
"""

from __future__ import annotations

import argparse
import math
from pathlib import Path

import numpy as np

from factorloc.datasets.rosbag import read_laser_log
from factorloc.evaluation.relations import Relations, read_relations, relations_benchmark
from factorloc.evaluation.relations_lattice import find_relations_grid

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "laser"
LOGS = {"intel": ("intel.sort.bag", "intel.relations"), "aces": ("aces.sort.bag", "aces.relations"),
        "mit": ("mit-csail.sort.bag", "mit-csail.relations")}  # fmt: skip


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--every", type=int, default=3, help="every k-th relation (fixed subset)")
    ap.add_argument("--logs", default="intel,aces,mit")
    args = ap.parse_args()
    print("log    kind   n    NEES  grid part  vs true motion  rms σ cm")
    for name in args.logs.split(","):
        bag, relf = LOGS[name]
        log = read_laser_log(args.data / bag)
        rel = read_relations(args.data / relf)
        lattice = find_relations_grid(rel, log.odometry)  # None: not gridded (chance hits are not discounted)
        sub = np.arange(0, len(rel), args.every)
        rows = relations_benchmark(
            log, Relations(rel.t1_s[sub], rel.t2_s[sub], rel.poses[sub]), methods=("ours", "ours_icp"), truth_rounding=None
        )
        for kind in ("local", "loop"):
            vals = []
            for r in rows:
                if r.method != "ours_icp" or r.kind != kind or not r.reliable or not math.isfinite(r.nees_position):
                    continue
                C = np.array(r.diagnostics["icp_covariance_position"])
                on = lattice is not None and bool(lattice.on_lattice[sub[r.index]])
                part = (lattice.step_m**2 / 12.0) * float(np.trace(np.linalg.inv(C))) if on else 0.0
                vals.append((r.nees_position, part, float(np.trace(C)) / 2.0))
            if vals:
                v = np.array(vals)
                print(
                    f"{name:6s} {kind:5s} {len(v):4d} {v[:, 0].mean():6.2f} {v[:, 1].mean():9.2f} "
                    f"{(v[:, 0] - v[:, 1]).mean():14.2f} {100 * math.sqrt(v[:, 2].mean()):9.2f}"
                )


if __name__ == "__main__":
    main()

"""What the ICP step's seed rules buy against kidnapping: the full pipeline on simulated kidnapped robots (the real
logs have none), with each rule of ``--ablate`` left out in turn.

``generate_scenario('apartment', n, seed, faults=('kidnapped',))`` for each seed; a query is *recovered* when the
fused pose is within 10 cm and 1° of the truth, *confidently wrong* when its position error lies outside the fused
covariance's 3σ ellipse (χ², 2 dof) while the pose is determined.

Usage::

    .venv/bin/python benchmarks/bench_icp_kidnapped.py --queries 30 --seeds 1,2,3
"""

from __future__ import annotations

import argparse
import math
from dataclasses import replace

import numpy as np

from factorloc import Config, Localizer
from factorloc.sim import generate_scenario

RULES = (
    "icp.global.seed_refuted",
    "icp.global.ambiguity.overturn",
    "icp.seed.consistency",
    "icp.seed.free_space",
    "icp.seed.fits_near",
    "icp.seed.stays_near",
    "global_init.widen",
)


def _config(what: str) -> Config:
    c = Config()
    if not what:
        return c
    icp = c.icp
    if what.startswith("icp."):
        return replace(c, icp=replace(icp, ablate=(what,)))
    group, name = what.split(".")
    return replace(c, icp=replace(icp, **{group: replace(getattr(icp, group), **{name: False})}))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--queries", type=int, default=30)
    ap.add_argument("--seeds", default="1,2,3")
    ap.add_argument("--ablate", default=",".join(RULES))
    args = ap.parse_args()
    scenarios = [generate_scenario("apartment", args.queries, int(s), faults=("kidnapped",)) for s in args.seeds.split(",")]
    limit = 11.829
    print(f"{'left out':34s} {'kidnapped: n  recovered  c.w.':>32s}   {'clean: n  recovered  c.w.':>28s}")
    for what in ["", *[w for w in args.ablate.split(",") if w]]:
        cfg = _config(what)
        out = {k: [0, 0, 0] for k in ("kidnapped", "clean")}
        for sc in scenarios:
            loc_ = Localizer(sc.references[0].reference, cfg)
            for sq in sc.queries:
                row = out["kidnapped" if "kidnapped" in sq.faults else "clean"]
                loc = loc_.localize(sq.query)
                e = np.array([loc.pose.x - sq.truth.x, loc.pose.y - sq.truth.y])
                herr = abs(math.degrees(math.remainder(loc.pose.theta - sq.truth.theta, 2 * math.pi)))
                cov = loc.covariance[:2, :2]
                row[0] += 1
                row[1] += int(float(np.hypot(*e)) < 0.1 and herr < 1.0)
                row[2] += int(loc.determined and bool(np.all(np.isfinite(cov)) and e @ np.linalg.solve(cov, e) > limit))
        k, c = out["kidnapped"], out["clean"]
        print(
            f"{what or '(nothing: the default)':34s} {k[0]:12d} {k[1]:10d} {k[2]:5d}   {c[0]:10d} {c[1]:10d} {c[2]:5d}",
            flush=True,
        )


if __name__ == "__main__":
    main()

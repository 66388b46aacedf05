"""Fixed localization cases whose verdicts must not depend on rounding, and their fingerprints.

Used by ``tests/test_stability.py`` in-process and, as a script, in subprocesses whose numerics are forced
onto other paths (numba's JIT off, the instruction sets of an AVX2-only or an SSE4.2-only CPU): ``python
tests/stability_cases.py [--shared DIR] [--perturb M] [--vision]`` prints one JSON object, case id → fingerprint.

Cases: one straight wall (the rank-deficient normal scatter of issue 13), a corridor of two parallel walls,
and a fixed sample of real local relations of the Intel and ACES logs (every ``LASER_EVERY``-th relation
shorter than 2 m of odometry path, when ``../shared/data/laser`` is present). With ``vision``: every
``SAMPLE_EVERY``-th query of the shipped sample scenario (``data/sample``), through the whole hierarchy (the
compass's SIFT and the correlation's image pyramids run in OpenCV, whose kernels depend on the CPU).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

from factorloc import Localization, Localizer, Odometry, Pose2, Query, Reference, Scan

#: Every how many-th short local relation of each real log enters the sample.
LASER_EVERY = 120
#: Every how many-th query of the shipped sample scenario enters the visual cases.
SAMPLE_EVERY = 1
SAMPLE = Path(__file__).resolve().parents[1] / "data" / "sample"
#: The odometry σ model of the relations benchmark (raw wheel odometry, honest 3σ tail).
ODOMETRY_SIGMAS = {
    "drift_ratio": 0.2,
    "min_sigma_m": 0.05,
    "heading_drift_ratio": 0.15,
    "heading_drift_rad_per_m": 0.08,
    "min_sigma_rad": math.radians(0.3),
}


def single_wall(noise_seed: int = 3) -> tuple[Reference, Query]:
    """One 8 m wall along the world diagonal y = x, seen by the reference and the query (3 mm noise); the
    odometry is 20 cm off along the wall and 10 cm off across it (σ 30 cm, 3°)."""
    rng = np.random.default_rng(noise_seed)
    t = np.linspace(-4.0, 4.0, 400)
    wall = np.column_stack([t, t])
    along = np.array([1.0, 1.0]) / math.sqrt(2.0)
    across = np.array([along[1], -along[0]])
    T_ref, truth = Pose2(1.0, 0.0, 0.3), Pose2(1.5, 0.2, 1.0)
    ref = Reference(scan=Scan(T_ref.inverse().transform_points(wall)), T_world_reference=T_ref)
    p = truth.translation + 0.2 * along + 0.1 * across
    odo = Odometry(Pose2(p[0], p[1], truth.theta + math.radians(2.0)), 0.3, 0.3, math.radians(3.0))
    scan = truth.inverse().transform_points(wall) + rng.normal(0.0, 0.003, wall.shape)
    return ref, Query(scan=Scan(scan), odometry=odo)


def corridor(noise_seed: int = 5) -> tuple[Reference, Query]:
    """Two parallel 10 m walls 2 m apart (a featureless corridor along world x); the odometry 30 cm off along it."""
    rng = np.random.default_rng(noise_seed)
    t = np.linspace(-5.0, 5.0, 300)
    walls = np.vstack([np.column_stack([t, np.full_like(t, 1.0)]), np.column_stack([t, np.full_like(t, -1.0)])])
    T_ref, truth = Pose2(0.0, 0.0, 0.0), Pose2(0.8, 0.1, 0.05)
    ref = Reference(scan=Scan(walls), T_world_reference=T_ref)
    odo = Odometry(Pose2(truth.x + 0.3, truth.y - 0.05, truth.theta + math.radians(1.5)), 0.4, 0.4, math.radians(3.0))
    scan = truth.inverse().transform_points(walls) + rng.normal(0.0, 0.003, walls.shape)
    return ref, Query(scan=Scan(scan), odometry=odo)


def laser_cases(laser_dir: Path) -> dict[str, tuple[Reference, Query]]:
    """Every ``LASER_EVERY``-th real local relation (odometry path < 2 m) of Intel and ACES, as reference/query pairs
    in the frame of the robot at t1 (as the relations benchmark poses them)."""
    from factorloc.datasets.rosbag import read_laser_log

    out: dict[str, tuple[Reference, Query]] = {}
    for name in ("intel", "aces"):
        log = read_laser_log(laser_dir / f"{name}.sort.bag")
        rel = np.loadtxt(laser_dir / f"{name}.relations", ndmin=2)
        short = [i for i in range(len(rel)) if log.odometry.distance_between(rel[i, 0], rel[i, 1])[0] < 2.0]
        for i in short[::LASER_EVERY]:
            t1, t2 = float(rel[i, 0]), float(rel[i, 1])
            d, r = log.odometry.distance_between(t1, t2)
            odo = Odometry.from_distance(log.odometry.between(t1, t2), d, r, **ODOMETRY_SIGMAS)
            ref = Reference(scan=log.scans.at(t1, 2e-3), T_world_reference=Pose2())
            out[f"{name}-{i}"] = (ref, Query(scan=log.scans.at(t2, 2e-3), odometry=odo))
    return out


def sample_cases() -> dict[str, tuple[Reference, Query]]:
    """Every ``SAMPLE_EVERY``-th query of the shipped sample scenario (panorama, cloud and scan; faults included)."""
    from factorloc.datasets import load_scenario

    scenario = load_scenario(SAMPLE)
    refs = {r.id: r.reference for r in scenario.references}
    return {f"sample-{q.query.id}": (refs[q.reference_id], q.query) for q in scenario.queries[::SAMPLE_EVERY]}


def all_cases(shared_dir: Path | None, vision: bool = False) -> dict[str, tuple[Reference, Query]]:
    cases = {"single-wall": single_wall(), "corridor": corridor()}
    laser = None if shared_dir is None else shared_dir / "data" / "laser"
    if laser is not None and (laser / "intel.sort.bag").is_file():
        cases.update(laser_cases(laser))
    if vision:
        cases.update(sample_cases())
    return cases


def perturbed(query: Query, delta_m: float, seed: int = 0) -> Query:
    """The query with every scan point moved by ±``delta_m`` in x and y (random signs)."""
    pts = query.scan.points_m
    signs = np.random.default_rng(seed).choice([-1.0, 1.0], size=pts.shape)
    return Query(scan=Scan(pts + delta_m * signs), odometry=query.odometry)


def fingerprint(loc: Localization) -> dict[str, object]:
    """What must not change: each step's status and failed check codes, the fused pose, what is undetermined; and
    the fused σ per axis (m, m, rad; the scale of the pose's tolerance)."""
    steps = {
        r.name: {
            "status": r.status.value,
            "reliable": None if r.estimate is None else r.estimate.reliable,
            "failed": [] if r.estimate is None else sorted(c.code for c in r.estimate.checks if not c.passed),
        }
        for r in loc.steps
    }
    return {
        "steps": steps,
        "pose": loc.pose.as_array().tolist(),
        "sigma": np.sqrt(np.diag(loc.covariance)).tolist(),
        "undetermined": sorted(c.value for c in loc.undetermined),
    }


def run(shared_dir: Path | None, delta_m: float = 0.0, vision: bool = False) -> dict[str, dict[str, object]]:
    out = {}
    localizers: dict[int, Localizer] = {}  # one per reference: the sample's queries share theirs
    for key, (ref, query) in all_cases(shared_dir, vision).items():
        q = perturbed(query, delta_m) if delta_m else query
        localizer = localizers.setdefault(id(ref), Localizer(ref))
        out[key] = fingerprint(localizer.localize(q))
    return out


def main(argv: list[str]) -> int:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--shared", type=Path, default=None)
    parser.add_argument("--perturb", type=float, default=0.0)
    parser.add_argument("--vision", action="store_true", help="the sample scenario's queries too")
    args = parser.parse_args(argv)
    json.dump(run(args.shared, args.perturb, args.vision), sys.stdout)
    return 0


if __name__ == "__main__":
    raise SystemExit(main(sys.argv[1:]))

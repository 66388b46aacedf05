"""The same verdicts on every CPU: a workload run under the kernels of other CPUs, compared with this one's.

Usage::

    .venv/bin/python benchmarks/bench_cpu_paths.py                                   # the three laser logs of ../shared
    .venv/bin/python benchmarks/bench_cpu_paths.py --every 3 --scenario /tmp/apt31 --queries 150

Each CPU is emulated on this one by every library's own switch (numpy's dispatch, numba's target, OpenBLAS's
kernels, OpenCV's dispatch, Intel IPP's kernels), in a subprocess with its own numba cache; ``threads-2`` runs
BLAS and OpenCV with two threads instead of one. The workloads: ``relations_benchmark`` (``ours`` and
``ours_icp``) on every ``--every``-th relation of each laser log, and the default hierarchy on the first
``--queries`` queries of ``--scenario`` (and of the shipped ``data/sample``). Printed per CPU path and workload:
the results compared, how many are bit-identical, how many differ in a verdict (reliable, confidently wrong, the
global search used, each step's status and failed check codes), and the largest difference of a value (m, rad;
relations: the translation and rotation errors; queries: each step's estimate and the fused pose, also as a
fraction of the fused σ). ``tests/test_stability.py`` holds the verdicts equal on fixed cases.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import subprocess
import sys
import tempfile
from pathlib import Path

from factorloc.sim.determinism import EMULATED_CPUS

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_LASER = ROOT.parent / "shared" / "data" / "laser"

#: Environment switches per CPU path (``native`` = this CPU as it is, one thread).
CPU_PATHS: dict[str, dict[str, str]] = {
    "native": {},
    **EMULATED_CPUS,
    "threads-2": {"OMP_NUM_THREADS": "2", "OPENBLAS_NUM_THREADS": "2", "FACTORLOC_BENCH_CV_THREADS": "2"},
}
ONE_THREAD = {"OMP_NUM_THREADS": "1", "OPENBLAS_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "FACTORLOC_BENCH_CV_THREADS": "1"}


def _relation_rows(laser: Path, every: int) -> dict[str, dict]:
    from factorloc.evaluation.folds import load_laser_datasets
    from factorloc.evaluation.relations import relations_benchmark

    out = {}
    for ds in load_laser_datasets(laser, every=every):
        for r in relations_benchmark(ds.log, ds.relations, methods=("ours", "ours_icp")):
            d = r.diagnostics
            out[f"{ds.name}/{r.method}/{r.index}"] = {
                "verdict": [
                    r.reliable,
                    r.confidently_wrong,
                    r.used_global_init,
                    d.get("icp_status"),
                    list(d.get("icp_failed_checks", ())),
                ],
                "values": [r.error_translation_m, math.radians(r.error_rotation_deg)],
                "sigma": None,
            }
    return out


def _query_rows(scenario: Path, n: int) -> dict[str, dict]:
    import numpy as np

    from factorloc.datasets import load_scenario
    from factorloc.pipeline import Localizer

    sc = load_scenario(scenario)
    refs = {r.id: r.reference for r in sc.references}
    localizers: dict[str, Localizer] = {}
    out = {}
    for q in sc.queries[:n]:
        loc = localizers.setdefault(q.reference_id, Localizer(refs[q.reference_id]))
        res = loc.localize(q.query)
        verdict, values = [], []
        for s in res.steps:
            e = s.estimate
            verdict.append([s.name, s.status.value, None if e is None else e.reliable])
            if e is not None:
                verdict[-1].append(sorted(c.code for c in e.checks if not c.passed))
                values += [float(v) for v in e.values]
        pose = None if res.pose is None else res.pose.as_array().tolist()
        sigma = None if res.pose is None else np.sqrt(np.diag(res.covariance)).tolist()
        out[f"{scenario.name}/{q.query.id}"] = {"verdict": verdict, "values": values, "pose": pose, "sigma": sigma}
    return out


def _worker(args: argparse.Namespace) -> None:
    import cv2

    cv2.setNumThreads(int(os.environ.get("FACTORLOC_BENCH_CV_THREADS", "1")))
    rows: dict[str, dict] = {}
    if args.laser is not None and args.laser.is_dir():
        rows.update(_relation_rows(args.laser, args.every))
    for scenario in args.scenarios:
        rows.update(_query_rows(scenario, args.queries))
    args.out.write_text(json.dumps(rows))


def _differences(a: dict, b: dict) -> tuple[int, list[str], float, float]:
    """(bit-identical, the keys whose verdicts differ, largest |Δ| of a value, largest |Δ pose| / σ)."""
    same = 0
    verdicts: list[str] = []
    largest = largest_sigma = 0.0
    for key, x in a.items():
        y = b[key]
        if x == y:
            same += 1
            continue
        if x["verdict"] != y["verdict"] or len(x["values"]) != len(y["values"]):
            verdicts.append(key)
            continue
        for u, v in zip(x["values"], y["values"], strict=True):
            if math.isfinite(u) and math.isfinite(v):
                largest = max(largest, abs(u - v))
        if x.get("pose") and y.get("pose"):
            for u, v, s in zip(x["pose"], y["pose"], x["sigma"], strict=True):
                largest = max(largest, abs(u - v))
                largest_sigma = max(largest_sigma, abs(u - v) / s)
    return same, verdicts, largest, largest_sigma


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--laser", type=Path, default=DEFAULT_LASER, help="the laser logs (skipped when absent)")
    ap.add_argument("--every", type=int, default=3, help="every N-th relation of each log")
    ap.add_argument("--scenario", type=Path, action="append", default=[], help="a scenario (repeatable)")
    ap.add_argument("--queries", type=int, default=150, help="the first N queries of each scenario")
    ap.add_argument("--paths", nargs="*", default=list(CPU_PATHS), choices=list(CPU_PATHS))
    ap.add_argument("--worker", type=Path, default=None, help=argparse.SUPPRESS)
    args = ap.parse_args()
    args.scenarios = [ROOT / "data" / "sample", *args.scenario]
    if args.worker is not None:
        args.out = args.worker
        _worker(args)
        return
    paths = ["native", *[p for p in args.paths if p != "native"]]
    results: dict[str, dict] = {}
    with tempfile.TemporaryDirectory() as tmp:
        for name in paths:
            out = Path(tmp) / f"{name}.json"
            cmd = [sys.executable, __file__, "--worker", str(out), "--laser", str(args.laser), "--every", str(args.every)]
            cmd += ["--queries", str(args.queries)]
            for s in args.scenario:
                cmd += ["--scenario", str(s)]
            env = {**os.environ, **ONE_THREAD, **CPU_PATHS[name], "NUMBA_CACHE_DIR": str(Path(tmp) / f"numba-{name}")}
            print(f"running {name} ...", flush=True)
            subprocess.run(cmd, env=env, check=True)
            results[name] = json.loads(out.read_text())
    base = results["native"]
    groups = sorted({k.split("/")[0] for k in base})
    notes: list[str] = []
    print(
        "\n| CPU path | workload | results | bit-identical | verdicts differing | largest value difference "
        "| largest pose difference / σ |"
    )
    print("|---|---|---|---|---|---|---|")
    for name in paths[1:]:
        for g in groups:
            a = {k: v for k, v in base.items() if k.split("/")[0] == g}
            b = {k: results[name][k] for k in a}
            same, verdicts, largest, largest_sigma = _differences(a, b)
            sig = "—" if g in ("intel", "aces", "mit-csail") else f"{largest_sigma:.2g}"
            print(f"| {name} | {g} | {len(a)} | {same} | {len(verdicts)} | {largest:.2g} | {sig} |")
            notes += [f"{name} {k}: {a[k]['verdict']} -> {b[k]['verdict']}" for k in verdicts]
    for line in notes:
        print(line)


if __name__ == "__main__":
    main()

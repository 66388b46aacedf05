"""Issue #21, reproducer 5: the inputs that once took tens of seconds or asked for terabytes, each timed in its own
process (wall time and peak resident memory). Target: each under 5 s and 2 GB.

Run: ``nice -n 10 .venv/bin/python benchmarks/bench_bad_input.py`` (all cases) or ``… --case NAME``. Prints a
table; asserts nothing. The time includes the case's own setup (loading the sample scenario) but not the
interpreter's start, imports and kernel warm-up; the peak is the case process's own maximum resident set. On a
shared machine the wall time includes waiting for a core: the CPU time (``cpu s``, all threads) is printed too.
"""

from __future__ import annotations

import argparse
import json
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "data" / "sample"
CASES: dict[str, Callable[[], str]] = {}


def case(fn: Callable[[], str]) -> Callable[[], str]:
    CASES[fn.__name__] = fn
    return fn


def _sample():  # noqa: ANN202
    from factorloc.datasets import load_scenario

    return load_scenario(SAMPLE)


def _localize(query, reference) -> str:  # noqa: ANN001
    import factorloc as fl

    loc = fl.localize(reference, query)
    icp = next((r for r in loc.steps if r.name == "icp"), None)
    sig = np.sqrt(np.diag(loc.covariance))
    return f"icp {icp.status.value if icp else '-'}; σ {np.array2string(sig, precision=3)}"


def _query_with(scan=None, odometry_at=None):  # noqa: ANN001, ANN202
    import factorloc as fl

    s = _sample()
    q = s.queries[0].query
    odo = q.odometry
    if odometry_at is not None:
        odo = fl.Odometry(fl.Pose2(*odometry_at), 0.1, 0.1, 0.05)
    return fl.Query(scan=q.scan if scan is None else scan, odometry=odo, id="bad"), s.reference


@case
def icp_seed_at_1e9_m() -> str:
    q, ref = _query_with(odometry_at=(1e9, 0.0, 0.0))
    return _localize(q, ref)


def _spread_reference(extent_m: float):  # noqa: ANN202
    import factorloc as fl

    pts = np.array([[0.0, 0.0], [extent_m, 0.0], [0.0, extent_m], [extent_m, extent_m]])
    return fl.Reference(scan=fl.Scan(pts))


@case
def reference_4_points_over_1_km() -> str:
    q, _ = _query_with()
    return _localize(q, _spread_reference(1000.0))


@case
def reference_4_points_over_10_km() -> str:
    q, _ = _query_with()
    return _localize(q, _spread_reference(10_000.0))


def _dense(scan_m: np.ndarray, n: int, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    idx = rng.integers(0, len(scan_m), n)
    return scan_m[idx] + rng.normal(0.0, 0.005, (n, 2))


@case
def query_scan_of_1e6_points() -> str:
    import factorloc as fl

    q, ref = _query_with()
    return _localize(fl.Query(scan=fl.Scan(_dense(q.scan.points_m, 1_000_000)), odometry=q.odometry), ref)


@case
def reference_scan_of_1e6_points() -> str:
    import factorloc as fl

    q, ref = _query_with()
    big = fl.Reference(scan=fl.Scan(_dense(ref.scan.points_m, 1_000_000)), T_world_reference=ref.T_world_reference)
    return _localize(q, big)


@case
def query_cloud_of_1e6_points() -> str:
    import factorloc as fl

    s = _sample()
    q = s.queries[0].query
    rng = np.random.default_rng(1)
    pts = q.cloud.points_m[rng.integers(0, len(q.cloud), 1_000_000)] + rng.normal(0.0, 0.005, (1_000_000, 3))
    return _localize(fl.Query(cloud=fl.PointCloud(pts), odometry=q.odometry), s.reference)


def _fuse(n: int, outlier_every: int = 10) -> str:
    import factorloc as fl

    rng = np.random.default_rng(2)
    ests = []
    for i in range(n):
        spread = 1.0 if i % outlier_every == 0 else 0.01
        ests.append(fl.Estimate.pose(f"e{i}", fl.Pose2(*rng.normal(0.0, spread, 3)), 0.01, 0.01, 0.01))
    loc = fl.fuse(ests)
    fused = sum(r.status.value == "fused" for r in loc.steps)
    return f"{fused} of {n} fused"


@case
def fuse_1000_estimates() -> str:
    return _fuse(1000)


@case
def fuse_5000_estimates() -> str:
    return _fuse(5000)


@case
def fuse_3000_mutually_inconsistent() -> str:
    """The gate's worst case: every estimate disagrees with every other, so it rejects them one round at a time."""
    return _fuse(3000, outlier_every=1)


def _damaged(edit: Callable[[Path], None]) -> str:
    from factorloc.datasets import load_scenario
    from factorloc.errors import FactorlocError

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "s"
        shutil.copytree(SAMPLE, root)
        edit(root)
        try:
            load_scenario(root)
        except FactorlocError as exc:
            return f"{type(exc).__name__}: {str(exc)[-70:]}"
        return "loaded"


@case
def npy_header_claiming_1e12_rows() -> str:
    def edit(root: Path) -> None:
        p = root / "references" / "ref0" / "scan.npy"
        raw = p.read_bytes()
        p.write_bytes(raw.replace(b"(360, 2)", b"(1000000000000, 2)", 1))

    return _damaged(edit)


@case
def yaml_alias_bomb_in_metadata() -> str:
    def edit(root: Path) -> None:
        p = root / "scenario.yaml"
        levels = ["a: &a [" + ",".join(["x"] * 10) + "]"]
        levels += [f"  {c}: &{c} [" + ",".join([f"*{p}"] * 10) + "]" for p, c in zip("abcdefgh", "bcdefghi", strict=True)]
        p.write_text(p.read_text().replace("metadata:\n  generator", "metadata:\n  " + "\n".join(levels) + "\n  generator", 1))

    return _damaged(edit)


def run_one(name: str) -> None:
    t0 = time.perf_counter()
    import factorloc  # noqa: F401 - imports and the numba cache are not the case's work
    import factorloc.jit

    factorloc.jit.warm_up()
    t1, c1 = time.perf_counter(), time.process_time()
    try:
        outcome = CASES[name]()
    except Exception as exc:  # noqa: BLE001 - reported as the case's outcome
        outcome = f"{type(exc).__name__}: {' '.join(str(exc).split())[:80]}"
    t2, c2 = time.perf_counter(), time.process_time()
    peak_mb = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024.0  # Linux: KiB
    record = {"case": name, "outcome": outcome, "seconds": t2 - t1, "cpu_s": c2 - c1, "import_s": t1 - t0, "peak_mb": peak_mb}
    print(json.dumps(record))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", choices=sorted(CASES))
    ap.add_argument("--timeout", type=float, default=120.0)
    args = ap.parse_args()
    if args.case:
        run_one(args.case)
        return
    print(f"{'case':34} {'seconds':>8} {'cpu s':>7} {'peak MB':>8}  {'within':6}  outcome")
    for name in CASES:
        proc = subprocess.Popen(
            [sys.executable, __file__, "--case", name], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True
        )
        t0 = time.perf_counter()
        try:
            out, err = proc.communicate(timeout=args.timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            out, err = proc.communicate()
            print(f"{name:34} {'>' + str(int(args.timeout)):>8} {'':>7} {'':>8}  {'no':6}  timed out")
            continue
        line = next((ln for ln in out.splitlines() if ln.startswith("{")), None)
        if line is None:
            print(f"{name:34} {time.perf_counter() - t0:8.1f} {'':>7} {'':>8}  {'no':6}  crashed: {err.strip()[-100:]}")
            continue
        r = json.loads(line)
        peak_mb = r["peak_mb"]
        ok = "yes" if r["seconds"] <= 5.0 and peak_mb <= 2048 else "no"
        print(f"{name:34} {r['seconds']:8.2f} {r['cpu_s']:7.2f} {peak_mb:8.0f}  {ok:6}  {r['outcome']}")


if __name__ == "__main__":
    main()

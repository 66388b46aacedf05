"""Throughput of the batch evaluation in process and on 1 and 2 local Dask workers (factorloc.parallel).

    .venv/bin/python benchmarks/bench_parallel.py                 # the issue's 300-query simulated scenario
    .venv/bin/python benchmarks/bench_parallel.py --queries 120   # a smaller one (same world, same seed)
    .venv/bin/factorloc simulate /tmp/sim300 --queries 300 --seed 7 && \
    .venv/bin/python benchmarks/bench_parallel.py --scenario /tmp/sim300   # a scenario rendered once, on disk

For each executor: queries per second of :func:`factorloc.evaluation.run_hierarchy` on a scenario generated in
the built-in apartment (seed 7, the default fault mix), after an untimed warm-up pass on the first queries
(the workers' numba cache load and imports); the speedup and the efficiency ``speedup / workers`` against the
in-process run; the mean per-query time each worker measured itself (it grows when the workers compete for
the cores); the overhead per task (a no-op chunk function over 200 one-item chunks, and the cluster's start
time). The results of the 2-worker run are checked to be identical to the serial run's (poses, covariances).
The 1-minute load average before and after is printed: on a shared machine it bounds what 2 workers can gain.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from factorloc.evaluation.cases import evaluation_set
from factorloc.evaluation.runner import HierarchyRun, run_hierarchy
from factorloc.parallel import DaskExecutor, SerialExecutor


def _noop(chunk: Sequence[int], shared: Any) -> list[int]:
    return list(chunk)


def _load() -> float:
    return float(os.getloadavg()[0])


def _timed(data: Any, executor: Any, warmup: int) -> tuple[float, HierarchyRun]:
    """Seconds of one run_hierarchy pass over ``data``, after an untimed pass over its first ``warmup`` queries."""
    if warmup:
        run_hierarchy(_first(data, warmup), executor=executor)
    t0 = time.perf_counter()
    run = run_hierarchy(data, executor=executor)
    return time.perf_counter() - t0, run


def _first(data: Any, n: int) -> Any:
    from factorloc.evaluation.cases import EvaluationSet

    return EvaluationSet(data.references, data.cases[:n], data.name, data.world)


def _same(a: HierarchyRun, b: HierarchyRun) -> bool:
    if len(a.runs) != len(b.runs):
        return False
    for x, y in zip(a.runs, b.runs, strict=True):
        la, lb = x.localization, y.localization
        if la.pose.as_array().tobytes() != lb.pose.as_array().tobytes() or la.covariance.tobytes() != lb.covariance.tobytes():
            return False
    return True


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--queries", type=int, default=300, help="queries generated (or the first N of --scenario)")
    ap.add_argument("--seed", type=int, default=7)
    ap.add_argument("--warmup", type=int, default=8, help="untimed queries before each timed pass")
    ap.add_argument("--scenario", type=Path, default=None, help="a scenario directory instead of generating one")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    from factorloc.sim import generate_scenario

    t0 = time.perf_counter()
    if args.scenario is not None:
        from factorloc.datasets import load_scenario

        data = evaluation_set(load_scenario(args.scenario))
        if args.queries < len(data.cases):
            data = _first(data, args.queries)
        print(f"loaded {len(data.cases)} queries of {data.name} in {time.perf_counter() - t0:.1f} s")
    else:
        data = evaluation_set(generate_scenario("apartment", args.queries, args.seed))
        print(f"generated {len(data.cases)} queries (apartment, seed {args.seed}) in {time.perf_counter() - t0:.1f} s")
    out: dict[str, Any] = {"queries": len(data.cases), "seed": args.seed, "cores": os.cpu_count(), "load_before": _load()}
    rows = []
    t_serial, serial = _timed(data, SerialExecutor(), args.warmup)
    rows.append(("in process", 1, t_serial, serial, math.nan))
    for n in (1, 2):
        t0 = time.perf_counter()
        with DaskExecutor(workers=n) as ex:
            start_s = time.perf_counter() - t0
            t, run = _timed(data, ex, args.warmup)
            rows.append((f"{n} Dask worker{'s' if n > 1 else ''}", n, t, run, start_s))
            if n == 2:
                m = 200
                t1 = time.perf_counter()
                list(ex.map_chunks(_noop, list(range(m)), 1))
                out["overhead_per_task_ms"] = 1e3 * (time.perf_counter() - t1) / m
                out["identical_to_serial"] = _same(serial, run)
    out["load_after"] = _load()
    q = len(data.cases)
    head = ("executor", "wall s", "queries/s", "speedup", "efficiency", "ms/query (own)", "start s")
    print(f"{head[0]:16s} " + " ".join(f"{h:>10s}" for h in head[1:]))
    out["runs"] = []
    for label, n, t, run, start_s in rows:
        thr = q / t
        speedup = t_serial / t
        own = 1e3 * sum(r.localize_seconds for r in run.runs) / max(1, len(run.runs))
        print(f"{label:16s} {t:10.1f} {thr:10.2f} {speedup:9.2f}× {speedup / n:10.2f} {own:10.1f} {start_s:10.1f}")
        out["runs"].append(
            {"executor": label, "workers": n, "wall_s": t, "queries_per_s": thr, "speedup": speedup,
             "efficiency": speedup / n, "own_ms_per_query": own, "start_s": start_s}
        )  # fmt: skip
    print(f"overhead per task (no-op, 200 one-item chunks on 2 workers): {out['overhead_per_task_ms']:.1f} ms")
    print(f"2 workers identical to in process (poses, covariances): {out['identical_to_serial']}")
    print(f"load average (1 min) before {out['load_before']:.2f}, after {out['load_after']:.2f} on {out['cores']} cores")
    if args.json is not None:
        args.json.write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()

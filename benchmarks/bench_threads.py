"""Per-query wall and CPU time of the hierarchy in one process under a thread / allocator setting.

    for m in default blas1 cv1 all1; do .venv/bin/python benchmarks/bench_threads.py /tmp/sim300 --mode $m; done
    MALLOC_TRIM_THRESHOLD_=65536 .venv/bin/python benchmarks/bench_threads.py /tmp/sim300 --mode all1

Modes: ``default`` (the libraries' own thread pools), ``blas1`` (``OMP/OPENBLAS/MKL_NUM_THREADS=1``, set before
numpy loads), ``cv1`` (``cv2.setNumThreads(1)``), ``all1`` (both: what a Dask worker of
:class:`factorloc.parallel.DaskExecutor` runs). The first 8 queries run untimed (imports, kernels, the
reference's preparation), then ``--queries`` are timed with :func:`factorloc.evaluation.run_hierarchy`.
CPU / wall above 1 means the process used more than one core inside a query (docs/scale.md).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("scenario", type=Path, help="a scenario directory (factorloc simulate OUT --queries 300 ...)")
    ap.add_argument("--mode", choices=("default", "blas1", "cv1", "all1"), default="default")
    ap.add_argument("--queries", type=int, default=120)
    args = ap.parse_args()
    if "numpy" in sys.modules:  # pragma: no cover - a guard for edits of this script
        raise SystemExit("numpy was imported before the thread variables were set")
    if args.mode in ("blas1", "all1"):
        for key in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            os.environ[key] = "1"
    import cv2

    if args.mode in ("cv1", "all1"):
        cv2.setNumThreads(1)
    from factorloc.datasets import load_scenario
    from factorloc.evaluation.cases import EvaluationSet, evaluation_set
    from factorloc.evaluation.runner import run_hierarchy

    data = evaluation_set(load_scenario(args.scenario))
    run_hierarchy(EvaluationSet(data.references, data.cases[:8], data.name, data.world))
    timed = data.cases[8 : 8 + args.queries]
    t0, c0 = time.perf_counter(), time.process_time()
    run_hierarchy(EvaluationSet(data.references, timed, data.name, data.world))
    wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    n = max(1, len(timed))
    trim = os.environ.get("MALLOC_TRIM_THRESHOLD_", "unset")
    print(
        f"{args.mode:8s} OpenCV threads {cv2.getNumThreads()}, MALLOC_TRIM_THRESHOLD_ {trim}: "
        f"wall {1e3 * wall / n:.1f} ms/query, CPU {1e3 * cpu / n:.1f} ms/query, CPU/wall {cpu / wall:.2f} ({n} queries)"
    )


if __name__ == "__main__":
    main()

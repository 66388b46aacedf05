"""Start-up cost of the command line: ``import factorloc``, ``factorloc --help``, and the first ``factorloc localize``.

Run: ``.venv/bin/python benchmarks/bench_startup.py [--repeats 3]``. Each figure is the wall time of a
fresh process (``subprocess``), the median of ``--repeats`` runs, printed beside the ratio to the
interpreter's own start-up (``python -c pass``) measured in the same run: on a shared machine only the
ratios compare across runs.

* cold: ``factorloc localize data/sample q0003`` with an empty numba cache (``NUMBA_CACHE_DIR`` = a new
  directory): the kernels compile — what a user's very first run costs without ``make setup``;
* warm-up: :func:`factorloc.jit.warm_up` into another empty cache (what ``make setup`` runs), then the
  first ``factorloc localize`` against that cache — a fresh install after ``make setup``;
* warm: ``factorloc localize`` again, and ``factorloc --help`` and ``import factorloc``.

Asserts nothing; prints a table.
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
LOCALIZE = [str(BIN / "factorloc"), "localize", str(REPO / "data" / "sample"), "q0003"]
WARM_UP = [sys.executable, "-c", "import factorloc.jit as j; j.warm_up()"]


def wall(cmd: list[str], env: dict[str, str] | None = None) -> float:
    t0 = time.perf_counter()
    subprocess.run(cmd, check=True, capture_output=True, env={**os.environ, **(env or {})})
    return time.perf_counter() - t0


def median(cmd: list[str], repeats: int, env: dict[str, str] | None = None) -> float:
    return statistics.median(wall(cmd, env) for _ in range(repeats))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    args = parser.parse_args()
    rows: list[tuple[str, float]] = []
    peer = median([sys.executable, "-c", "pass"], args.repeats)
    rows.append(("python -c pass (peer)", peer))
    with tempfile.TemporaryDirectory() as cold, tempfile.TemporaryDirectory() as setup:
        rows.append(("factorloc localize, empty numba cache (cold)", wall(LOCALIZE, {"NUMBA_CACHE_DIR": cold})))
        rows.append(("warm-up into an empty cache (make setup)", wall(WARM_UP, {"NUMBA_CACHE_DIR": setup})))
        rows.append(("first factorloc localize after the warm-up", wall(LOCALIZE, {"NUMBA_CACHE_DIR": setup})))
        rows.append(("factorloc localize, warm (median)", median(LOCALIZE, args.repeats, {"NUMBA_CACHE_DIR": setup})))
    rows.append(("factorloc --help (median)", median([str(BIN / "factorloc"), "--help"], args.repeats)))
    rows.append(("python -c 'import factorloc' (median)", median([sys.executable, "-c", "import factorloc"], args.repeats)))
    width = max(len(r[0]) for r in rows)
    print(f"{'':{width}s}  {'s':>7s}  {'× peer':>7s}")
    for name, sec in rows:
        print(f"{name:{width}s}  {sec:7.2f}  {sec / peer:7.1f}")


if __name__ == "__main__":
    main()

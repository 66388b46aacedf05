"""Benchmark of the correlative global search (:mod:`factorloc.registration.global_search`): the compiled window
kernel of :func:`score_lattice` against the numpy gather it replaced (:func:`score_lattice_gather`, the peer,
measured in the same run on the same poses), and the whole :func:`search` per pair.

Usage::

    .venv/bin/python benchmarks/bench_global_search.py                 # the three laser logs of ../shared
    .venv/bin/python benchmarks/bench_global_search.py --pairs 20 --logs intel

Prints, per log, the median milliseconds of the level-1 lattice (every heading at 3°, ±5 m at 0.3 m) by the
kernel and by the gather, their ratio, whether the scores are bitwise equal; the local maxima of that score volume
by the compiled test (``_peaks``) and by ``scipy.ndimage.maximum_filter`` (the peer it replaced), their ratio and
whether they are the same cells; and the median search time.
"""

from __future__ import annotations

import argparse
import math
import time
from pathlib import Path

import numpy as np
from scipy import ndimage

from factorloc.evaluation.folds import load_laser_datasets
from factorloc.registration.global_search import (
    GlobalSearchParams,
    _peaks,
    reference_fields,
    score_lattice,
    score_lattice_gather,
    search,
)
from factorloc.registration.scan2d import voxel_downsample_2d

DATA = Path(__file__).resolve().parents[1] / ".." / "shared" / "data" / "laser"


def _median_ms(f, repeat: int = 3) -> float:  # noqa: ANN001 - a callable
    times = []
    for _ in range(repeat):
        t0 = time.perf_counter()
        f()
        times.append(time.perf_counter() - t0)
    return 1e3 * float(np.median(times))


def _pair(ref: np.ndarray, qry: np.ndarray, p: GlobalSearchParams) -> tuple[float, float, bool, float, float, bool, float]:
    """Level-1 ms by the kernel and by the gather and whether they agree to the bit; the peak test's ms, compiled
    and by scipy's maximum filter, and whether they find the same cells; the whole search's ms."""
    fields = reference_fields(ref, p)
    q1 = voxel_downsample_2d(qry[np.hypot(qry[:, 0], qry[:, 1]) <= p.max_range_m], 0.5 * p.coarse_resolution_m)
    n1 = int(math.ceil(p.radius_m / p.coarse_resolution_m))
    thetas = np.arange(120) * (2.0 * math.pi / 120)
    t_lo = np.full(2, -n1 * p.coarse_resolution_m)
    steps = (2 * n1 + 1, 2 * n1 + 1)
    kernel = score_lattice(fields[0], q1, thetas, t_lo, steps)  # compiled (or loaded) before timing
    same = bool(np.array_equal(kernel, score_lattice_gather(fields[0], q1, thetas, t_lo, steps)))
    # the search's own window: ± separation in heading and cells, the heading axis wrapped
    size_heading = 2 * max(1, int(p.separation_rad // p.coarse_angle_step_rad)) + 1
    size = (size_heading, 2 * max(1, int(p.separation_m // p.coarse_resolution_m)) + 1)

    def by_scipy() -> np.ndarray:
        window = ndimage.maximum_filter(kernel, size=(size[0], size[1], size[1]), mode=("wrap", "nearest", "nearest"))
        return np.flatnonzero((kernel >= window) & (kernel > 0.0))

    same_peaks = bool(np.array_equal(_peaks(kernel, size[0], size[1], True), by_scipy()))
    return (
        _median_ms(lambda: score_lattice(fields[0], q1, thetas, t_lo, steps)),
        _median_ms(lambda: score_lattice_gather(fields[0], q1, thetas, t_lo, steps)),
        same,
        _median_ms(lambda: _peaks(kernel, size[0], size[1], True)),
        _median_ms(by_scipy),
        same_peaks,
        _median_ms(lambda: search(ref, qry, p, fields=fields)),
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", type=Path, default=DATA)
    ap.add_argument("--logs", default="intel,aces,mit-csail")
    ap.add_argument("--pairs", type=int, default=40, help="scan pairs per log (evenly spread, 1–60 scans apart)")
    args = ap.parse_args()
    p = GlobalSearchParams()
    rng = np.random.default_rng(0)
    print(
        "| log | pairs | level 1: kernel ms | gather ms | kernel/gather | bitwise equal "
        "| peaks: compiled ms | scipy ms | compiled/scipy | same cells | search ms |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for ds in load_laser_datasets(args.data, args.logs.split(","), every=1000):
        scans = ds.log.scans.scans
        rows, equal, equal_peaks = [], True, True
        step = max(1, (len(scans) - 61) // args.pairs)
        for i in range(0, step * args.pairs, step):
            ref, qry = scans[i].points_m, scans[i + int(rng.integers(1, 61))].points_m
            k_ms, g_ms, same, pk_ms, ps_ms, same_peaks, s_ms = _pair(ref, qry, p)
            rows.append((k_ms, g_ms, pk_ms, ps_ms, s_ms))
            equal &= same
            equal_peaks &= same_peaks
        k, g, pk, ps, s = np.median(np.asarray(rows), axis=0)
        print(
            f"| {ds.name} | {len(rows)} | {k:.2f} | {g:.2f} | {k / g:.3f} | {equal} "
            f"| {pk:.3f} | {ps:.3f} | {pk / ps:.3f} | {equal_peaks} | {s:.1f} |"
        )


if __name__ == "__main__":
    main()

"""All the benchmarks on one scenario: :func:`run_bench` (what ``factorloc bench`` prints)."""

from __future__ import annotations

import os
import time
from dataclasses import replace
from typing import Any

import cv2

from factorloc.benchmarking.base import BenchProgress, BenchSettings
from factorloc.benchmarking.cost import bench_cost_curve
from factorloc.benchmarking.hierarchy import bench_hierarchy
from factorloc.benchmarking.results import BenchReport, Machine
from factorloc.benchmarking.timing import bench_fusion, bench_icp_vs_open3d, bench_localize
from factorloc.config import Config
from factorloc.evaluation.cases import evaluation_set
from factorloc.evaluation.runner import HierarchyRun, run_hierarchy
from factorloc.parallel import Executor

__all__ = ["run_bench"]


def _load_average() -> float:
    """The 1-minute load average (nan where the platform has none): other work competing for the CPU."""
    try:
        return float(os.getloadavg()[0])
    except (AttributeError, OSError):
        return float("nan")


def run_bench(
    scenario: Any,
    config: Config | None = None,
    *,
    settings: BenchSettings = BenchSettings(),
    progress: BenchProgress | None = None,
    executor: Executor | None = None,
) -> BenchReport:
    """All the benchmarks on one scenario (``to_json()``: the keys in ``docs/evaluation.md``).

    Parameters
    ----------
    scenario
        A :class:`factorloc.datasets.Scenario` or :class:`~factorloc.evaluation.EvaluationSet`.
    config
        The configuration (defaults if None).
    settings
        Repeats, cost-curve factors, ….
    progress
        ``progress(stage, done, total)``; stages: ``"seeded"``, ``"blind"``,
        ``"icp vs open3d"``, ``"fusion"``, ``"cost curve"``.
    executor
        Where the seeded and blind passes run (:mod:`factorloc.parallel`; default in this process). Per-query
        times are the workers' own; the other benchmarks run here.
    """
    data = evaluation_set(scenario)
    cfg = config or Config()

    def passes(label: str, seeded: bool) -> list[HierarchyRun]:
        runs = []
        for k in range(settings.repeats):
            cb = None if progress is None else (lambda d, t, k=k: progress(label, k * t + d, settings.repeats * t))
            runs.append(run_hierarchy(data, cfg, seeded=seeded, progress=cb, executor=executor))
        return runs

    t_start = time.perf_counter()
    load_before = _load_average()
    seeded = passes("seeded", True)
    blind = passes("blind", False)
    localize = bench_localize(seeded)
    hierarchy = bench_hierarchy(seeded, blind, settings=settings)
    icp = bench_icp_vs_open3d(data, cfg, settings=settings)
    if progress is not None:
        progress("icp vs open3d", 1, 1)
    fusion = bench_fusion(seeded[0], settings=settings)
    if progress is not None:
        progress("fusion", 1, 1)
    cost = bench_cost_curve(data, cfg, settings=replace(settings), progress=progress)
    return BenchReport(
        scenario=data.name,
        queries=len(data.cases),
        settings=settings,
        localize=localize,
        hierarchy=hierarchy,
        icp_vs_open3d=icp,
        fusion=fusion,
        cost_curve=cost,
        peak_memory_mb=seeded[0].peak_memory_mb,
        wall_seconds=time.perf_counter() - t_start,
        machine=Machine(
            cpu_count=os.cpu_count(),
            usable_cpus=len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count(),
            load_average_1min_before=load_before,
            load_average_1min_after=_load_average(),
            opencv_threads=cv2.getNumThreads(),
        ),
    )

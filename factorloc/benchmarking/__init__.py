"""Speed, measured as ratios against peers in the same run on the same inputs.

The library functions behind ``factorloc bench`` (which only prints):

- :func:`bench_localize` — full :meth:`~factorloc.Localizer.localize` per
  query and per step (median and 95th percentile over queries of the
  per-query median over repeats);
- :func:`bench_hierarchy` — the patent's central claim: every step seeded by
  its predecessors vs every step blind (``Localizer.localize(q, seeded=False)``):
  time per query and false positives of each, and their ratios;
- :func:`bench_icp_vs_open3d` — our ICP (:func:`factorloc.registration.icp2d.align`)
  vs Open3D's point-to-plane ICP on the same scan pairs from the same seeds;
- :func:`bench_fusion` — GTSAM graph vs closed-form product on the same gated
  estimates: time ratio and agreement;
- :func:`bench_cost_curve` — time per query as the reference panorama width
  and the cloud sizes double, with the fitted exponent ``t ∝ scale^k``.

:func:`run_bench` runs them all and returns a :class:`~factorloc.benchmarking.results.BenchReport`
(``to_json()``: the keys in ``docs/evaluation.md``). Timings use :func:`time.perf_counter`; every figure
is a median, so a stray slow repeat does not move it. Nothing here asserts
a speed: the test suite only checks that the machinery runs.

False positive
    A step's estimate that the step called *reliable* while its error exceeds
    3 marginal σ in a component it measures (the confidently-wrong test of
    :func:`factorloc.evaluation.metrics.confidently_wrong` applied per step):
    the headline. The second definition, a reliable estimate off by more than
    a fixed tolerance (:func:`beyond_tolerance`), does not depend on the σ the
    step states (a blind step's σ is wider). Counts of rare events get exact
    intervals: :func:`clopper_pearson` for a rate, :func:`rate_ratio_interval`
    for the blind / seeded ratio, :func:`queries_to_show_ratio` for the
    sample a claimed ratio needs.

One module per job: :mod:`~factorloc.benchmarking.timing` (localize, ICP vs Open3D, fusion),
:mod:`~factorloc.benchmarking.hierarchy` (the ablation), :mod:`~factorloc.benchmarking.statistics`
(exact binomial statistics), :mod:`~factorloc.benchmarking.cost` (the cost curve),
:mod:`~factorloc.benchmarking.results` (the typed results), :mod:`~factorloc.benchmarking.run`.
"""

from __future__ import annotations

from factorloc.benchmarking.base import BenchProgress, BenchSettings
from factorloc.benchmarking.cost import bench_cost_curve, fit_exponent, scaled_set
from factorloc.benchmarking.hierarchy import bench_hierarchy, beyond_tolerance
from factorloc.benchmarking.results import (
    BenchReport,
    CostCurve,
    CountComparison,
    FalsePositiveComparison,
    FusionBench,
    HierarchyBench,
    HierarchyMode,
    IcpVsOpen3d,
    LocalizeBench,
)
from factorloc.benchmarking.run import run_bench
from factorloc.benchmarking.statistics import (
    clopper_pearson,
    compare_counts,
    power_to_show_ratio,
    queries_to_show_ratio,
    rate_ratio_interval,
)
from factorloc.benchmarking.timing import bench_fusion, bench_icp_vs_open3d, bench_localize

__all__ = [
    "BenchProgress",
    "BenchReport",
    "BenchSettings",
    "CostCurve",
    "CountComparison",
    "FalsePositiveComparison",
    "FusionBench",
    "HierarchyBench",
    "HierarchyMode",
    "IcpVsOpen3d",
    "LocalizeBench",
    "bench_cost_curve",
    "bench_fusion",
    "bench_hierarchy",
    "bench_icp_vs_open3d",
    "bench_localize",
    "beyond_tolerance",
    "clopper_pearson",
    "compare_counts",
    "fit_exponent",
    "power_to_show_ratio",
    "queries_to_show_ratio",
    "rate_ratio_interval",
    "run_bench",
    "scaled_set",
]

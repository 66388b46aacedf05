"""The benchmark results as frozen records; ``to_json()`` of each gives the keys of ``docs/evaluation.md``.

Times in ms (µs where the field says so), errors in m and degrees (or rad where the field says so), rates as
fractions; NaN (JSON ``null``) where a figure does not apply.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from factorloc._json import JsonRecord

if TYPE_CHECKING:  # pragma: no cover
    from factorloc.benchmarking.base import BenchSettings

__all__ = [
    "BenchReport",
    "CostCurve",
    "CostPoint",
    "CountComparison",
    "FalsePositiveComparison",
    "FusionBench",
    "HierarchyBench",
    "HierarchyMode",
    "IcpVsOpen3d",
    "LocalizeBench",
    "Machine",
    "ModeFigures",
    "Timing",
]


@dataclass(frozen=True)
class Timing(JsonRecord):
    """Median, 95th percentile and mean of a time over queries (ms)."""

    median_ms: float
    p95_ms: float
    mean_ms: float


@dataclass(frozen=True)
class LocalizeBench(JsonRecord):
    """``localize()`` per query and each step (over the queries where it ran), from repeated passes."""

    queries: int
    repeats: int
    median_ms: float
    p95_ms: float
    mean_ms: float
    steps: Mapping[str, Timing]
    prepare_ms: Mapping[str, float]


@dataclass(frozen=True)
class ModeFigures(JsonRecord):
    """A count of rare events in one mode: the rate per query and its exact interval; per reliable estimate too."""

    count: int
    queries: int
    rate: float
    rate_ci: tuple[float, float]
    reliable: int | None = None
    per_reliable: float = math.nan
    per_reliable_ci: tuple[float, float] = (math.nan, math.nan)

    def to_json(self) -> dict[str, Any]:
        out = super().to_json()
        if self.reliable is None:
            for key in ("reliable", "per_reliable", "per_reliable_ci"):
                del out[key]
        return out


@dataclass(frozen=True)
class CountComparison(JsonRecord):
    """Blind vs seeded counts on the same queries (:func:`~factorloc.benchmarking.statistics.compare_counts`)."""

    seeded: ModeFigures
    blind: ModeFigures
    ratio: float
    ratio_ci: tuple[float, float]
    ratio_lower_bound: float
    shows_target: bool
    queries_needed: int | None
    queries_needed_power_80: int | None


@dataclass(frozen=True)
class FalsePositiveComparison(JsonRecord):
    """The exact false-positive comparison of the hierarchy ablation, for the two definitions ``sigma3`` and ``tolerance``.

    ``steps_after_first[<def>]``: per query, some step after the first was a false positive; ``fused[<def>]``:
    the fused pose was; ``steps[<name>][<def>]``: one step's. Empty when no query has truth.
    """

    headline: str
    confidence: float
    target_ratio: float
    tolerance_m: float
    tolerance_deg: float
    queries: int
    steps_after_first: Mapping[str, CountComparison]
    fused: Mapping[str, CountComparison]
    steps: Mapping[str, Mapping[str, CountComparison]]

    def to_json(self) -> dict[str, Any]:
        out = super().to_json()
        if self.queries == 0:
            for key in ("steps_after_first", "fused", "steps"):
                del out[key]
        return out


@dataclass(frozen=True)
class HierarchyMode(JsonRecord):
    """One mode of the hierarchy ablation (every step seeded, or every step blind)."""

    median_ms: float
    p95_ms: float
    mean_ms: float
    steps_median_ms: Mapping[str, float]
    queries_with_truth: int
    false_positive_count: int
    false_positive_rate: float
    steps_false_positive_count: Mapping[str, int]
    steps_reliable_count: Mapping[str, int]
    steps_false_positive_per_reliable: Mapping[str, float]
    steps_reliable_rate: Mapping[str, float]
    confidently_wrong_rate: float
    confidently_wrong_count: int
    determined_rate: float
    position_rmse_m: float
    heading_rmse_deg: float


@dataclass(frozen=True)
class HierarchyBench(JsonRecord):
    """Seeded vs blind: time, false positives, the fused outcome, and their ratios (see ``bench_hierarchy``)."""

    seeded: HierarchyMode
    blind: HierarchyMode
    time_ratio: float
    false_positive_ratio: float
    false_positive_ratio_is_lower_bound: bool
    confidently_wrong_ratio: float
    confidently_wrong_ratio_is_lower_bound: bool
    false_positives: FalsePositiveComparison


@dataclass(frozen=True)
class IcpVsOpen3d(JsonRecord):
    """Our ICP vs Open3D point-to-plane ICP on the same pairs from the same seeds (``pairs = 0``: none)."""

    pairs: int
    ours_median_ms: float = math.nan
    open3d_median_ms: float = math.nan
    ours_median_error_m: float = math.nan
    open3d_median_error_m: float = math.nan
    ours_median_error_deg: float = math.nan
    open3d_median_error_deg: float = math.nan
    ours_success_rate: float = math.nan
    open3d_success_rate: float = math.nan
    time_ratio: float = math.nan
    error_ratio: float = math.nan

    def to_json(self) -> dict[str, Any]:
        return super().to_json() if self.pairs else {"pairs": 0}


@dataclass(frozen=True)
class FusionBench(JsonRecord):
    """GTSAM graph vs closed-form product on the same gated estimates (``queries = 0``: none to fuse)."""

    queries: int
    graph_median_us: float = math.nan
    product_median_us: float = math.nan
    queries_with_cross_covariance: int = 0
    max_position_diff_m: float = math.nan
    max_heading_diff_rad: float = math.nan
    max_variance_rel_diff: float = math.nan
    max_position_diff_m_cross_covariance: float = math.nan
    max_heading_diff_rad_cross_covariance: float = math.nan
    time_ratio: float = math.nan

    def to_json(self) -> dict[str, Any]:
        return super().to_json() if self.queries else {"queries": 0}


@dataclass(frozen=True)
class CostPoint(JsonRecord):
    """Time per query at one scale factor of the reference panorama and the clouds."""

    factor: float
    panorama_width_px: int | None
    reference_cloud_points: int | None
    reference_scan_points: int | None
    query_cloud_points_median: float | None
    median_ms: float
    steps_median_ms: Mapping[str, float]


@dataclass(frozen=True)
class CostCurve(JsonRecord):
    """The cost curve and the fitted exponents ``k`` of ``t ∝ scale^k`` (total and per step)."""

    points: tuple[CostPoint, ...]
    exponent: float
    steps_exponent: Mapping[str, float]


@dataclass(frozen=True)
class Machine(JsonRecord):
    """What the machine was doing: CPUs, the 1-minute load average before and after, OpenCV's threads."""

    cpu_count: int | None
    usable_cpus: int | None
    load_average_1min_before: float
    load_average_1min_after: float
    opencv_threads: int


@dataclass(frozen=True)
class BenchReport(JsonRecord):
    """All the benchmarks on one scenario (:func:`~factorloc.benchmarking.run_bench`)."""

    scenario: str
    queries: int
    settings: BenchSettings
    localize: LocalizeBench
    hierarchy: HierarchyBench
    icp_vs_open3d: IcpVsOpen3d
    fusion: FusionBench
    cost_curve: CostCurve
    peak_memory_mb: float
    wall_seconds: float
    machine: Machine

    def to_json(self) -> dict[str, Any]:
        out = super().to_json()
        s = self.settings
        out["settings"] = {
            "repeats": s.repeats,
            "fusion_repeats": s.fusion_repeats,
            "cost_factors": list(s.cost_factors),
            "cost_queries": s.cost_queries,
        }
        return out

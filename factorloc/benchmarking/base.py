"""How much a benchmark measures (:class:`BenchSettings`), and the helpers the benchmarks share."""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

import numpy as np

from factorloc.benchmarking.results import Timing
from factorloc.benchmarking.statistics import check_confidence
from factorloc.errors import InputError
from factorloc.evaluation.runner import HierarchyRun
from factorloc.types import StepStatus

__all__ = ["BenchProgress", "BenchSettings", "per_query_median", "ratio", "timing"]

#: ``progress(stage, done, total)``: called as each stage advances.
BenchProgress = Callable[[str, int, int], None]


@dataclass(frozen=True)
class BenchSettings:
    """How much to measure.

    Parameters
    ----------
    repeats
        Passes over the queries for the localize and hierarchy figures; each
        query's time is its median over the passes.
    fusion_repeats
        Repeats of each fusion call (µs-scale: many repeats).
    cost_factors
        Scale factors of the cost curve (panorama width and cloud sizes × factor).
    cost_queries
        How many queries (the first ones) each cost-curve point localizes.
    icp_success_m, icp_success_rad
        An ICP alignment is a success when its error is below both.
    confidence
        Confidence of the exact intervals of the false-positive rates and of their ratio.
    fp_target_ratio
        The blind / seeded false-positive ratio to show (the issue's claim: 5).
    fp_tolerance_m, fp_tolerance_rad
        The fixed tolerance of the second false-positive definition (:func:`beyond_tolerance`):
        10 cm, 5° — gross errors (the wrong correlation peak, a look-alike's vote mode, the wrong
        ICP basin), above the honest noise of a reliable visual heading (σ up to 5°).
    """

    repeats: int = 3
    fusion_repeats: int = 20
    cost_factors: tuple[float, ...] = (0.5, 1.0, 2.0)
    cost_queries: int = 20
    icp_success_m: float = 0.05
    icp_success_rad: float = math.radians(1.0)
    confidence: float = 0.95
    fp_target_ratio: float = 5.0
    fp_tolerance_m: float = 0.10
    fp_tolerance_rad: float = math.radians(5.0)

    def __post_init__(self) -> None:
        if self.repeats < 1 or self.fusion_repeats < 1 or self.cost_queries < 1:
            raise InputError(
                "repeats, fusion_repeats and cost_queries must be >= 1, "
                f"got {self.repeats}, {self.fusion_repeats}, {self.cost_queries}"
            )
        factors = tuple(float(f) for f in self.cost_factors)
        if len(factors) < 2 or any(not (f > 0 and math.isfinite(f)) for f in factors):
            raise InputError(f"cost_factors needs at least 2 positive scale factors, got {self.cost_factors!r}")
        object.__setattr__(self, "cost_factors", factors)
        check_confidence(self.confidence)
        for name in ("fp_target_ratio", "fp_tolerance_m", "fp_tolerance_rad"):
            if not getattr(self, name) > 0.0:
                raise InputError(f"{name} must be > 0, got {getattr(self, name)!r}")


def timing(seconds: np.ndarray) -> Timing:
    """Median, 95th percentile and mean (ms) of the finite entries of ``seconds`` (NaN when there is none)."""
    s = np.asarray(seconds, dtype=np.float64)
    s = s[np.isfinite(s)]
    if s.size == 0:
        return Timing(math.nan, math.nan, math.nan)
    return Timing(1e3 * float(np.median(s)), 1e3 * float(np.percentile(s, 95)), 1e3 * float(s.mean()))


def ratio(num: float, den: float) -> float:
    """``num / den``, NaN when either is not finite or ``den`` is not positive (nothing to compare)."""
    return num / den if den > 0 and math.isfinite(num) and math.isfinite(den) else math.nan


def per_query_median(runs: Sequence[HierarchyRun]) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """Per query, the median over repeats of localize() time and of each step's time (s; NaN where it was skipped)."""
    total = np.median(np.array([[q.localize_seconds for q in r.runs] for r in runs]), axis=0)
    steps = {}
    for name in runs[0].step_names:
        per = np.array([[next((s.seconds for s in q.reports if s.name == name), math.nan) for q in r.runs] for r in runs])
        skipped = np.array(
            [[next((s.status is StepStatus.SKIPPED for s in q.reports if s.name == name), True) for q in r.runs] for r in runs]
        )
        per[skipped] = math.nan
        with np.errstate(all="ignore"):
            steps[name] = np.nanmedian(per, axis=0) if np.isfinite(per).any() else np.full(per.shape[1], math.nan)
    return total, steps

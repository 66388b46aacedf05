"""The cost curve: time per query as the reference panorama and the clouds grow, with the fitted exponent."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import cv2
import numpy as np

from factorloc.benchmarking.base import BenchProgress, BenchSettings, per_query_median, timing
from factorloc.benchmarking.results import CostCurve, CostPoint
from factorloc.config import Config
from factorloc.evaluation.cases import Case, EvaluationSet
from factorloc.evaluation.runner import run_hierarchy
from factorloc.types import Panorama, PointCloud, Query, Reference, Scan

__all__ = ["bench_cost_curve", "fit_exponent", "scaled_set"]


def _resample_points(points: np.ndarray, factor: float, rng: np.random.Generator) -> np.ndarray:
    """``round(N·factor)`` points: a random subset (factor ≤ 1) or the points plus jittered copies (1 mm)."""
    n = len(points)
    m = max(3, int(round(n * factor)))
    if m <= n:
        return points[np.sort(rng.choice(n, size=m, replace=False))]
    extra = points[rng.choice(n, size=m - n, replace=True)] + rng.normal(scale=1e-3, size=(m - n, points.shape[1]))
    return np.vstack([points, extra])


def _scaled_panorama(p: Panorama, factor: float) -> Panorama:
    w, h = max(8, int(round(p.width_px * factor))), max(4, int(round(p.height_px * factor)))
    interp = cv2.INTER_AREA if factor < 1 else cv2.INTER_LINEAR
    return Panorama(cv2.resize(p.image_bgr, (w, h), interpolation=interp), p.fov_v_rad, p.azimuth_col0_rad)


def scaled_set(data: EvaluationSet, factor: float, *, queries: int | None = None, seed: int = 0) -> EvaluationSet:
    """The evaluation set with the reference panoramas scaled by ``factor`` and every cloud and scan × ``factor`` points.

    Panoramas are resized in width and height (same field of view).

    Clouds and scans are resampled (:func:`_resample_points`: subset or jittered copies),
    so their geometry stays; query camera images are unchanged. Only the
    first ``queries`` cases are kept when given.
    """
    rng = np.random.default_rng(seed)
    refs = {}
    for rid, r in data.references.items():
        refs[rid] = Reference(
            panorama=None if r.panorama is None else _scaled_panorama(r.panorama, factor),
            cloud=None if r.cloud is None else PointCloud(_resample_points(r.cloud.points_m, factor, rng)),
            scan=None if r.scan is None else Scan(_resample_points(r.scan.points_m, factor, rng)),
            T_world_reference=r.T_world_reference,
            name=r.name,
        )
    cases = []
    for c in data.cases[: queries or len(data.cases)]:
        q = c.query
        cloud = None if q.cloud is None else PointCloud(_resample_points(q.cloud.points_m, factor, rng))
        scan = None if q.scan is None else Scan(_resample_points(q.scan.points_m, factor, rng))
        q2 = Query(images=q.images, panorama=q.panorama, cloud=cloud, scan=scan, odometry=q.odometry, id=q.id)
        cases.append(Case(q2, c.truth, c.faults, c.reference_id, c.distance_from_reference_m))
    return EvaluationSet(refs, tuple(cases), name=f"{data.name}×{factor:g}", world=data.world)


def _median_len(items: Sequence[Any]) -> float | None:
    sizes = [len(x) for x in items if x is not None]
    return float(np.median(sizes)) if sizes else None


def fit_exponent(scales: Sequence[float], times: Sequence[float]) -> float:
    """The exponent ``k`` of ``t ∝ scale^k``: least-squares slope of log t against log scale (nan with < 2 valid points)."""
    s, t = np.asarray(scales, dtype=np.float64), np.asarray(times, dtype=np.float64)
    ok = np.isfinite(s) & np.isfinite(t) & (s > 0) & (t > 0)
    if ok.sum() < 2:
        return math.nan
    return float(np.polyfit(np.log(s[ok]), np.log(t[ok]), 1)[0])


def bench_cost_curve(
    data: EvaluationSet,
    config: Config | None = None,
    *,
    settings: BenchSettings = BenchSettings(),
    progress: BenchProgress | None = None,
) -> CostCurve:
    """Time per query (median over the first ``cost_queries`` queries) at each scale factor, and the fitted exponents.

    At factor f the reference panorama is f× wider (and higher), every
    reference and query cloud has f× as many points (:func:`scaled_set`).
    ``exponent`` fits the total time, ``steps_exponent`` each step's.
    """
    rows = []
    for i, f in enumerate(settings.cost_factors):
        scaled = scaled_set(data, f, queries=settings.cost_queries)
        run = run_hierarchy(scaled, config)
        total, steps = per_query_median([run])
        ref = next(iter(scaled.references.values()))
        rows.append(
            CostPoint(
                factor=f,
                panorama_width_px=None if ref.panorama is None else ref.panorama.width_px,
                reference_cloud_points=None if ref.cloud is None else len(ref.cloud),
                reference_scan_points=None if ref.scan is None else len(ref.scan),
                query_cloud_points_median=_median_len([c.query.cloud for c in scaled.cases]),
                median_ms=1e3 * float(np.median(total)),
                steps_median_ms={k: timing(v).median_ms for k, v in steps.items()},
            )
        )
        if progress is not None:
            progress("cost curve", i + 1, len(settings.cost_factors))
    factors = [r.factor for r in rows]
    return CostCurve(
        points=tuple(rows),
        exponent=fit_exponent(factors, [r.median_ms for r in rows]),
        steps_exponent={n: fit_exponent(factors, [r.steps_median_ms[n] for r in rows]) for n in rows[0].steps_median_ms},
    )

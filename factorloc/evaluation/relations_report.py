"""The tables of the relations benchmark (:mod:`factorloc.evaluation.relations`): the summary per method and
subset, its text rendering, and why relations were not recovered."""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["METHODS", "RelationResult", "format_table", "summarize", "unrecovered_breakdown"]

#: The methods the benchmark compares (see :func:`factorloc.evaluation.relations.relations_benchmark`).
METHODS = ("ours", "ours_icp", "odometry", "open3d_p2p", "open3d_p2plane")


@dataclass(frozen=True)
class RelationResult:
    """One method on one relation."""

    method: str
    index: int
    kind: str  # "local" or "loop"
    error_translation_m: float
    error_rotation_deg: float
    reliable: bool
    confidently_wrong: bool
    seconds: float
    nees_position: float = math.nan
    used_global_init: bool = False
    diagnostics: dict[str, Any] = field(default_factory=dict)


def summarize(results: Sequence[RelationResult], dataset: str = "") -> list[dict[str, Any]]:
    """The table: one row per (method, subset ∈ local/loop/all).

    Columns: ``dataset``, ``method``, ``subset``, ``n``, ``trans_mean_cm``,
    ``trans_std_cm``, ``rot_mean_deg``, ``rot_std_deg``, ``reliable_rate``,
    ``confidently_wrong_rate`` (over all relations of the subset),
    ``recovered_rate`` (error < 10 cm and < 1°), ``unrecovered_flagged_rate``
    (of those not recovered, the fraction marked unreliable), ``ms_per_pair`` (mean), ``ms_median``,
    ``trans_mean_reliable_cm`` (mean over the reliable ones) and ``nees_icp_mean``.
    Plain dicts: ``pandas.DataFrame(summarize(...))`` gives a data frame.
    """
    rows = []
    methods = [m for m in METHODS if any(r.method == m for r in results)]
    methods += [m for m in dict.fromkeys(r.method for r in results) if m not in METHODS]  # e.g. "map"
    for m in methods:
        for subset in ("local", "loop", "all"):
            rs = [r for r in results if r.method == m and (subset == "all" or r.kind == subset)]
            if not rs:
                continue
            et = np.array([r.error_translation_m for r in rs]) * 100.0
            er = np.array([r.error_rotation_deg for r in rs])
            rel = np.array([r.reliable for r in rs])
            rec = (et < 10.0) & (er < 1.0)
            nees = np.array([r.diagnostics.get("icp_nees_position", math.nan) for r in rs if r.diagnostics.get("icp_reliable")])
            rows.append(
                {
                    "dataset": dataset,
                    "method": m,
                    "subset": subset,
                    "n": len(rs),
                    "trans_mean_cm": float(et.mean()),
                    "trans_std_cm": float(et.std()),
                    "rot_mean_deg": float(er.mean()),
                    "rot_std_deg": float(er.std()),
                    "reliable_rate": float(rel.mean()),
                    "confidently_wrong_rate": float(np.mean([r.confidently_wrong for r in rs])),
                    "recovered_rate": float(rec.mean()),
                    "unrecovered_flagged_rate": float(np.mean(~rel[~rec])) if np.any(~rec) else 1.0,
                    "trans_mean_reliable_cm": float(et[rel].mean()) if rel.any() else math.nan,
                    "ms_per_pair": 1000.0 * float(np.mean([r.seconds for r in rs])),
                    "ms_median": 1000.0 * float(np.median([r.seconds for r in rs])),
                    "nees_icp_mean": float(np.mean(nees)) if len(nees) else math.nan,
                }
            )
    return rows


def unrecovered_breakdown(
    results: Sequence[RelationResult], subset: str = "loop", tolerance: tuple[float, float] = (0.1, 1.0)
) -> dict[str, int]:
    """Why ``ours`` did not recover the relations of ``subset`` (``"local"``, ``"loop"`` or ``"all"``).

    A relation is recovered when the fused pose is within ``tolerance`` (m, deg; the table's 10 cm and 1°).
    Each unrecovered one is counted under one key:

    * ``icp_correct_rejected: <rule>`` — the ICP step's own pose was within the tolerance but it called it
      unreliable; ``<rule>`` is the code of its first failed check (``icp.score``, ``icp.constraint``, …;
      the rules apply in the order of :data:`factorloc.estimators.icp.rules.RULES`);
    * ``icp_correct_gated`` — the ICP pose was within the tolerance and reliable, yet not what the pipeline
      returned (the consistency gate or the seed audit);
    * ``icp_wrong_flagged`` — the ICP pose was off and the result is unreliable (flagged, as it should be);
    * ``not_flagged_near`` — reliable and off, but within 15 cm and 2.5° (e.g. a loop closure 1.1° off);
    * ``not_flagged_wrong`` — reliable and farther off.

    Plus ``n`` (relations of the subset) and ``recovered``.
    """
    out: dict[str, int] = {"n": 0, "recovered": 0}
    for r in results:
        if r.method != "ours" or (subset != "all" and r.kind != subset):
            continue
        out["n"] += 1
        if r.error_translation_m < tolerance[0] and r.error_rotation_deg < tolerance[1]:
            out["recovered"] += 1
            continue
        d = r.diagnostics
        icp_ok = (
            d.get("icp_error_translation_m", math.inf) < tolerance[0] and d.get("icp_error_rotation_deg", math.inf) < tolerance[1]
        )
        if icp_ok and not d.get("icp_reliable", False):
            key = f"icp_correct_rejected: {(d.get('icp_failed_checks') or ('other',))[0]}"
        elif icp_ok:
            key = "icp_correct_gated"
        elif not r.reliable:
            key = "icp_wrong_flagged"
        elif r.error_translation_m < 0.15 and r.error_rotation_deg < 2.5:
            key = "not_flagged_near"
        else:
            key = "not_flagged_wrong"
        out[key] = out.get(key, 0) + 1
    return out


def format_table(rows: Sequence[dict[str, Any]]) -> str:
    """A fixed-width text rendering of :func:`summarize`'s rows (for the CLI and benchmarks).

    ``rel. cm`` is the mean translation error over the relations the method marked reliable.
    """
    head = (
        f"{'dataset':8s} {'method':15s} {'subset':6s} {'n':>5s} {'trans cm':>14s} {'rot deg':>14s} "
        f"{'reliable':>8s} {'rel. cm':>7s} {'conf.wrong':>10s} {'recov':>6s} {'flagged':>7s} "
        f"{'ms/pair':>8s} {'ms med':>7s} {'NEES':>6s}"
    )
    lines = [head, "-" * len(head)]
    for r in rows:
        lines.append(
            f"{r['dataset']:8s} {r['method']:15s} {r['subset']:6s} {r['n']:5d} "
            f"{r['trans_mean_cm']:6.2f}±{r['trans_std_cm']:<7.2f} {r['rot_mean_deg']:6.2f}±{r['rot_std_deg']:<7.2f} "
            f"{100 * r['reliable_rate']:7.1f}% {r['trans_mean_reliable_cm']:7.2f} "
            f"{100 * r['confidently_wrong_rate']:9.2f}% {100 * r['recovered_rate']:5.1f}% "
            f"{100 * r['unrecovered_flagged_rate']:6.1f}% {r['ms_per_pair']:8.2f} {r['ms_median']:7.2f} {r['nees_icp_mean']:6.2f}"
        )
    return "\n".join(lines)

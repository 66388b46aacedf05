"""The offline (fully smoothed) trajectory of a hierarchy run, scored like any strategy."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from factorloc.evaluation.report import EvaluationReport
from factorloc.evaluation.runner import HierarchyRun, evaluate
from factorloc.fusion.base import mark_undetermined
from factorloc.fusion.smoother import PLACEHOLDER_SIGMA, TrajectorySmoother
from factorloc.types import FULL

__all__ = ["smoothed_report"]


def smoothed_report(run: HierarchyRun, smoother: TrajectorySmoother | None = None) -> EvaluationReport:
    """Evaluate the *offline* (fully smoothed) trajectory of ``run``, with the keys of :func:`factorloc.evaluation.evaluate`.

    :func:`~factorloc.evaluation.evaluate` scores what a sequential strategy answers at each query (online:
    only the past is known). After the last query, the smoother re-estimates every pose with all the
    evidence, past and future; this report scores those poses and their marginal covariances (a component
    whose variance exceeds a quarter of the placeholder prior's, :data:`~factorloc.fusion.smoother.PLACEHOLDER_SIGMA`,
    is undetermined). Latencies are the online updates' (the final re-estimation is not included). The
    strategy is named ``"<name>_offline"``.
    """
    sm = smoother or TrajectorySmoother()
    online = evaluate(run, sm)
    results = []
    for r, (pose, cov) in zip(online.results, sm.smoothed(), strict=True):
        c = np.array(cov)
        unknown = [comp for comp, bad in zip(FULL, np.diag(c) > 0.25 * PLACEHOLDER_SIGMA**2, strict=True) if bad]
        results.append(replace(r, pose=pose, covariance=mark_undetermined(c, unknown)))
    return EvaluationReport(run, f"{sm.name}_offline", tuple(results))

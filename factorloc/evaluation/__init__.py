"""Metrics and the evaluation runner.

- :mod:`factorloc.evaluation.metrics` — position/heading errors, RMSE/median/p95,
  NEES, outside-ellipse and confidently-wrong rates (pure array functions).
- :mod:`factorloc.evaluation.runner` — :func:`run_hierarchy` (the estimators,
  once per query) and :func:`evaluate` (fuse with a strategy object, score);
  :meth:`EvaluationReport.to_json_dict` holds the keys of ``docs/evaluation.md``.
"""

from factorloc.evaluation.metrics import (
    ErrorSummary,
    confidently_wrong,
    heading_error_rad,
    nees,
    nees_mean,
    normalized_nees_mean,
    outside_ellipse,
    pose_errors,
    position_error_m,
    summarize,
)
from factorloc.evaluation.runner import (
    SCHEMA_VERSION,
    Case,
    EvaluationReport,
    EvaluationSet,
    HierarchyRun,
    QueryResult,
    QueryRun,
    evaluate,
    evaluation_set,
    run_hierarchy,
)

__all__ = [
    "SCHEMA_VERSION",
    "Case",
    "ErrorSummary",
    "EvaluationReport",
    "EvaluationSet",
    "HierarchyRun",
    "QueryResult",
    "QueryRun",
    "confidently_wrong",
    "evaluate",
    "evaluation_set",
    "heading_error_rad",
    "nees",
    "nees_mean",
    "normalized_nees_mean",
    "outside_ellipse",
    "pose_errors",
    "position_error_m",
    "run_hierarchy",
    "summarize",
]

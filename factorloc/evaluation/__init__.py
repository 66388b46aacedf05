"""Metrics and the evaluation runner.

- :mod:`factorloc.evaluation.metrics` — position/heading errors, RMSE/median/p95,
  NEES, outside-ellipse and confidently-wrong rates (pure array functions).
- :mod:`factorloc.evaluation.cases` — what is evaluated (:class:`Case`, :class:`EvaluationSet`);
- :mod:`factorloc.evaluation.runner` — :func:`run_hierarchy` (the estimators,
  once per query) and :func:`evaluate` (fuse with a strategy object, score);
- :mod:`factorloc.evaluation.report` — the typed result: :meth:`EvaluationReport.summary`
  (an :class:`EvaluationSummary`; ``to_json()`` gives the keys of ``docs/evaluation.md``);
- :mod:`factorloc.evaluation.reasons` — why steps were not fused, counted by rule code.
"""

from factorloc.evaluation.cases import Case, EvaluationSet, evaluation_set
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
from factorloc.evaluation.reasons import RuleTally
from factorloc.evaluation.report import SCHEMA_VERSION, EvaluationReport, EvaluationSummary, StepSummary, Summary
from factorloc.evaluation.runner import HierarchyRun, QueryResult, QueryRun, evaluate, run_hierarchy

__all__ = [
    "SCHEMA_VERSION",
    "Case",
    "ErrorSummary",
    "EvaluationReport",
    "EvaluationSet",
    "EvaluationSummary",
    "HierarchyRun",
    "QueryResult",
    "QueryRun",
    "RuleTally",
    "StepSummary",
    "Summary",
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

"""Helpers of the executor tests: a hierarchy whose first step raises on chosen queries."""

from __future__ import annotations

from typing import Any

from factorloc.config import Config
from factorloc.estimators.base import Hypotheses
from factorloc.pipeline import default_steps
from factorloc.types import Query, Reference


class RaisingStep:
    """A step that delegates to ``inner`` but raises a RuntimeError (not a FactorlocError) on the queries named."""

    def __init__(self, inner: Any, fail_ids: frozenset[str]) -> None:
        self.inner, self.fail_ids, self.name = inner, fail_ids, inner.name

    def prepare(self, reference: Reference) -> Any:
        return self.inner.prepare(reference)

    def estimate(self, prepared: Any, query: Query, hypotheses: Hypotheses) -> Any:
        if query.id in self.fail_ids:
            raise RuntimeError(f"injected failure on {query.id}")
        return self.inner.estimate(prepared, query, hypotheses)


def raising_steps(fail_ids: frozenset[str]) -> list[Any]:
    """The default hierarchy with its first step raising on ``fail_ids``."""
    steps = default_steps(Config())
    return [RaisingStep(steps[0], fail_ids), *steps[1:]]

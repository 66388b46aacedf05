"""What is evaluated: queries with their ground truth (:class:`Case`) against references (:class:`EvaluationSet`)."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from types import MappingProxyType
from typing import TYPE_CHECKING, Any

from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.types import Query, Reference

if TYPE_CHECKING:  # pragma: no cover
    from factorloc.sim.world import World

__all__ = ["DEFAULT_REFERENCE", "Case", "EvaluationSet", "evaluation_set"]

#: The id under which a single reference is stored.
DEFAULT_REFERENCE = "ref0"


@dataclass(frozen=True, eq=False)
class Case:
    """One query with its ground truth.

    Parameters
    ----------
    query
        What the robot sensed.
    truth
        The true ``T_world_robot`` (None: the query is run and timed but not scored).
    faults
        Fault tags of the query (``"kidnapped"``, ``"occlusion"``, …; empty when clean).
    reference_id
        The reference (of the :class:`EvaluationSet`) it is localized against.
    distance_from_reference_m
        Distance of the true pose from that reference's pose (m); computed
        from ``truth`` when None.
    """

    query: Query
    truth: Pose2 | None = None
    faults: tuple[str, ...] = ()
    reference_id: str = DEFAULT_REFERENCE
    distance_from_reference_m: float | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.query, Query):
            raise InputError(f"Case.query must be a factorloc.Query, got {type(self.query).__name__}")
        if self.truth is not None and not isinstance(self.truth, Pose2):
            raise InputError(f"Case.truth must be a Pose2 or None, got {type(self.truth).__name__}")
        faults = (self.faults,) if isinstance(self.faults, str) else tuple(self.faults)
        for f in faults:
            if not isinstance(f, str) or not f:
                raise InputError(f"Case.faults must be non-empty strings, got {f!r} in query {self.query.id!r}")
        object.__setattr__(self, "faults", faults)
        if not isinstance(self.reference_id, str) or not self.reference_id:
            raise InputError(f"Case.reference_id must be a non-empty string, got {self.reference_id!r}")


@dataclass(frozen=True, eq=False)
class EvaluationSet:
    """References and the cases to localize against them, in scenario (time) order.

    :func:`evaluation_set` builds one from a :class:`factorloc.datasets.Scenario`;
    tests and notebooks may build one directly. ``references`` maps ids to
    references (a single :class:`~factorloc.Reference` is stored under
    ``"ref0"``); ``world`` (optional) is the floor plan the figures draw.
    """

    references: Mapping[str, Reference] | Reference
    cases: tuple[Case, ...]
    name: str = "scenario"
    world: World | None = None

    def __post_init__(self) -> None:
        refs = {DEFAULT_REFERENCE: self.references} if isinstance(self.references, Reference) else dict(self.references)
        if not refs:
            raise InputError(f"EvaluationSet({self.name}).references is empty")
        for k, r in refs.items():
            if not isinstance(r, Reference):
                raise InputError(f"EvaluationSet.references[{k!r}] must be a factorloc.Reference, got {type(r).__name__}")
        object.__setattr__(self, "references", MappingProxyType(refs))
        cases = tuple(self.cases)
        if not cases:
            raise InputError(f"EvaluationSet({self.name}).cases is empty: nothing to evaluate")
        for i, c in enumerate(cases):
            if not isinstance(c, Case):
                raise InputError(f"EvaluationSet.cases[{i}] must be a Case, got {type(c).__name__}")
            if c.reference_id not in refs:
                raise InputError(
                    f"EvaluationSet.cases[{i}] ({c.query.id}) names reference {c.reference_id!r}, not one of {sorted(refs)}"
                )
        object.__setattr__(self, "cases", cases)

    def reference_of(self, case: Case) -> Reference:
        """The reference ``case`` is localized against."""
        return self.references[case.reference_id]


def evaluation_set(scenario: Any) -> EvaluationSet:
    """The :class:`EvaluationSet` of ``scenario`` (an ``EvaluationSet`` is returned as is).

    Accepts a :class:`factorloc.datasets.Scenario`: its references, its
    queries (in scenario order) with their ground truth, fault tags and
    reference, and its world when known.
    """
    if isinstance(scenario, EvaluationSet):
        return scenario
    from factorloc.datasets.scenario import Scenario

    if not isinstance(scenario, Scenario):
        raise InputError(f"scenario must be a factorloc.datasets.Scenario or an EvaluationSet, got {type(scenario).__name__}")
    cases = tuple(Case(q.query, q.truth, tuple(q.faults), q.reference_id, q.distance_from_reference_m) for q in scenario.queries)
    refs = {r.id: r.reference for r in scenario.references}
    return EvaluationSet(refs, cases, name=scenario.name, world=scenario.world)

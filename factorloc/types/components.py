"""The pose components an estimate can measure, and their index in an (x, y, θ) vector."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from enum import StrEnum
from types import MappingProxyType
from typing import Any

from factorloc.errors import InputError

__all__ = ["COMPONENT_INDEX", "FULL", "HEADING", "POSITION", "Component", "component_indices", "component_set"]


class Component(StrEnum):
    """A pose component an estimate can measure."""

    X = "x"
    Y = "y"
    THETA = "theta"


#: The component sets an :class:`Estimate` may measure, in canonical order.
HEADING: tuple[Component, ...] = (Component.THETA,)
POSITION: tuple[Component, ...] = (Component.X, Component.Y)
FULL: tuple[Component, ...] = (Component.X, Component.Y, Component.THETA)
ALLOWED_COMPONENTS = {HEADING: "heading", POSITION: "position", FULL: "full"}
#: Position of each component in an (x, y, θ) vector or 3×3 covariance: the one index map.
COMPONENT_INDEX: Mapping[Component, int] = MappingProxyType({Component.X: 0, Component.Y: 1, Component.THETA: 2})


def component_indices(components: Sequence[Component | str]) -> list[int]:
    """Positions of ``components`` in (x, y, θ)."""
    return [COMPONENT_INDEX[Component(c)] for c in components]


#: The canonical tuples by themselves (a tuple of names or members equal to one maps to it).
_CANONICAL: Mapping[tuple[Component, ...], tuple[Component, ...]] = MappingProxyType({c: c for c in ALLOWED_COMPONENTS})


def component_set(value: Any) -> tuple[Component, ...]:
    """``value`` (component names or members) as one of the allowed sets in canonical order, or InputError."""
    if type(value) is tuple:
        try:
            canonical = _CANONICAL.get(value)
        except TypeError:  # unhashable items: the general form below says what is wrong
            canonical = None
        if canonical is not None:
            return canonical
    try:
        comps = tuple(sorted({Component(c) for c in value}, key=COMPONENT_INDEX.__getitem__))
    except (TypeError, ValueError) as exc:
        raise InputError(f"Estimate.components must be drawn from 'x', 'y', 'theta', got {value!r}") from exc
    if comps not in ALLOWED_COMPONENTS:
        raise InputError(
            "Estimate.components must be ('theta',) heading-only, ('x', 'y') position-only "
            f"or ('x', 'y', 'theta') full pose, got {tuple(c.value for c in comps)}"
        )
    return comps

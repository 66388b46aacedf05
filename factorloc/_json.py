"""JSON-ready values of the typed results: the one converter behind every ``to_json``."""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from enum import Enum
from typing import Any

import numpy as np

__all__ = ["JsonRecord", "json_ready"]


def json_ready(value: Any, *, finite: bool = True) -> Any:
    """``value`` as plain JSON types, recursively.

    Dataclasses become dicts of their fields in order (a :class:`JsonRecord` gives its own
    :meth:`~JsonRecord.to_json`), mappings dicts with string keys, sequences and arrays lists, numpy scalars
    Python numbers, enums their values. With ``finite`` (the default), NaN and ±inf become ``None``
    (JSON has no such numbers: ``null`` means "not applicable").
    """
    if isinstance(value, JsonRecord):
        return value.to_json()
    if dataclasses.is_dataclass(value) and not isinstance(value, type):
        return {f.name: json_ready(getattr(value, f.name), finite=finite) for f in dataclasses.fields(value)}
    if isinstance(value, Enum):
        return value.value
    if isinstance(value, Mapping):
        return {str(k): json_ready(v, finite=finite) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v, finite=finite) for v in value]
    if isinstance(value, np.ndarray):
        return json_ready(value.tolist(), finite=finite)
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)):
        return int(value)
    if isinstance(value, (float, np.floating)):
        v = float(value)
        return v if math.isfinite(v) or not finite else None
    if isinstance(value, np.generic):  # numpy strings, bytes, datetimes
        return value.item()
    return value


class JsonRecord:
    """Mixin of the frozen result dataclasses: :meth:`to_json` gives their fields in order, JSON-safe."""

    def to_json(self) -> dict[str, Any]:
        """The fields as a JSON-ready dict (NaN and ±inf as ``null``)."""
        return {f.name: json_ready(getattr(self, f.name)) for f in dataclasses.fields(self)}  # type: ignore[arg-type]

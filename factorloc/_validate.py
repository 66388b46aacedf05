"""The input rules every boundary shares: what a valid number, mapping or sequence is, and how it is said.

Each rule has one home here. The ``*_problem`` functions return what is wrong with a value (``""`` when nothing
is) so that each boundary frames the words in its own error: the constructors raise
:class:`~factorloc.errors.InputError` naming the field (:func:`finite_float`, :func:`positive_float`, …), the
config loader :class:`~factorloc.errors.ConfigError` naming the key (:mod:`factorloc.config`), the scenario
reader :class:`~factorloc.errors.DatasetError` naming the manifest and the field
(:mod:`factorloc.datasets.reader`).
"""

from __future__ import annotations

import difflib
import math
from collections.abc import Collection, Mapping
from typing import Any

import numpy as np

from factorloc.errors import InputError

__all__ = [
    "MAX_ANGLE_MARGIN_RAD",
    "MAX_COORDINATE_M",
    "MIN_CORRELATION_EIGENVALUE",
    "SIGMA_MAX",
    "SIGMA_MIN",
    "angle_of_view",
    "bgr_image",
    "construct",
    "finite_float",
    "float_array",
    "keys_problem",
    "mapping",
    "nonnegative_float",
    "number_problem",
    "point2",
    "positive_float",
    "positive_int",
    "sequence",
    "sigma_float",
    "sigma_problem",
]

#: The smallest standard deviation an input may carry (metres for positions, radians for headings).
#: Below it a variance (≤ 1e-18) next to another one of the documented range makes the information matrix
#: lose every digit of the larger variance (double precision keeps about 16).
SIGMA_MIN = 1e-9
#: The largest standard deviation an input may carry (m, rad): beyond it a value is not a measurement
#: (and its variance, 1e12, stays far from overflow when multiplied or summed).
SIGMA_MAX = 1e6
#: A covariance's correlation matrix (``D^-1/2 Σ D^-1/2``) must have its smallest eigenvalue at least this
#: large: a correlation closer to ±1 than 1 - 5e-13 makes the inverse (the information) meaningless.
MIN_CORRELATION_EIGENVALUE = 1e-12
#: The largest absolute coordinate (m) of a position estimate or a registered point: at 1e9 m a double still
#: resolves 1.2e-7 m; at 1e16 m its spacing is 2 m, so a σ of centimetres could not be honest. One home for the
#: estimates (:class:`~factorloc.types.Estimate`) and the registration (``factorloc.registration.prepared``).
MAX_COORDINATE_M = 1e9
#: A field of view (camera hfov, panorama fov_v) lies in [MARGIN, π - MARGIN]: at 0 the focal length is
#: infinite, at π zero (``f = (W/2) / tan(fov/2)``).
MAX_ANGLE_MARGIN_RAD = 1e-3


def _short(value: Any, limit: int = 60) -> str:
    """``repr(value)`` cut to ``limit`` characters (a 400-digit integer in a message is one line, not a page)."""
    text = repr(value)
    return text if len(text) <= limit else f"{text[: limit - 20]}…({len(text)} characters)"


def number_problem(value: Any, *, positive: bool = False, nonnegative: bool = False) -> str:
    """What is wrong with ``value`` as a finite real number (> 0 with ``positive``, ≥ 0 with ``nonnegative``), or ``""``.

    Booleans are not numbers; numpy scalars are.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        return f"must be a real number, got {type(value).__name__} {_short(value)}"
    try:
        out = float(value)
    except OverflowError:
        return f"must be finite (a float), got {_short(value)}"
    if not math.isfinite(out):
        return f"must be finite, got {out!r}"
    if positive and out <= 0.0:
        return f"must be > 0, got {out!r}"
    if nonnegative and out < 0.0:
        return f"must be >= 0, got {out!r}"
    return ""


def sigma_problem(value: Any) -> str:
    """What is wrong with ``value`` as a standard deviation (a finite number in [SIGMA_MIN, SIGMA_MAX]), or ``""``."""
    problem = number_problem(value, positive=True)
    if problem:
        return problem
    out = float(value)
    if not SIGMA_MIN <= out <= SIGMA_MAX:
        return f"must be a standard deviation in [{SIGMA_MIN:g}, {SIGMA_MAX:g}] (m or rad), got {out!r}"
    return ""


def sigma_float(name: str, value: Any) -> float:
    """Return ``value`` as a standard deviation in [:data:`SIGMA_MIN`, :data:`SIGMA_MAX`] or raise :class:`InputError`."""
    problem = sigma_problem(value)
    if problem:
        raise InputError(f"{name} {problem}")
    return float(value)


def angle_of_view(name: str, value: Any) -> float:
    """Return ``value`` as a field of view in [MARGIN, π - MARGIN] (:data:`MAX_ANGLE_MARGIN_RAD`) or raise."""
    fov = positive_float(name, value)
    if not MAX_ANGLE_MARGIN_RAD <= fov <= math.pi - MAX_ANGLE_MARGIN_RAD:
        raise InputError(
            f"{name} must be a field of view in [{MAX_ANGLE_MARGIN_RAD:g}, π - {MAX_ANGLE_MARGIN_RAD:g}] rad, got {fov!r}"
        )
    return fov


def keys_problem(data: Mapping[str, Any], known: Collection[str]) -> str:
    """What is wrong with the keys of ``data`` (a key not in ``known``, with the nearest known one), or ``""``."""
    unknown = sorted(str(k) for k in data if k not in known)
    if not unknown:
        return ""
    hint = difflib.get_close_matches(unknown[0], sorted(known), n=1)
    suggestion = f" (did you mean {hint[0]!r}?)" if hint else ""
    return f"has unknown key(s) {unknown}{suggestion}; known: {sorted(known)}"


def _checked(name: str, value: Any, **rule: bool) -> float:
    problem = number_problem(value, **rule)
    if problem:
        raise InputError(f"{name} {problem}")
    return float(value)


def finite_float(name: str, value: Any) -> float:
    """Return ``value`` as a finite float or raise :class:`InputError`."""
    if type(value) is float and math.isfinite(value):  # the common case (every Pose2 made), without the checks' calls
        return value
    return _checked(name, value)


def positive_float(name: str, value: Any) -> float:
    """Return ``value`` as a finite float > 0 or raise :class:`InputError`."""
    return _checked(name, value, positive=True)


def nonnegative_float(name: str, value: Any) -> float:
    """Return ``value`` as a finite float >= 0 or raise :class:`InputError`."""
    return _checked(name, value, nonnegative=True)


def positive_int(name: str, value: Any, minimum: int = 1) -> int:
    """Return ``value`` as an int ≥ ``minimum`` (booleans are not integers) or raise :class:`InputError`."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or int(value) < minimum:
        raise InputError(f"{name} must be an integer >= {minimum}, got {value!r}")
    return int(value)


def mapping(name: str, value: Any, known: Collection[str] | None = None) -> dict[str, Any]:
    """``value`` as a dict, checked to be a mapping (with only ``known`` keys when given), or raise :class:`InputError`."""
    if not isinstance(value, Mapping):
        raise InputError(f"{name} must be a mapping, got {type(value).__name__}")
    problem = keys_problem(value, known) if known is not None else ""
    if problem:
        raise InputError(f"{name} {problem}")
    return dict(value)


def sequence(name: str, value: Any, n: int | None = None) -> list[Any]:
    """``value`` as a list, checked to be a list, tuple or 1-D array (of ``n`` items when given), or raise :class:`InputError`."""
    if not isinstance(value, (list, tuple, np.ndarray)) or np.ndim(value) == 0:
        raise InputError(f"{name} must be a list, got {type(value).__name__}")
    if n is not None and len(value) != n:
        raise InputError(f"{name} must be a sequence of {n} numbers, got {value!r}")
    return list(value)


def construct(cls: type, where: str, fields: dict[str, Any]) -> Any:
    """``cls(**fields)``, an unknown or missing field raised as :class:`InputError` naming ``where``."""
    try:
        return cls(**fields)
    except TypeError as exc:
        raise InputError(f"{where}: {exc}") from exc


def point2(name: str, value: Any) -> tuple[float, float]:
    """``value`` as a point ``(x, y)`` of two finite floats, or raise :class:`InputError`."""
    x, y = sequence(name, value, 2)
    return finite_float(f"{name}[0]", x), finite_float(f"{name}[1]", y)


def float_array(name: str, value: Any, shape: tuple[int | None, ...], *, min_rows: int = 1) -> np.ndarray:
    """Return a read-only float64 copy of ``value`` with the given shape.

    ``None`` in ``shape`` means any length. Rejects non-numeric data, wrong
    shapes, fewer than ``min_rows`` rows, and NaN/inf.
    """
    if isinstance(value, np.ndarray):
        arr = value
    else:
        try:
            arr = np.asarray(value)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{name} is not array-like: {exc}") from exc
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.floating) or np.issubdtype(arr.dtype, np.integer)):
        raise InputError(f"{name} must be a numeric array, got dtype {arr.dtype}")
    if arr.ndim != len(shape) or any(s is not None and s != a for s, a in zip(shape, arr.shape, strict=True)):
        want = "×".join("N" if s is None else str(s) for s in shape)
        raise InputError(f"{name} must have shape {want}, got {arr.shape}")
    if arr.ndim >= 1 and arr.shape[0] < min_rows:
        raise InputError(f"{name} must have at least {min_rows} row(s), got {arr.shape[0]}")
    out = np.array(arr, dtype=np.float64, copy=True)
    if not np.isfinite(out).all():
        bad = int(np.count_nonzero(~np.isfinite(out)))
        raise InputError(f"{name} contains {bad} NaN or infinite value(s)")
    out.setflags(write=False)
    return out


def bgr_image(name: str, value: Any) -> np.ndarray:
    """Return a read-only copy of a colour image: H×W×3 uint8, BGR (OpenCV order)."""
    if not isinstance(value, np.ndarray):
        raise InputError(f"{name} must be a numpy array (H×W×3 uint8 BGR), got {type(value).__name__}")
    if value.dtype != np.uint8:
        raise InputError(f"{name} must be uint8 (BGR, 0..255), got dtype {value.dtype}")
    if value.ndim != 3 or value.shape[2] != 3:
        raise InputError(f"{name} must be a colour image of shape H×W×3 (BGR), got shape {value.shape}")
    if value.shape[0] < 8 or value.shape[1] < 8:
        raise InputError(f"{name} is too small ({value.shape[1]}×{value.shape[0]} px); need at least 8×8")
    out = np.ascontiguousarray(value).copy()
    out.setflags(write=False)
    return out

"""Input checks shared by the constructors: each raises InputError naming the field."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from factorloc.errors import InputError


def finite_float(name: str, value: Any) -> float:
    """Return ``value`` as a finite float or raise :class:`InputError`."""
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"{name} must be a real number, got {type(value).__name__} {value!r}")
    out = float(value)
    if not math.isfinite(out):
        raise InputError(f"{name} must be finite, got {out!r}")
    return out


def positive_float(name: str, value: Any) -> float:
    """Return ``value`` as a finite float > 0 or raise :class:`InputError`."""
    out = finite_float(name, value)
    if out <= 0.0:
        raise InputError(f"{name} must be > 0, got {out!r}")
    return out


def nonnegative_float(name: str, value: Any) -> float:
    """Return ``value`` as a finite float >= 0 or raise :class:`InputError`."""
    out = finite_float(name, value)
    if out < 0.0:
        raise InputError(f"{name} must be >= 0, got {out!r}")
    return out


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

"""One estimator's measurement of some pose components: :class:`Estimate` (world frame, with its typed verdicts)."""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Any

import numpy as np

from factorloc._json import json_ready
from factorloc._validate import MAX_COORDINATE_M, MIN_CORRELATION_EIGENVALUE, SIGMA_MAX, SIGMA_MIN, float_array, sigma_float
from factorloc.errors import InputError
from factorloc.geometry import Pose2, wrap_angle
from factorloc.types.components import ALLOWED_COMPONENTS, FULL, HEADING, POSITION, Component, component_set
from factorloc.verdicts import Check, SeedEvidence, failed, render_checks

__all__ = ["Estimate"]


def _cholesky_pivots(c: list[list[float]]) -> list[float]:
    """The pivots ``d_i`` of the LDLᵀ factorization of a small symmetric matrix (all > 0 ⇔ positive definite).

    Plain Python for k ≤ 3: a numpy call costs more than the arithmetic. The
    factorization stops at the first pivot ≤ 0 (it is returned last).
    """
    k = len(c)
    L = [[0.0] * k for _ in range(k)]
    d: list[float] = []
    for j in range(k):
        dj = c[j][j] - sum(L[j][m] * L[j][m] * d[m] for m in range(j))
        d.append(dj)
        if not dj > 0.0:
            break
        for i in range(j + 1, k):
            L[i][j] = (c[i][j] - sum(L[i][m] * L[j][m] * d[m] for m in range(j))) / dj
    return d


def _cholesky_pivots3(c: list[list[float]]) -> list[float]:
    """:func:`_cholesky_pivots` of a 3×3 matrix, unrolled: the same operations in the same order (``sum`` starts
    from the integer 0), so the same bits (``tests/test_types.py`` compares them)."""
    d0 = c[0][0] - 0
    if not d0 > 0.0:
        return [d0]
    l10 = (c[1][0] - 0) / d0
    l20 = (c[2][0] - 0) / d0
    d1 = c[1][1] - (0 + l10 * l10 * d0)
    if not d1 > 0.0:
        return [d0, d1]
    l21 = (c[2][1] - (0 + l20 * l10 * d0)) / d1
    d2 = c[2][2] - ((0 + l20 * l20 * d0) + l21 * l21 * d1)
    return [d0, d1, d2]


def _float_rows(name: str, value: Any, k: int) -> list[list[float]]:
    """``value`` as k×k nested lists of finite floats: what :func:`~factorloc._validate.float_array` accepts, read
    without its copy when ``value`` is already a finite k×k float64 array (the errors are float_array's)."""
    if type(value) is np.ndarray and value.dtype == np.float64 and value.shape == (k, k):
        rows = value.tolist()
        if all(map(math.isfinite, value.ravel().tolist())):
            return rows
    return float_array(name, value, (k, k)).tolist()


def _covariance(name: str, value: Any, k: int) -> np.ndarray:
    """The k×k covariance ``value``, checked: symmetric, positive definite, every σ (the square root of a diagonal
    term) in [SIGMA_MIN, SIGMA_MAX] (:mod:`factorloc._validate`) and correlations away from ±1
    (:data:`~factorloc._validate.MIN_CORRELATION_EIGENVALUE`). Checked before any arithmetic on it, so nothing
    overflows (the symmetrized mean is taken as ``0.5·a + 0.5·b``).

    On the k ≤ 3 entries as plain floats (the numpy calls cost more than the arithmetic; the same IEEE operations,
    so the same verdicts and bits). The correlation matrix's smallest eigenvalue (``numpy.linalg.eigvalsh``) is
    computed only when a bound from the LDLᵀ pivots does not already put it far above the limit:
    ``λ_min ≥ det(R) / k^(k−1)`` (the other eigenvalues sum to at most ``tr R = k``), with ``det R`` the product
    of the pivots over that of the diagonal; ``det R ≥`` :data:`_SURE_CORRELATION_DET` makes ``λ_min`` at least
    1e-7, five orders above the limit and far beyond the rounding of either computation."""
    c = _float_rows(name, value, k)
    bad = [i for i in range(k) if c[i][i] > 0.0 and not _VAR_MIN <= c[i][i] <= _VAR_MAX]  # ≤ 0: not PD, below
    if bad:
        raise InputError(
            f"{name}[{bad[0]}][{bad[0]}] must be a variance whose σ is in [{SIGMA_MIN:g}, {SIGMA_MAX:g}] (m or rad), "
            f"got {c[bad[0]][bad[0]]!r}"
        )
    # np.allclose(rtol=1e-9, atol=1e-15), cheaper. An exactly symmetric matrix (what the estimators build) is its
    # own symmetrized mean, bit for bit, when no entry is below 2^-1021 in magnitude except zeros (0.5·a is then
    # exact, and so is 0.5·a + 0.5·a = a); otherwise the mean is taken
    exact = _exactly_symmetric(c, k)
    if not exact and any(abs(c[i][j] - c[j][i]) > 1e-15 + 1e-9 * abs(c[j][i]) for i in range(k) for j in range(k)):
        raise InputError(f"{name} must be symmetric, got {c}")
    sym = c if exact else [[0.5 * c[i][j] + 0.5 * c[j][i] for j in range(k)] for i in range(k)]
    cov = np.array(sym)
    pivots = _cholesky_pivots3(sym) if k == 3 else _cholesky_pivots(sym)
    if not all(p > 0.0 for p in pivots):
        with np.errstate(all="ignore"):
            eig = np.linalg.eigvalsh(cov).tolist() if np.abs(cov).max() <= SIGMA_MAX**2 else "(entries beyond σ² range)"
        raise InputError(f"{name} must be positive definite (all sigmas > 0), got eigenvalues {eig}")
    if k > 1 and not math.prod(pivots) / math.prod(sym[i][i] for i in range(k)) >= _SURE_CORRELATION_DET:
        scale = 1.0 / np.sqrt(np.diagonal(cov))
        corr_min = float(np.linalg.eigvalsh(cov * np.outer(scale, scale))[0])
        if corr_min < MIN_CORRELATION_EIGENVALUE:
            raise InputError(
                f"{name} is too close to singular: its correlation matrix has eigenvalue {corr_min:.3g} "
                f"< {MIN_CORRELATION_EIGENVALUE:g} (a correlation of ±1)"
            )
    cov.setflags(write=False)
    return cov


_VAR_MIN, _VAR_MAX = SIGMA_MIN**2, SIGMA_MAX**2
_HALF_EXACT = 2.0**-1021  # from this magnitude on, 0.5·a is exact (a / 2 is a normal double)
_UPPER = {k: [(i, j) for i in range(k) for j in range(i + 1, k)] for k in (1, 2, 3)}


def _exactly_symmetric(c: list[list[float]], k: int) -> bool:
    """Whether ``c`` (k×k finite floats) equals its symmetrized mean ``0.5·c + 0.5·cᵀ`` bit for bit by construction:
    exactly symmetric, and every entry zero or at least 2^-1021 in magnitude."""
    if k not in _UPPER or not all(c[i][j] == c[j][i] for i, j in _UPPER[k]):
        return False
    return all(x == 0.0 or abs(x) >= _HALF_EXACT for row in c for x in row)


#: A correlation matrix (k ≤ 3) whose determinant reaches this has its smallest eigenvalue ≥ 1e-6 / 9 (see
#: :func:`_covariance`): no need to compute it against :data:`~factorloc._validate.MIN_CORRELATION_EIGENVALUE`.
_SURE_CORRELATION_DET = 1e-6


def _json_bool(name: str, value: Any) -> bool:
    """A JSON boolean (``true``/``false``; numpy's bool too), not a string or a number read as truthy."""
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    raise InputError(f"{name} must be a JSON boolean (true or false), got {type(value).__name__} {value!r}")


# --------------------------------------------------------------------------
# Estimate
# --------------------------------------------------------------------------
@dataclass(frozen=True)
class Estimate:
    """One estimator's measurement of some pose components, in the world frame.

    Parameters
    ----------
    step
        Name of the step that made it (``"odometry"``, ``"compass"``, ``"correlation"``, ``"icp"``, …).
    components
        What it measures: ``("theta",)``, ``("x", "y")`` or ``("x", "y", "theta")``.
    values
        The measured values in the order of ``components`` (metres, radians; θ wrapped to [-π, π)).
    covariance
        k×k covariance of ``values`` (m², rad²), world frame. Per-axis estimates
        (the patent's case) have a diagonal one; use :meth:`heading`,
        :meth:`position` or :meth:`pose` to build from sigmas.
    reliable
        The estimator's own verdict.
    reason
        A human-readable reason for it. Without a ``reason``, an estimate with ``checks`` gets the
        one rendered from its failed checks (:func:`factorloc.verdicts.render_checks`).
    diagnostics
        Free-form figures for people and plots: match count, peak correlation, residual, scale… Nothing in
        the library decides on them: decisions travel as ``checks`` and ``seed``.
    checks
        The step's reliability rules as typed :class:`~factorloc.verdicts.Check` records, in the order they
        apply. An estimate with a failed check cannot be ``reliable``.
    seed
        What seeded the step and what its data say about that seed (:class:`~factorloc.verdicts.SeedEvidence`;
        None: the step used no seed and tested none). The gate's seed audit reads only this.
    """

    step: str
    components: tuple[Component, ...]
    values: np.ndarray
    covariance: np.ndarray
    reliable: bool = True
    reason: str = ""
    diagnostics: Mapping[str, Any] = field(default_factory=dict)
    checks: tuple[Check, ...] = ()
    seed: SeedEvidence | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.step, str) or not self.step:
            raise InputError(f"Estimate.step must be a non-empty string, got {self.step!r}")
        comps = component_set(self.components)
        object.__setattr__(self, "components", comps)
        k = len(comps)
        v = self.values
        if type(v) is np.ndarray and v.dtype == np.float64 and v.shape == (k,) and all(map(math.isfinite, v.tolist())):
            values = v.copy()  # what float_array would accept, without its copy and checks' calls
        else:
            values = np.array(float_array(f"Estimate({self.step}).values", v, (k,)))
        if comps[-1] is Component.THETA:
            values[-1] = wrap_angle(float(values[-1]))
        if k >= 2 and not max(abs(float(values[0])), abs(float(values[1]))) <= MAX_COORDINATE_M:
            raise InputError(
                f"Estimate({self.step}).values: position ({values[0]!r}, {values[1]!r}) m is beyond the documented "
                f"coordinate range ±{MAX_COORDINATE_M:g} m"
            )
        values.setflags(write=False)
        object.__setattr__(self, "values", values)
        object.__setattr__(self, "covariance", _covariance(f"Estimate({self.step}).covariance", self.covariance, k))
        object.__setattr__(self, "reliable", bool(self.reliable))
        checks = tuple(self.checks)
        for c in checks:
            if not isinstance(c, Check):
                raise InputError(f"Estimate({self.step}).checks must hold factorloc.verdicts.Check, got {type(c).__name__}")
        if self.reliable and failed(checks):
            raise InputError(f"Estimate({self.step}) cannot be reliable with failed checks: {render_checks(checks)}")
        object.__setattr__(self, "checks", checks)
        if self.seed is not None and not isinstance(self.seed, SeedEvidence):
            raise InputError(f"Estimate({self.step}).seed must be a SeedEvidence or None, got {type(self.seed).__name__}")
        reason = str(self.reason)
        if not reason and not self.reliable and checks:
            reason = render_checks(checks)
        object.__setattr__(self, "reason", reason)
        object.__setattr__(self, "diagnostics", MappingProxyType(dict(self.diagnostics)))

    # --- builders -----------------------------------------------------------
    @classmethod
    def heading(cls, step: str, theta_rad: float, sigma_rad: float, **kwargs: Any) -> Estimate:
        """A heading-only estimate θ ± σ (radians)."""
        s = sigma_float(f"Estimate({step}).sigma_theta_rad", sigma_rad)
        return cls(step, HEADING, [theta_rad], [[s * s]], **kwargs)

    @classmethod
    def position(
        cls,
        step: str,
        x_m: float,
        y_m: float,
        sigma_x_m: float | None = None,
        sigma_y_m: float | None = None,
        *,
        covariance: np.ndarray | None = None,
        **kwargs: Any,
    ) -> Estimate:
        """A position-only estimate (world-frame x, y) from sigmas or a 2×2 covariance."""
        if covariance is None:
            sx = sigma_float(f"Estimate({step}).sigma_x_m", sigma_x_m)
            sy = sigma_float(f"Estimate({step}).sigma_y_m", sigma_y_m)
            covariance = np.diag([sx * sx, sy * sy])
        return cls(step, POSITION, [x_m, y_m], covariance, **kwargs)

    @classmethod
    def pose(
        cls,
        step: str,
        pose: Pose2,
        sigma_x_m: float | None = None,
        sigma_y_m: float | None = None,
        sigma_theta_rad: float | None = None,
        *,
        covariance: np.ndarray | None = None,
        **kwargs: Any,
    ) -> Estimate:
        """A full-pose estimate from per-axis sigmas or a 3×3 world-frame covariance."""
        if covariance is None:
            sx = sigma_float(f"Estimate({step}).sigma_x_m", sigma_x_m)
            sy = sigma_float(f"Estimate({step}).sigma_y_m", sigma_y_m)
            st = sigma_float(f"Estimate({step}).sigma_theta_rad", sigma_theta_rad)
            covariance = np.diag([sx * sx, sy * sy, st * st])
        return cls(step, FULL, pose.as_array(), covariance, **kwargs)

    # --- accessors ------------------------------------------------------------
    @property
    def kind(self) -> str:
        """``"heading"``, ``"position"`` or ``"full"``."""
        return ALLOWED_COMPONENTS[self.components]

    @property
    def sigmas(self) -> np.ndarray:
        """Standard deviations of ``values`` (square roots of the covariance diagonal)."""
        return np.sqrt(np.diag(self.covariance))

    def measures(self, component: Component | str) -> bool:
        """Whether this estimate measures ``component``."""
        return (component if type(component) is Component else Component(component)) in self.components

    def _index(self, component: Component | str) -> int:
        """The position of ``component`` in ``components``; :class:`InputError` naming it when not measured."""
        try:
            return self.components.index(component if type(component) is Component else Component(component))
        except ValueError:
            measured = [str(c.value) for c in self.components]
            raise InputError(f"the {self.step!r} estimate measures {measured}, not {component!r}") from None

    def value(self, component: Component | str) -> float:
        """The measured value of ``component`` (m or rad); :class:`InputError` when it is not measured."""
        return float(self.values[self._index(component)])

    def sigma(self, component: Component | str) -> float:
        """The standard deviation of ``component`` (m or rad); :class:`InputError` when it is not measured."""
        i = self._index(component)
        return float(math.sqrt(self.covariance[i, i]))

    @property
    def has_cross_covariance(self) -> bool:
        """True when a full estimate couples position and heading (non-zero x–θ or y–θ terms)."""
        return self.kind == "full" and bool(np.any(self.covariance[:2, 2] != 0.0))

    def marginal(self, components: Sequence[Component | str]) -> Estimate:
        """The estimate restricted to ``components`` (values and covariance block)."""
        comps = component_set(components)
        missing = [c.value for c in comps if c not in self.components]
        if missing:
            raise InputError(f"Estimate({self.step}) does not measure {missing}")
        idx = [self.components.index(c) for c in comps]
        return Estimate(
            self.step,
            comps,
            self.values[idx],
            self.covariance[np.ix_(idx, idx)],
            self.reliable,
            self.reason,
            self.diagnostics,
            self.checks,
            self.seed,
        )

    def with_verdict(self, reliable: bool, reason: str, checks: Sequence[Check] | None = None) -> Estimate:
        """A copy with another reliability verdict (and, when given, other checks)."""
        kept = self.checks if checks is None else tuple(checks)
        return Estimate(
            self.step, self.components, self.values, self.covariance, reliable, reason, self.diagnostics, kept, self.seed
        )

    def to_dict(self) -> dict[str, Any]:
        """A JSON-ready dict (the format ``factorloc fuse`` reads)."""
        return {
            "step": self.step,
            "components": [c.value for c in self.components],
            "values": self.values.tolist(),
            "covariance": self.covariance.tolist(),
            "reliable": self.reliable,
            "reason": self.reason,
            "diagnostics": json_ready(self.diagnostics, finite=False),
            "checks": [c.to_dict() for c in self.checks],
            "seed": None if self.seed is None else self.seed.to_dict(),
        }

    @classmethod
    def from_dict(cls, data: Mapping[str, Any]) -> Estimate:
        """Inverse of :meth:`to_dict`; ``sigmas`` may replace ``covariance``.

        Every field is type-checked: a malformed one raises :class:`InputError` naming the estimate and the field
        (never a ``TypeError`` or ``KeyError`` from deeper down).
        """
        if not isinstance(data, Mapping):
            raise InputError(f"an estimate must be a JSON object, got {type(data).__name__}")
        for key in ("step", "components", "values"):
            if key not in data:
                raise InputError(f"estimate is missing the field '{key}': {dict(data)!r}"[:300])
        step = data["step"]
        if not isinstance(step, str) or not step:
            raise InputError(f"estimate field 'step' must be a non-empty string, got {step!r}"[:200])
        where = f"Estimate({step})"
        comps = data["components"]
        if not isinstance(comps, (list, tuple)) or not all(isinstance(c, str) for c in comps):
            raise InputError(f"{where}.components must be a list of component names, got {comps!r}"[:200])
        values = data["values"]
        if not isinstance(values, (list, tuple)):
            raise InputError(f"{where}.values must be a list of numbers, got {type(values).__name__}")
        if "covariance" in data:
            cov = data["covariance"]
        elif "sigmas" in data:
            sig = float_array(f"{where}.sigmas", data["sigmas"], (len(values),))
            for i, s in enumerate(sig):
                sigma_float(f"{where}.sigmas[{i}]", s)
            cov = np.diag(sig**2)
        else:
            raise InputError(f"estimate '{step}' needs 'covariance' or 'sigmas'")
        checks_data, seed_data = data.get("checks") or (), data.get("seed")
        try:
            if not isinstance(checks_data, (list, tuple)):
                raise TypeError(f"a list, got {type(checks_data).__name__}")
            checks = tuple(Check.from_dict(c) for c in checks_data)
        except (TypeError, ValueError, KeyError, AttributeError) as exc:
            raise InputError(f"{where}.checks must be a list of checks as to_dict writes them: {exc}"[:300]) from exc
        try:
            seed = None if seed_data is None else SeedEvidence.from_dict(seed_data)
        except (TypeError, ValueError, KeyError, AttributeError) as exc:
            raise InputError(f"{where}.seed must be a seed record as to_dict writes it: {exc}"[:300]) from exc
        diagnostics = data.get("diagnostics", {})
        if not isinstance(diagnostics, Mapping):
            raise InputError(f"{where}.diagnostics must be an object, got {type(diagnostics).__name__}")
        reason = data.get("reason", "")
        if not isinstance(reason, str):
            raise InputError(f"{where}.reason must be a string, got {type(reason).__name__}")
        return cls(
            step=step,
            components=tuple(comps),
            values=values,
            covariance=cov,
            reliable=_json_bool(f"{where}.reliable", data.get("reliable", True)),
            reason=reason,
            diagnostics=diagnostics,
            checks=checks,
            seed=seed,
        )

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Estimate):
            return NotImplemented
        return (
            self.step == other.step
            and self.components == other.components
            and np.array_equal(self.values, other.values)
            and np.array_equal(self.covariance, other.covariance)
            and self.reliable == other.reliable
            and self.reason == other.reason
            and dict(self.diagnostics) == dict(other.diagnostics)
            and self.checks == other.checks
            and self.seed == other.seed
        )

    __hash__ = None  # type: ignore[assignment]

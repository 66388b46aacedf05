"""One root configuration of per-step sub-configs, loadable from YAML.

Every field is a frozen dataclass; :meth:`Config.from_dict` rejects unknown
keys and wrong types with a :class:`~factorloc.errors.ConfigError` naming the
key, and :meth:`Config.to_dict` gives back exactly what was used (it is kept
in every :class:`~factorloc.types.Localization`).
"""

from __future__ import annotations

import dataclasses
import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from factorloc._validate import keys_problem, number_problem
from factorloc._yaml import load_yaml
from factorloc.errors import ConfigError
from factorloc.estimators.compass import CompassConfig
from factorloc.estimators.correlation import CorrelationConfig
from factorloc.estimators.icp import IcpConfig
from factorloc.estimators.odometry import OdometryConfig
from factorloc.gating.config import GatingConfig


@dataclass(frozen=True)
class FusionConfig:
    """Which fusion strategy :func:`factorloc.localize` uses: ``"graph"`` (GTSAM) or ``"product"`` (closed form)."""

    strategy: str = "graph"

    def __post_init__(self) -> None:
        if self.strategy not in ("graph", "product"):
            raise ConfigError(f"fusion.strategy must be 'graph' or 'product', got {self.strategy!r}")


@dataclass(frozen=True)
class Config:
    """The root configuration: one sub-config per step, the gates, the fusion."""

    odometry: OdometryConfig = field(default_factory=OdometryConfig)
    compass: CompassConfig = field(default_factory=CompassConfig)
    correlation: CorrelationConfig = field(default_factory=CorrelationConfig)
    icp: IcpConfig = field(default_factory=IcpConfig)
    gating: GatingConfig = field(default_factory=GatingConfig)
    fusion: FusionConfig = field(default_factory=FusionConfig)

    # --- (de)serialisation -------------------------------------------------
    def to_dict(self) -> dict[str, Any]:
        """Nested plain dict (tuples become lists)."""
        return _to_plain(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> Config:
        """Build from a nested dict; missing keys keep their defaults, unknown keys raise."""
        return _from_plain(cls, data or {}, "config")

    @classmethod
    def from_yaml(cls, path: str | Path) -> Config:
        """Load a YAML file (keys as in :meth:`to_dict`)."""
        p = Path(path)
        if not p.is_file():
            raise ConfigError(f"config file not found: {p}")
        try:
            data = load_yaml(p.read_text(encoding="utf-8"))
        except UnicodeDecodeError as exc:
            raise ConfigError(f"config file {p} is not UTF-8 text: {exc}") from exc
        except yaml.YAMLError as exc:
            raise ConfigError(f"config file {p} is not valid YAML: {exc}") from exc
        if data is not None and not isinstance(data, dict):
            raise ConfigError(f"config file {p} must hold a mapping at top level, got {type(data).__name__}")
        return cls.from_dict(data)

    def to_yaml(self, path: str | Path | None = None) -> str:
        """The YAML text of this config; written to ``path`` when given."""
        text = yaml.safe_dump(self.to_dict(), sort_keys=False)
        if path is not None:
            Path(path).write_text(text)
        return text


def _to_plain(obj: Any) -> Any:
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return {f.name: _to_plain(getattr(obj, f.name)) for f in dataclasses.fields(obj)}
    if isinstance(obj, (list, tuple)):
        return [_to_plain(v) for v in obj]
    return obj


def _field_default(f: dataclasses.Field) -> Any:
    """A dataclass field's default value (None without one)."""
    if f.default is not dataclasses.MISSING:
        return f.default
    if f.default_factory is not dataclasses.MISSING:
        return f.default_factory()
    return None


def _from_plain(cls: type, data: Any, where: str, base: Any = None) -> Any:
    """``cls`` from a mapping; missing keys keep the values of ``base`` (default: the fields' own defaults, so that
    a nested group whose default differs from its class's defaults, e.g. ``icp.alignment.icp``, keeps it)."""
    if not isinstance(data, dict):
        raise ConfigError(f"{where} must be a mapping, got {type(data).__name__} {data!r}")
    hints = typing.get_type_hints(cls)
    fields = {f.name: f for f in dataclasses.fields(cls)}
    problem = keys_problem(data, fields)
    if problem:
        raise ConfigError(f"{where} {problem}")
    kwargs: dict[str, Any] = {}
    for name, value in data.items():
        default = getattr(base, name) if base is not None else _field_default(fields[name])
        kwargs[name] = _coerce(hints[name], value, f"{where}.{name}", default)
    try:
        return dataclasses.replace(base, **kwargs) if base is not None else cls(**kwargs)
    except (TypeError, ValueError) as exc:
        if isinstance(exc, ConfigError):
            raise
        raise ConfigError(f"{where}: {exc}") from exc


def _coerce(hint: Any, value: Any, where: str, default: Any = None) -> Any:
    """``value`` as the type ``hint`` of a config field (a dataclass, a tuple, an optional, a scalar); a nested
    dataclass keeps the values of ``default`` for the keys it does not name."""
    origin = typing.get_origin(hint)
    if dataclasses.is_dataclass(hint):
        return _from_plain(hint, value, where, default if isinstance(default, hint) else None)
    if origin is tuple:
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where} must be a list, got {value!r}")
        args = typing.get_args(hint)
        inner = args[0] if args else Any
        return tuple(_coerce(inner, v, f"{where}[{i}]") for i, v in enumerate(value))
    if origin in (typing.Union, types.UnionType):
        return _coerce_union(typing.get_args(hint), value, where)
    return _coerce_scalar(hint, value, where)


def _coerce_union(args: tuple[Any, ...], value: Any, where: str) -> Any:
    if value is None and type(None) in args:
        return None
    for a in args:
        if a is type(None):
            continue
        try:
            return _coerce(a, value, where)
        except ConfigError:
            continue
    raise ConfigError(f"{where} has an invalid value {value!r}")


def _coerce_scalar(hint: Any, value: Any, where: str) -> Any:
    if hint is bool:
        if not isinstance(value, bool):
            raise ConfigError(f"{where} must be true or false, got {value!r}")
        return value
    if hint is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where} must be an integer, got {value!r}")
        return value
    if hint is float:
        problem = number_problem(value)
        if problem:
            raise ConfigError(f"{where} {problem}")
        return float(value)
    if hint is str and not isinstance(value, str):
        raise ConfigError(f"{where} must be a string, got {value!r}")
    return value

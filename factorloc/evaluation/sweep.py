"""Parameter sweeps: settings (config overrides) × scenarios and laser logs, on an executor.

A *setting* is a name and overrides of :class:`~factorloc.config.Config` fields by dotted key
(``{"icp.covariance.sigma_floor_m": 0.0075}``). A :class:`SweepSpec` holds the settings (a grid: the
cartesian product of lists of values, and/or an explicit list), the simulated or recorded scenarios to
:func:`~factorloc.evaluation.evaluate`, and the laser logs to run the relations benchmark on, leave one log
out (:func:`~factorloc.evaluation.folds.relations_folds`; a setting has no fit, so its figures on each
held-out log are its figures on that log). :func:`run_sweep` runs every setting; each
:class:`SettingResult` has one JSON (:meth:`SettingResult.to_json`: the evaluation's keys per scenario and
the fold figures per log) and :func:`format_sweep` one table of them.

The grid file read by :meth:`SweepSpec.from_yaml` (paths relative to the file)::

    grid:                              # every combination of these values (dotted keys into Config)
      icp.covariance.sigma_floor_m: [0.0075, 0.01]
      icp.covariance.bias_rmse_ratio: [0.5, 0.75]
    settings:                          # and/or settings named one by one
      - name: default
        overrides: {}
    base_config: base.yaml             # optional: the config the overrides apply to
    scenarios: [../data/sample]        # optional: scenario directories to evaluate
    laser:                             # optional: the relations benchmark, leave one log out
      directory: ../../shared/data/laser
      logs: [intel, aces, mit-csail]
      every: 10                        # every 10th relation (a fixed subset)

On the laser logs a setting's overrides apply to :func:`~factorloc.evaluation.relations.relations_config` of
the base config (the odometry limits of the benchmark), so that an override of those wins.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from factorloc.config import Config
from factorloc.errors import ConfigError
from factorloc.evaluation.folds import LOGS, Candidate, FoldReport, format_folds, load_laser_datasets, relations_folds
from factorloc.evaluation.relations import relations_config
from factorloc.evaluation.report import EvaluationReport
from factorloc.evaluation.runner import evaluate
from factorloc.parallel import Executor

__all__ = [
    "LaserSpec",
    "Setting",
    "SettingResult",
    "SweepSpec",
    "apply_overrides",
    "format_sweep",
    "grid_settings",
    "run_sweep",
]


def apply_overrides(config: Config, overrides: Mapping[str, Any]) -> Config:
    """``config`` with the fields named by dotted keys replaced (``"icp.covariance.sigma_floor_m"``), validated
    as :meth:`Config.from_dict` validates a YAML file; an unknown key raises a :class:`ConfigError` naming it."""
    data = config.to_dict()
    for key, value in overrides.items():
        parts = str(key).split(".")
        node: Any = data
        for depth, part in enumerate(parts):
            if not isinstance(node, dict) or part not in node:
                where = ".".join(parts[: depth + 1])
                raise ConfigError(f"sweep override {key!r}: config has no field {where!r}")
            if depth == len(parts) - 1:
                if isinstance(node[part], dict):
                    raise ConfigError(f"sweep override {key!r} names a group of fields, not one field")
                node[part] = value
            else:
                node = node[part]
    return Config.from_dict(data)


@dataclass(frozen=True)
class Setting:
    """One point of a sweep: a name and dotted-key overrides of the config."""

    name: str
    overrides: Mapping[str, Any] = field(default_factory=dict)


def _value_text(value: Any) -> str:
    return f"{value:g}" if isinstance(value, float) else str(value)


def grid_settings(grid: Mapping[str, Sequence[Any]]) -> list[Setting]:
    """Every combination of the grid's values, in the order of its keys (the last varies fastest); the name of
    a setting is ``leaf=value`` per key (``sigma_floor_m=0.0075,bias_rmse_ratio=0.5``)."""
    keys = list(grid)
    for k in keys:
        if isinstance(grid[k], (str, bytes)) or not isinstance(grid[k], Sequence) or not grid[k]:
            raise ConfigError(f"sweep grid {k!r} must be a non-empty list of values, got {grid[k]!r}")
    out = []
    for values in itertools.product(*(grid[k] for k in keys)):
        name = ",".join(f"{k.split('.')[-1]}={_value_text(v)}" for k, v in zip(keys, values, strict=True))
        out.append(Setting(name, dict(zip(keys, values, strict=True))))
    return out


@dataclass(frozen=True)
class LaserSpec:
    """The laser logs of a sweep: ``<directory>/<log>.sort.bag`` and ``.relations``; every ``every``-th relation."""

    directory: Path
    logs: tuple[str, ...] = LOGS
    every: int = 1


@dataclass(frozen=True)
class SweepSpec:
    """What a sweep runs: the settings over the scenarios and the laser logs, from ``base``."""

    settings: tuple[Setting, ...]
    scenarios: tuple[Path, ...] = ()
    laser: LaserSpec | None = None
    base: Config = field(default_factory=Config)

    def __post_init__(self) -> None:
        if not self.settings:
            raise ConfigError("a sweep needs at least one setting (grid: or settings:)")
        names = [s.name for s in self.settings]
        if len(set(names)) != len(names):
            raise ConfigError(f"sweep settings must have distinct names, got {names}")
        if not self.scenarios and self.laser is None:
            raise ConfigError("a sweep needs scenarios: or laser: to run on")
        for s in self.settings:  # every override is checked before anything runs
            apply_overrides(self.base, s.overrides)

    @classmethod
    def from_yaml(cls, path: str | Path) -> SweepSpec:
        """Read a grid file (the format of the module docstring); paths are relative to the file."""
        p = Path(path)
        if not p.is_file():
            raise ConfigError(f"sweep file not found: {p}")
        try:
            data = yaml.safe_load(p.read_text())
        except yaml.YAMLError as exc:
            raise ConfigError(f"sweep file {p} is not valid YAML: {exc}") from exc
        if not isinstance(data, dict):
            raise ConfigError(f"sweep file {p} must hold a mapping at top level")
        unknown = set(data) - {"grid", "settings", "base_config", "scenarios", "laser"}
        if unknown:
            raise ConfigError(f"sweep file {p}: unknown keys {sorted(unknown)}")
        here = p.parent
        settings = [*grid_settings(data["grid"])] if data.get("grid") else []
        for i, s in enumerate(data.get("settings") or []):
            if not isinstance(s, dict) or "name" not in s:
                raise ConfigError(f"sweep file {p}: settings[{i}] must be a mapping with a name")
            settings.append(Setting(str(s["name"]), dict(s.get("overrides") or {})))
        base = Config.from_yaml(here / data["base_config"]) if data.get("base_config") else Config()
        laser = None
        if data.get("laser"):
            lz = data["laser"]
            if not isinstance(lz, dict) or "directory" not in lz:
                raise ConfigError(f"sweep file {p}: laser must be a mapping with a directory")
            laser = LaserSpec(here / lz["directory"], tuple(lz.get("logs") or LOGS), int(lz.get("every", 1)))
        scenarios = tuple(here / s for s in data.get("scenarios") or ())
        return cls(tuple(settings), scenarios, laser, base)


@dataclass(frozen=True, eq=False)
class SettingResult:
    """One setting's results: an :class:`EvaluationReport` per scenario and its leave-one-log-out folds."""

    setting: Setting
    config: Config
    scenarios: Mapping[str, EvaluationReport]
    folds: FoldReport | None

    def to_json(self) -> dict[str, Any]:
        """``{"setting", "overrides", "scenarios": {name: the evaluation's keys}, "folds": [...], "worst_shortfall"}``."""
        out: dict[str, Any] = {"setting": self.setting.name, "overrides": dict(self.setting.overrides)}
        out["scenarios"] = {name: rep.to_json() for name, rep in self.scenarios.items()}
        if self.folds is not None:
            out["folds"] = [f.to_dict() for f in self.folds.folds]
            out["worst_shortfall"] = self.folds.worst_shortfall
        return out


SweepProgress = Callable[[str, int, int], None]


def run_sweep(
    spec: SweepSpec,
    *,
    executor: Executor | None = None,
    progress: SweepProgress | None = None,
    every: int | None = None,
) -> list[SettingResult]:
    """Run every setting of ``spec`` on its scenarios and laser logs, on ``executor`` (default in process).

    ``progress(label, done, total)`` follows each batch (label: ``"<setting>: <scenario or log>"``); ``every``
    overrides the laser subset of the spec. The queries (relations) of each batch are spread over the executor's
    workers; the results do not depend on it.
    """
    from factorloc.datasets import load_scenario

    scenarios = [load_scenario(p) for p in spec.scenarios]
    datasets = []
    if spec.laser is not None:
        datasets = load_laser_datasets(spec.laser.directory, spec.laser.logs, every=every or spec.laser.every)
    out = []
    for setting in spec.settings:
        cfg = apply_overrides(spec.base, setting.overrides)
        reports = {}
        for scen in scenarios:
            label = f"{setting.name}: {scen.name}"
            cb = None if progress is None else (lambda d, t, label=label: progress(label, d, t))
            reports[scen.name] = evaluate(scen, config=cfg, executor=executor, progress=cb)
        folds = None
        if datasets:
            laser_cfg = apply_overrides(relations_config(spec.base), setting.overrides)
            folds = relations_folds(
                datasets,
                [Candidate(setting.name, laser_cfg)],
                executor=executor,
                batch_progress=None if progress is None else (lambda log, d, t, s=setting.name: progress(f"{s}: {log}", d, t)),
            )[0]
        out.append(SettingResult(setting, cfg, reports, folds))
    return out


def format_sweep(results: Sequence[SettingResult]) -> str:
    """The sweep as fixed-width text: per scenario a row per setting (the evaluation's headline figures), then
    the leave-one-log-out fold table (:func:`~factorloc.evaluation.folds.format_folds`) of every setting."""
    lines: list[str] = []
    scen_names = list(results[0].scenarios) if results else []
    if scen_names:
        head = (
            f"{'setting':32s} {'scenario':16s} {'pos rmse cm':>11s} {'head rmse°':>10s} {'NEES':>6s} "
            f"{'c.w.':>6s} {'determined':>10s} {'failed':>6s}"
        )
        lines += [head, "-" * len(head)]
        for r in results:
            for name, rep in r.scenarios.items():
                s = rep.summary()
                o = s.overall
                lines.append(
                    f"{r.setting.name:32s} {name:16s} {100 * o.position_rmse_m:11.2f} {o.heading_rmse_deg:10.3f} "
                    f"{o.nees_mean:6.2f} {100 * o.confidently_wrong_rate:5.1f}% {100 * o.determined_rate:9.1f}% "
                    f"{s.failed_queries:6d}"
                )
    reports = [r.folds for r in results if r.folds is not None]
    if reports:
        if lines:
            lines.append("")
        lines.append(format_folds(reports))
        best = min(reports, key=lambda f: f.worst_shortfall)
        lines.append(f"best on its worst held-out log: {best.candidate} (shortfall {best.worst_shortfall:.3f})")
    return "\n".join(lines)

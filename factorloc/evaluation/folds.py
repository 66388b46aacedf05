"""Leave-one-log-out evaluation of the ICP step on the relations benchmark (Kümmerle et al., 2009).

A *candidate* is a setting of the library (a :class:`~factorloc.config.Config`), optionally with a ``fit``
that adjusts it from results on other logs (e.g. a σ inflation). For every log of a set, the *fold* holding it
out fits the candidate on the other logs (runs the candidate's config on them, calls ``fit``) and reports the
fitted setting on the held-out log: the figures of :class:`FoldFigures`. A candidate without ``fit`` is the
same setting in every fold, and its fold figures are its figures on each log.

:func:`relations_folds` runs the candidates, :func:`best_on_worst_fold` picks the one whose worst held-out
fold is best (the house rule for defaults), :func:`format_folds` renders the table.

Example
-------
>>> from factorloc.evaluation.folds import Candidate, load_laser_datasets, relations_folds   # doctest: +SKIP
>>> data = load_laser_datasets("../shared/data/laser", every=10)                            # doctest: +SKIP
>>> report = relations_folds(data, [Candidate("default", relations_config())])[0]            # doctest: +SKIP
>>> print(format_folds([report]))                                                            # doctest: +SKIP
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from pathlib import Path

import numpy as np

from factorloc.config import Config
from factorloc.datasets.rosbag import LaserLog, read_laser_log
from factorloc.errors import InputError
from factorloc.evaluation.relations import (
    METHODS,
    RelationResult,
    Relations,
    read_relations,
    relations_benchmark,
    relations_config,
)
from factorloc.parallel import Executor

__all__ = [
    "LOGS",
    "SHORTFALL_WEIGHTS",
    "TARGETS",
    "Candidate",
    "FoldFigures",
    "FoldReport",
    "LaserDataset",
    "EmulatedLaser",
    "best_on_worst_fold",
    "emulated",
    "fold_figures",
    "format_folds",
    "load_laser_datasets",
    "relations_folds",
]

#: The laser logs of ``../shared/data/laser`` (file stems).
LOGS = ("intel", "aces", "mit-csail")

#: The issue's targets on every held-out fold: (figure, comparison, limit).
TARGETS: tuple[tuple[str, str, float], ...] = (
    ("confidently_wrong_local", "<", 0.01),
    ("confidently_wrong_loop", "<", 0.01),
    ("confidently_wrong_all", "<", 0.01),
    ("local_error_ratio_open3d", "<=", 0.8),
    ("local_error_ratio_odometry", "<=", 1.0),
    ("loops_recovered", ">=", 0.6),
    ("icp_nees_position_low", ">=", 1.5),
    ("icp_nees_position_high", "<=", 3.0),
    ("time_ratio_open3d", "<=", 1.0),
)


#: Weights of the targets in :meth:`FoldFigures.shortfall` (1 unless listed). A confidently wrong result costs
#: twice a cautious one: the step must above all not be wrong while claiming to be right. The time is reported
#: but does not choose between settings: it is a property of the code (all settings of a run share it), and on a
#: shared machine its noise would decide between settings of equal cost.
SHORTFALL_WEIGHTS: dict[str, float] = {
    "confidently_wrong_local": 2.0,
    "confidently_wrong_loop": 2.0,
    "confidently_wrong_all": 2.0,
    "time_ratio_open3d": 0.0,
}


@dataclass(frozen=True, eq=False)
class LaserDataset:
    """One laser log and its ground-truth relations (``name``: the file stem, e.g. ``"intel"``)."""

    name: str
    log: LaserLog
    relations: Relations


def load_laser_datasets(
    directory: str | Path, names: Sequence[str] = LOGS, *, every: int = 1, offset: int = 0
) -> list[LaserDataset]:
    """Read ``<name>.sort.bag`` and ``<name>.relations`` of each log in ``directory`` (every ``every``-th relation
    from ``offset``: a fixed, reproducible subset)."""
    d = Path(directory)
    return [
        LaserDataset(n, read_laser_log(d / f"{n}.sort.bag"), read_relations(d / f"{n}.relations").subset(every, offset))
        for n in names
    ]


@dataclass(frozen=True)
class EmulatedLaser:
    """A laser the logs were not taken with, emulated from their scans (a check of what generalizes; the held-out
    logs of issue #14 are other buildings *and* other lasers).

    ``range_noise_m``: extra Gaussian range noise (1σ, m) per beam, along its ray. ``max_range_m``: returns at or
    beyond it dropped (a shorter-range scanner: a Hokuyo URG-04LX reaches 5.6 m). ``fov_rad``: only the beams
    within half of it of the scanner's forward axis kept. ``every_beam``: every n-th return kept (a coarser
    angular resolution). ``seed``: the noise's generator. The default changes nothing.
    """

    range_noise_m: float = 0.0
    max_range_m: float = math.inf
    fov_rad: float = 2.0 * math.pi
    every_beam: int = 1
    seed: int = 0

    def __post_init__(self) -> None:
        if not (math.isfinite(self.range_noise_m) and self.range_noise_m >= 0.0):
            raise InputError(f"EmulatedLaser.range_noise_m must be a finite number >= 0, got {self.range_noise_m!r}")
        if not self.max_range_m > 0.0:
            raise InputError(f"EmulatedLaser.max_range_m must be > 0, got {self.max_range_m!r}")
        if not (math.isfinite(self.fov_rad) and 0.0 < self.fov_rad <= 2.0 * math.pi):
            raise InputError(f"EmulatedLaser.fov_rad must be in (0, 2π], got {self.fov_rad!r}")
        if isinstance(self.every_beam, bool) or not isinstance(self.every_beam, int) or self.every_beam < 1:
            raise InputError(f"EmulatedLaser.every_beam must be an int >= 1, got {self.every_beam!r}")

    def scan(self, points_m: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """One scan's points (N×2, robot frame, m) as this laser would return them."""
        p = np.asarray(points_m, dtype=np.float64)[:: self.every_beam]
        r = np.hypot(p[:, 0], p[:, 1])
        if self.range_noise_m > 0.0:
            u = p / np.maximum(r, 1e-12)[:, None]
            r = r + rng.normal(0.0, self.range_noise_m, len(r))
            p = u * r[:, None]
        keep = (r > 0.0) & (r < self.max_range_m)
        if self.fov_rad < 2.0 * math.pi:
            keep &= np.abs(np.arctan2(p[:, 1], p[:, 0])) <= 0.5 * self.fov_rad
        return p[keep]


def emulated(dataset: LaserDataset, laser: EmulatedLaser) -> LaserDataset:
    """``dataset`` with every scan as ``laser`` would return it (the odometry and the relations unchanged).

    Raises :class:`~factorloc.errors.InputError` naming the first scan that ``laser`` leaves without a return."""
    from factorloc.datasets.rosbag import ScanTrack
    from factorloc.types import Scan

    rng = np.random.default_rng(laser.seed)
    track = dataset.log.scans
    out = []
    for t, s in zip(track.stamps_s, track.scans, strict=True):
        pts = laser.scan(s.points_m, rng)
        if len(pts) == 0:
            raise InputError(f"{dataset.name}: the scan at t = {float(t):.3f} s has no return left under {laser}")
        out.append(Scan(pts))
    log = replace(dataset.log, scans=ScanTrack(track.stamps_s, tuple(out), track.frame_id))
    return LaserDataset(dataset.name, log, dataset.relations)


Fit = Callable[[Mapping[str, Sequence[RelationResult]], Config], Config]


@dataclass(frozen=True)
class Candidate:
    """A setting to evaluate: its ``config`` and, optionally, ``fit(training results by log, config) -> config``
    which adjusts it from the results of ``config`` on the training logs of a fold."""

    name: str
    config: Config = field(default_factory=relations_config)
    fit: Fit | None = None


@dataclass(frozen=True)
class FoldFigures:
    """The figures of one setting on one (held-out) log.

    Rates are fractions of the subset's relations (``recovered_all``: within 10 cm and 1°, ``flagged_all``:
    unreliable, both over all relations); errors in cm; times in ms (median per pair, both measured in
    the same run: the ICP step's ``prepare`` + ``estimate`` and Open3D point-to-plane's per-pair job).
    ``local_error_ratio_open3d`` is ours over the better of Open3D point-to-point and point-to-plane on the
    local relations, ``local_error_ratio_odometry`` ours over the odometry alone; ``icp_nees_position`` is the
    mean squared Mahalanobis position error (2 dof) of the ICP step's own reliable full-pose estimates.
    Confidently wrong and NEES are judged with the relations' rounding added where they were rounded to a grid
    (``truth_rounded``: their share; :func:`~factorloc.evaluation.relations_lattice.truth_rounding`); the
    ``*_exact`` figures take the relations as exact.
    """

    dataset: str
    setting: str
    n_local: int
    n_loop: int
    confidently_wrong_local: float
    confidently_wrong_loop: float
    confidently_wrong_all: float
    local_error_cm: float
    local_error_open3d_cm: float
    local_error_odometry_cm: float
    loops_recovered: float
    loops_unrecovered_flagged: float
    recovered_all: float
    flagged_all: float
    icp_reliable_local: float
    icp_nees_position: float
    icp_nees_n: int
    ms_median: float
    ms_median_open3d_p2plane: float
    truth_rounded: float = 0.0
    confidently_wrong_all_exact: float = math.nan
    icp_nees_position_exact: float = math.nan

    @property
    def local_error_ratio_open3d(self) -> float:
        return self.local_error_cm / self.local_error_open3d_cm if self.local_error_open3d_cm > 0 else math.nan

    @property
    def local_error_ratio_odometry(self) -> float:
        return self.local_error_cm / self.local_error_odometry_cm if self.local_error_odometry_cm > 0 else math.nan

    @property
    def time_ratio_open3d(self) -> float:
        return self.ms_median / self.ms_median_open3d_p2plane if self.ms_median_open3d_p2plane > 0 else math.nan

    @property
    def icp_nees_position_low(self) -> float:
        return self.icp_nees_position

    @property
    def icp_nees_position_high(self) -> float:
        return self.icp_nees_position

    def misses(self) -> tuple[str, ...]:
        """The :data:`TARGETS` this fold misses (NaN figures miss, except a subset without relations)."""
        out = []
        for name, op, limit in TARGETS:
            v = getattr(self, name)
            if name == "confidently_wrong_loop" and self.n_loop == 0:
                continue
            ok = (v < limit) if op == "<" else (v <= limit) if op == "<=" else (v >= limit)
            if not ok:
                out.append(name)
        return tuple(out)

    def shortfall(self) -> float:
        """How far the fold is from its targets: Σ over missed targets of :data:`SHORTFALL_WEIGHTS` × the relative
        miss capped at 1 (0 when all are met; NaN figures count 1). The objective :func:`best_on_worst_fold`
        minimizes on the worst fold."""
        total = 0.0
        for name, _, limit in TARGETS:
            w = SHORTFALL_WEIGHTS.get(name, 1.0)
            if w == 0.0 or name not in self.misses():
                continue
            v = getattr(self, name)
            total += w * (1.0 if not math.isfinite(v) else min(1.0, abs(v - limit) / max(abs(limit), 1e-9)))
        return total

    def to_dict(self) -> dict[str, object]:
        d: dict[str, object] = asdict(self)
        for name, _, _ in TARGETS:
            d[name] = getattr(self, name)
        d["misses"] = list(self.misses())
        return {k: (None if isinstance(v, float) and not math.isfinite(v) else v) for k, v in d.items()}


def _mean(a: Sequence[float]) -> float:
    return float(np.mean(a)) if len(a) else math.nan


def fold_figures(results: Sequence[RelationResult], dataset: str, setting: str) -> FoldFigures:
    """The :class:`FoldFigures` of one run of :func:`~factorloc.evaluation.relations.relations_benchmark` (with
    the methods ``ours``, ``ours_icp``, ``odometry``, ``open3d_p2p``, ``open3d_p2plane``)."""

    def of(method: str, kind: str | None = None) -> list[RelationResult]:
        return [r for r in results if r.method == method and (kind is None or r.kind == kind)]

    ours, ours_local, ours_loop = of("ours"), of("ours", "local"), of("ours", "loop")
    if not ours:
        raise InputError("fold_figures needs the 'ours' method's results")

    def local_cm(method: str) -> float:
        return 100.0 * _mean([r.error_translation_m for r in of(method, "local")])

    open3d = [local_cm(m) for m in ("open3d_p2p", "open3d_p2plane") if of(m, "local")]
    recovered = [r.error_translation_m < 0.1 and r.error_rotation_deg < 1.0 for r in ours_loop]
    unrec = [not r.reliable for r, ok in zip(ours_loop, recovered, strict=True) if not ok]
    icp_local = of("ours_icp", "local")
    nees = [r.nees_position for r in of("ours_icp") if r.reliable and math.isfinite(r.nees_position)]
    peer = of("open3d_p2plane")
    nees_exact = [
        r.diagnostics.get("icp_nees_position_exact", r.nees_position)
        for r in of("ours_icp")
        if r.reliable and math.isfinite(r.nees_position)
    ]
    return FoldFigures(
        dataset=dataset,
        setting=setting,
        n_local=len(ours_local),
        n_loop=len(ours_loop),
        confidently_wrong_local=_mean([r.confidently_wrong for r in ours_local]),
        confidently_wrong_loop=_mean([r.confidently_wrong for r in ours_loop]),
        confidently_wrong_all=_mean([r.confidently_wrong for r in ours]),
        local_error_cm=local_cm("ours"),
        local_error_open3d_cm=min(open3d) if open3d else math.nan,
        local_error_odometry_cm=local_cm("odometry") if of("odometry", "local") else math.nan,
        loops_recovered=_mean(recovered),
        loops_unrecovered_flagged=_mean(unrec) if unrec else 1.0,
        recovered_all=_mean([r.error_translation_m < 0.1 and r.error_rotation_deg < 1.0 for r in ours]),
        flagged_all=_mean([not r.reliable for r in ours]),
        icp_reliable_local=_mean([r.reliable for r in icp_local]),
        icp_nees_position=_mean(nees),
        icp_nees_n=len(nees),
        ms_median=1000.0 * float(np.median([r.seconds for r in ours])),
        ms_median_open3d_p2plane=1000.0 * float(np.median([r.seconds for r in peer])) if peer else math.nan,
        truth_rounded=_mean([bool(r.diagnostics.get("truth_rounded", False)) for r in ours]),
        confidently_wrong_all_exact=_mean(
            [bool(r.diagnostics.get("confidently_wrong_exact", r.confidently_wrong)) for r in ours]
        ),
        icp_nees_position_exact=_mean(nees_exact),
    )


@dataclass(frozen=True)
class FoldReport:
    """One candidate over the folds: ``folds[i]`` are its figures on the log held out by fold ``i`` (fitted on
    the others when the candidate has a ``fit``), ``configs[i]`` the setting used there."""

    candidate: str
    folds: tuple[FoldFigures, ...]
    configs: tuple[Config, ...]

    @property
    def worst_shortfall(self) -> float:
        return max(f.shortfall() for f in self.folds)

    def to_json(self) -> str:
        return json.dumps(
            {"candidate": self.candidate, "folds": [f.to_dict() for f in self.folds], "worst_shortfall": self.worst_shortfall},
            indent=1,
        )


def relations_folds(
    datasets: Sequence[LaserDataset],
    candidates: Sequence[Candidate],
    *,
    methods: Sequence[str] = METHODS,
    progress: Callable[[str], None] | None = None,
    executor: Executor | None = None,
    batch_progress: Callable[[str, int, int], None] | None = None,
) -> list[FoldReport]:
    """Every candidate on every leave-one-log-out fold of ``datasets`` (at least two logs).

    A candidate without ``fit`` runs once per log; one with ``fit`` also runs its fitted setting on each
    held-out log. ``progress`` is called with a line of text after each run (the library does not print),
    ``batch_progress(log, done, total)`` as the relations of a run finish. ``executor`` is where the relations
    run (:func:`~factorloc.evaluation.relations.relations_benchmark`; default in process).
    """

    def bench(d: LaserDataset, config: Config) -> list[RelationResult]:
        cb = None if batch_progress is None else (lambda done, total: batch_progress(d.name, done, total))
        return relations_benchmark(d.log, d.relations, methods=methods, config=config, executor=executor, progress=cb)

    if len(datasets) < 2:
        raise InputError(f"relations_folds needs at least two logs, got {len(datasets)}")
    names = [d.name for d in datasets]
    if len(set(names)) != len(names):
        raise InputError(f"relations_folds needs distinct log names, got {names}")
    out = []
    for cand in candidates:
        base = {d.name: bench(d, cand.config) for d in datasets}
        if progress is not None:
            progress(f"{cand.name}: ran on {', '.join(names)}")
        folds, configs = [], []
        for held in datasets:
            if cand.fit is None:
                cfg, res = cand.config, base[held.name]
            else:
                cfg = cand.fit({n: r for n, r in base.items() if n != held.name}, cand.config)
                res = bench(held, cfg)
                if progress is not None:
                    progress(f"{cand.name}: fitted without {held.name}, ran on it")
            folds.append(fold_figures(res, held.name, cand.name))
            configs.append(cfg)
        out.append(FoldReport(cand.name, tuple(folds), tuple(configs)))
    return out


def best_on_worst_fold(reports: Sequence[FoldReport]) -> FoldReport:
    """The candidate whose worst held-out fold has the smallest :meth:`FoldFigures.shortfall` (ties: the first)."""
    if not reports:
        raise InputError("best_on_worst_fold needs at least one report")
    return min(reports, key=lambda r: r.worst_shortfall)


def format_folds(reports: Sequence[FoldReport]) -> str:
    """A fixed-width table: one row per (candidate, held-out log), the targets missed marked ``*``."""
    w = max([18, *(len(r.candidate) for r in reports)])
    head = (
        f"{'setting':{w}s} {'held out':10s} {'c.w. local':>10s} {'loop':>6s} {'all':>6s} {'local cm':>8s} "
        f"{'/o3d':>5s} {'/odo':>5s} {'loops rec':>9s} {'flagged':>7s} {'ICP NEES':>8s} {'ms':>7s} {'/o3d':>6s} "
        f"{'rounded':>7s} {'exact: c.w.':>11s} {'NEES':>5s}"
    )
    lines = [head, "-" * len(head)]
    for rep in reports:
        for f in rep.folds:
            miss = set(f.misses())

            def m(name: str, text: str, width: int, miss: set[str] = miss) -> str:
                flag = (
                    "*"
                    if name in miss
                    or (name == "icp_nees_position" and miss & {"icp_nees_position_low", "icp_nees_position_high"})
                    else " "
                )
                return f"{text:>{width}s}{flag}"

            lines.append(
                f"{rep.candidate:{w}s} {f.dataset:10s} "
                f"{m('confidently_wrong_local', f'{100 * f.confidently_wrong_local:.2f}%', 9)}"
                f"{m('confidently_wrong_loop', f'{100 * f.confidently_wrong_loop:.2f}%', 6)}"
                f"{m('confidently_wrong_all', f'{100 * f.confidently_wrong_all:.2f}%', 6)}"
                f" {f.local_error_cm:7.2f} "
                f"{m('local_error_ratio_open3d', f'{f.local_error_ratio_open3d:.2f}', 4)}"
                f"{m('local_error_ratio_odometry', f'{f.local_error_ratio_odometry:.2f}', 4)}"
                f"{m('loops_recovered', f'{100 * f.loops_recovered:.1f}%', 8)}"
                f" {100 * f.loops_unrecovered_flagged:6.1f}%"
                f"{m('icp_nees_position', f'{f.icp_nees_position:.2f}', 8)}"
                f" {f.ms_median:7.2f}"
                f"{m('time_ratio_open3d', f'{f.time_ratio_open3d:.2f}', 6)}"
                f" {100 * f.truth_rounded:6.1f}% {100 * f.confidently_wrong_all_exact:10.2f}% {f.icp_nees_position_exact:5.2f}"
            )
    lines.append(
        "(* = target missed: c.w. < 1 %, local error ≤ 0.8× Open3D and ≤ odometry, loops ≥ 60 %, NEES in [1.5, 3], "
        "time ≤ Open3D;\n"
        " c.w. and NEES judged with the relations' rounding added where they are on a grid ('rounded'; 'exact': without it))"
    )
    return "\n".join(lines)

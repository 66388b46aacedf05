"""Several places, one answer: the hierarchy against each candidate place, their estimates fused on one pose.

For a query and a list of candidate places, :class:`MultiPlaceLocalizer` runs the hierarchy
(:class:`~factorloc.pipeline.Localizer`, one per place, reference work cached) against each place. What each run
fused, apart from the odometry (which belongs to the query, not to a place: it enters once), becomes a
world-frame factor named ``<step>@<place id>``:

* the hierarchy answers in the world frame already (the place's reference carries its pose ``T_world_reference``);
* a place whose pose is uncertain (:attr:`~factorloc.places.Place.covariance` Σ_wr) adds that uncertainty,
  moved to the query by the Jacobian of the composition ``T_world_query = T_world_reference ∘ T_reference_query``
  with respect to the place's pose: ``Σ += F Σ_wr Fᵀ`` with ``F = [[1, 0, -Δy], [0, 1, Δx], [0, 0, 1]]``, Δ the
  query's offset from the place in the world frame (the first-order propagation of
  :func:`~factorloc.fusion.sequential.compose_with_covariance`; the adjoint of SE(2) written in the world frame).

All factors (the odometry once, then the places nearest first) go through the library's gate and fusion
(:func:`factorloc.pipeline.fuse`): the consistency gate drops the estimates of a place that disagrees with the
others (``gate.consistency.*``, its reason in the step report), the fusion strategy gives the pose and covariance.
The result (:class:`PlaceLocalization`) says which places were used and why the others were not.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from factorloc.config import Config
from factorloc.errors import InputError
from factorloc.fusion.base import FusionStrategy
from factorloc.gating.consistency import WHOLE_POSE, consistency_code
from factorloc.geometry import Pose2
from factorloc.pipeline import Localizer, fuse, strategy_for
from factorloc.places.placemap import Place, PlaceMap
from factorloc.types import HEADING, POSITION, Component, Estimate, Localization, Query, StepReport, StepStatus
from factorloc.verdicts import render_checks

__all__ = ["MultiPlaceLocalizer", "PlaceLocalization", "PlaceRun", "place_factor", "split_step_name"]

#: The separator of a place factor's step name: ``"icp@p012"``.
SEPARATOR = "@"


def split_step_name(name: str) -> tuple[str, str | None]:
    """``"icp@p012"`` → ``("icp", "p012")``; a name without a place (the odometry) → ``(name, None)``."""
    step, sep, place = name.partition(SEPARATOR)
    return (step, place) if sep else (name, None)


def _accepted_part(report: StepReport) -> Estimate | None:
    """The part of a fused report's estimate its run's consistency gate accepted."""
    est = report.estimate
    if est is None or report.status is not StepStatus.FUSED:
        return None
    dropped: set[Component] = set()
    for c in report.checks:
        if c.passed:
            continue
        if c.code == consistency_code("position"):
            dropped |= set(POSITION)
        elif c.code in (consistency_code("heading"), WHOLE_POSE):
            dropped |= set(HEADING)
    keep = [c for c in est.components if c not in dropped]
    if not keep:
        return None
    return est if len(keep) == len(est.components) else est.marginal(keep)


def place_factor(estimate: Estimate, place: Place, T_world_query: Pose2) -> Estimate:
    """``estimate`` (world frame, from the hierarchy against ``place``) as a factor named ``<step>@<place id>``,
    with the place's pose covariance added (see the module docstring); ``T_world_query`` is where the query is."""
    cov = np.array(estimate.covariance, dtype=np.float64)
    if place.covariance is not None:
        dx, dy = T_world_query.x - place.T_world_reference.x, T_world_query.y - place.T_world_reference.y
        F = np.array([[1.0, 0.0, -dy], [0.0, 1.0, dx], [0.0, 0.0, 1.0]])
        added = F @ place.covariance @ F.T
        idx = [{Component.X: 0, Component.Y: 1, Component.THETA: 2}[c] for c in estimate.components]
        cov = cov + added[np.ix_(idx, idx)]
        cov = 0.5 * (cov + cov.T)
    return Estimate(
        f"{estimate.step}{SEPARATOR}{place.id}",
        estimate.components,
        estimate.values,
        cov,
        diagnostics={"place": place.id, "step": estimate.step},
    )


@dataclass(frozen=True, eq=False)
class PlaceRun:
    """The hierarchy against one place: its :class:`~factorloc.Localization` and the factors it gave."""

    place_id: str
    localization: Localization
    factors: tuple[Estimate, ...]


@dataclass(frozen=True, eq=False)
class PlaceLocalization:
    """One query localized against several places.

    Parameters
    ----------
    localization
        The fused answer (world frame): one step report per factor — ``"odometry"`` and ``"<step>@<place>"`` —
        with the consistency gate's verdict on it.
    places_used
        The places at least one of whose factors was fused, in the order tried.
    places_dropped
        ``(place id, reason)`` for every other place tried: no reliable estimate against it, or its estimates
        rejected by the consistency gate (the rendered checks).
    runs
        The hierarchy's result against each place tried.
    """

    localization: Localization
    places_used: tuple[str, ...]
    places_dropped: tuple[tuple[str, str], ...]
    runs: tuple[PlaceRun, ...]

    @property
    def pose(self) -> Pose2:
        return self.localization.pose

    @property
    def covariance(self) -> np.ndarray:
        return self.localization.covariance

    def to_dict(self) -> dict[str, Any]:
        return {
            **self.localization.to_dict(),
            "places_used": list(self.places_used),
            "places_dropped": [{"place": p, "reason": r} for p, r in self.places_dropped],
        }


class MultiPlaceLocalizer:
    """Localizes queries against several places of a :class:`PlaceMap` at once (see the module docstring).

    One :class:`~factorloc.pipeline.Localizer` per place is built on first use and kept, so the reference work
    (KD-trees, keypoints) is done once per place; :meth:`sharing` gives a second configuration on the same work.
    """

    def __init__(self, place_map: PlaceMap, config: Config | None = None, *, strategy: FusionStrategy | None = None) -> None:
        if not isinstance(place_map, PlaceMap):
            raise InputError(f"MultiPlaceLocalizer needs a PlaceMap, got {type(place_map).__name__}")
        self.place_map = place_map
        self.config = config or Config()
        self.strategy = strategy or strategy_for(self.config)
        self._localizers: dict[str, Localizer] = {}
        self._prepared_by: MultiPlaceLocalizer | None = None

    def sharing(self, config: Config) -> MultiPlaceLocalizer:
        """The places with ``config``, on this localizer's prepared references (:meth:`Localizer.with_config`: for a
        ``config`` that differs only in what the steps read when they estimate)."""
        other = MultiPlaceLocalizer(self.place_map, config)
        other._prepared_by = self
        return other

    def localizer(self, place_id: str) -> Localizer:
        """The (cached) hierarchy against one place."""
        if place_id not in self._localizers:
            if self._prepared_by is not None:
                self._localizers[place_id] = self._prepared_by.localizer(place_id).with_config(self.config)
            else:
                self._localizers[place_id] = Localizer(self.place_map[place_id].reference, self.config, strategy=self.strategy)
        return self._localizers[place_id]

    def run_place(self, query: Query, place_id: str) -> PlaceRun:
        """The hierarchy against one place and the place factors it gives (odometry left out)."""
        loc = self.localizer(place_id).localize(query)
        place = self.place_map[place_id]
        factors = []
        for report in loc.steps:
            if report.name == "odometry":
                continue
            part = _accepted_part(report)
            if part is not None:
                factors.append(place_factor(part, place, loc.pose))
        return PlaceRun(place_id, loc, tuple(factors))

    def localize(self, query: Query, place_ids: Sequence[str], *, use_odometry: bool = True) -> PlaceLocalization:
        """Localize ``query`` against the places ``place_ids`` (tried in that order, nearest first by convention).

        ``use_odometry``: whether the query's odometry estimate is one of the factors (the tracker, which holds
        the odometry as between factors, passes False).
        """
        if not isinstance(query, Query):
            raise InputError(f"query must be a factorloc.Query, got {type(query).__name__}")
        ids = list(dict.fromkeys(place_ids))
        if not ids:
            raise InputError("localize needs at least one place id")
        runs = [self.run_place(query, pid) for pid in ids]
        factors: list[Estimate] = []
        if use_odometry:
            odo = next((r for r in runs[0].localization.steps if r.name == "odometry"), None)
            part = None if odo is None else _accepted_part(odo)
            if part is None and odo is not None and odo.estimate is not None and odo.estimate.reliable:
                part = odo.estimate  # rejected against one place, it may agree with the others: the joint gate decides
            if part is not None:
                factors.append(part)
        for run in runs:
            factors.extend(run.factors)
        if not factors:
            seed = query.odometry.T_world_robot if query.odometry is not None else Pose2()
            loc = Localization(
                seed, np.diag([math.inf] * 3), (), self.strategy.name, (Component.X, Component.Y, Component.THETA), self.config
            )
            return PlaceLocalization(
                loc, (), tuple((r.place_id, "no reliable estimate against this place") for r in runs), tuple(runs)
            )
        loc = fuse(factors, self.strategy, self.config.gating)
        loc = Localization(loc.pose, loc.covariance, loc.steps, loc.fused_with, loc.undetermined, self.config, loc.checks)
        used, dropped = [], []
        for run in runs:
            reports = [r for r in loc.steps if split_step_name(r.name)[1] == run.place_id]
            if any(r.status is StepStatus.FUSED for r in reports):
                used.append(run.place_id)
            elif not reports:
                dropped.append((run.place_id, "no reliable estimate against this place"))
            else:
                dropped.append((run.place_id, "; ".join(render_checks(r.checks) or r.reason for r in reports)))
        return PlaceLocalization(loc, tuple(used), tuple(dropped), tuple(runs))

"""The hierarchy: run the steps in the patent's order, gate, fuse.

:func:`localize` runs odometry → compass → correlation → ICP. Each step gets
the *reliable* estimates of the steps before it as hypotheses (seeds), a
step whose inputs are absent is skipped, every step is timed. Then the
seed audit drops a seed that a later step's data contradict (a kidnapped
robot's odometry), the consistency gate drops the parts of reliable estimates that disagree with
the others, and a fusion strategy (GTSAM graph by default) returns the
maximum-likelihood pose and its world-frame covariance.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np

from factorloc.config import Config
from factorloc.errors import FactorlocError, InputError, UnusableInputError
from factorloc.estimators.base import Hypotheses, Step
from factorloc.estimators.compass import CompassStep
from factorloc.estimators.correlation import CorrelationStep
from factorloc.estimators.icp import IcpStep
from factorloc.estimators.odometry import OdometryStep
from factorloc.fusion.base import FusionStrategy, mark_undetermined
from factorloc.fusion.graph import GraphFusion
from factorloc.fusion.product import ProductFusion
from factorloc.gating import Gated, GatingConfig, StepRun, gate, position_determined
from factorloc.geometry import Pose2
from factorloc.types import FULL, POSITION, Component, Estimate, Localization, Query, Reference
from factorloc.verdicts import Check

log = logging.getLogger(__name__)


#: The patent's hierarchy, cheapest first: the field of :class:`~factorloc.Config` that holds each step's
#: sub-config, and the step class built from it (``StepClass(sub_config)``). A new estimator is one module,
#: one field of the config and one entry here.
STEPS: tuple[tuple[str, Callable[[Any], Step]], ...] = (
    ("odometry", OdometryStep),
    ("compass", CompassStep),
    ("correlation", CorrelationStep),
    ("icp", IcpStep),
)


def default_steps(config: Config, registry: Sequence[tuple[str, Callable[[Any], Step]]] = STEPS) -> list[Step]:
    """The steps of ``registry`` (default :data:`STEPS`), built from ``config``'s sub-configs, disabled ones left out.

    Every step sub-config has an ``enabled`` field; ``False`` leaves its step out.
    """
    steps = []
    for field_name, make in registry:
        sub = getattr(config, field_name)
        if sub.enabled:
            steps.append(make(sub))
    return steps


def strategy_for(config: Config) -> FusionStrategy:
    """The fusion strategy named in ``config.fusion.strategy``."""
    return GraphFusion() if config.fusion.strategy == "graph" else ProductFusion()


class Localizer:
    """Localizes queries against one reference; reference-only work is done once.

    Parameters
    ----------
    reference
        The place the robot knows (panorama, scan/cloud, pose).
    config
        The root configuration (defaults if None).
    steps
        The steps to run, in order (default: :func:`default_steps`).
    strategy
        The fusion strategy object (default: from ``config.fusion``).
    """

    def __init__(
        self,
        reference: Reference,
        config: Config | None = None,
        *,
        steps: Sequence[Step] | None = None,
        strategy: FusionStrategy | None = None,
    ) -> None:
        if not isinstance(reference, Reference):
            raise InputError(f"reference must be a factorloc.Reference, got {type(reference).__name__}")
        if config is not None and not isinstance(config, Config):
            raise InputError(f"config must be a factorloc.Config or None, got {type(config).__name__}")
        self.reference = reference
        self.config = config or Config()
        self.steps = list(default_steps(self.config) if steps is None else steps)
        for s in self.steps:
            if not isinstance(s, Step):
                raise InputError(f"step {s!r} does not implement the Step protocol (name, prepare, estimate)")
        self.strategy = strategy or strategy_for(self.config)
        self.prepare_seconds: dict[str, float] = {}
        self._prepared: dict[str, Any] = {}
        for s in self.steps:
            t0 = time.perf_counter()
            self._prepared[s.name] = s.prepare(reference)
            self.prepare_seconds[s.name] = time.perf_counter() - t0

    def with_config(self, config: Config) -> Localizer:
        """A Localizer on the same reference with ``config``'s default steps, sharing this one's prepared references.

        For a ``config`` that differs only in what the steps read when they estimate (e.g.
        ``icp.global_init.widen``), not in how they prepare a reference: the caller vouches for that. The steps
        must be the same ones by name (:class:`~factorloc.errors.InputError` otherwise).
        """
        if not isinstance(config, Config):
            raise InputError(f"config must be a factorloc.Config, got {type(config).__name__}")
        steps = default_steps(config)
        if [s.name for s in steps] != [s.name for s in self.steps]:
            raise InputError(
                f"with_config needs the same steps: {[s.name for s in steps]} against {[s.name for s in self.steps]}"
            )
        other = object.__new__(Localizer)
        other.reference, other.config, other.steps, other.strategy = self.reference, config, steps, strategy_for(config)
        other.prepare_seconds, other._prepared = self.prepare_seconds, self._prepared
        return other

    def localize(self, query: Query, *, seeded: bool = True) -> Localization:
        """Run the hierarchy on ``query``.

        With ``seeded=False`` every step runs blind (no hypotheses from the
        earlier ones): the ablation of the patent's central claim.
        """
        if not isinstance(query, Query):
            raise InputError(f"query must be a factorloc.Query, got {type(query).__name__}")
        hypotheses = Hypotheses()
        runs: list[StepRun] = []
        for step in self.steps:
            t0 = time.perf_counter()
            est, failure, unusable = None, "", ""
            try:
                est = step.estimate(self._prepared[step.name], query, hypotheses if seeded else Hypotheses())
            except UnusableInputError as exc:
                unusable = str(exc)
            except FactorlocError as exc:
                failure = f"{type(exc).__name__}: {exc}"
                log.warning("step %s failed on query %r: %s", step.name, query.id, failure)
            runs.append(StepRun(step.name, est, time.perf_counter() - t0, failure, unusable))
            if est is not None:
                hypotheses = hypotheses.plus(est)  # an unreliable estimate is kept as a weak prior only
        return fuse_gated(gate(runs, self.config.gating), self.strategy, config=self.config, query=query)


def fuse_gated(
    gated: Gated,
    strategy: FusionStrategy,
    *,
    gating: GatingConfig | None = None,
    config: Config | None = None,
    query: Query | None = None,
) -> Localization:
    """Fuse what the gate accepted (``gated.accepted``) with ``strategy``: the :class:`Localization` of one query.

    Nothing accepted: the pose is the query's odometry (or the origin) with every component undetermined.
    A fused position that fails :func:`~factorloc.gating.position_determined` (only estimates "unknown" along
    some direction measured it: one wall, no seed) is reported undetermined whatever its value across the wall.
    ``gating`` defaults to ``config.gating``; ``config`` is kept in the result.
    """
    gating = gating or (config.gating if config is not None else GatingConfig())
    if not gated.accepted:
        seed = query.odometry.T_world_robot if query is not None and query.odometry is not None else Pose2()
        return Localization(seed, np.diag([math.inf] * 3), gated.reports, strategy.name, FULL, config)
    fused = strategy.fuse(gated.accepted)
    undetermined, cov = fused.undetermined, np.array(fused.covariance, dtype=np.float64)
    checks: tuple[Check, ...] = ()
    if Component.X not in undetermined:
        determined = position_determined(cov, gating.undetermined_sigma_m)
        checks = (determined,)
        if not determined.passed:
            undetermined = tuple(c for c in FULL if c in undetermined or c in POSITION)
            cov = mark_undetermined(cov, POSITION)
    return Localization(fused.pose, cov, gated.reports, strategy.name, undetermined, config, checks)


def localize(
    reference: Reference,
    query: Query,
    config: Config | None = None,
    *,
    strategy: FusionStrategy | None = None,
    steps: Sequence[Step] | None = None,
) -> Localization:
    """Localize ``query`` against ``reference`` with the patent's hierarchy.

    Parameters
    ----------
    reference
        What the robot knows: a place's panorama, scan or cloud and its pose (:class:`~factorloc.types.Reference`).
    query
        What the robot senses now: images, scan or cloud, odometry (:class:`~factorloc.types.Query`).
    config
        Thresholds, seeds and the fusion strategy (defaults if None); kept in the result.
    strategy
        A fusion strategy object overriding ``config.fusion`` (e.g. ``ProductFusion()``).
    steps
        Override the steps (default: odometry → compass → correlation → ICP).

    Returns
    -------
    Localization
        The ML pose (world frame), its 3×3 world-frame covariance (x, y, θ),
        one report per step, and :meth:`~factorloc.types.Localization.certainty`.

    Notes
    -----
    A one-shot call prepares the reference inside (each step's
    :meth:`~factorloc.estimators.base.Step.prepare`: the compass's SIFT
    keypoints of the whole panorama and its depth maps, the correlation's pyramid, the ICP's KD-tree), which
    costs many times one query's estimation (figures: ``docs/calibration/vision.md``, "Time";
    :attr:`Localizer.prepare_seconds` holds them per step). To localize many queries against one reference,
    build a :class:`Localizer` once: the reference-only work is then done once and cached.
    """
    return Localizer(reference, config, steps=steps, strategy=strategy).localize(query)


def fuse(
    estimates: Sequence[Estimate],
    strategy: FusionStrategy | None = None,
    gating: GatingConfig | None = None,
) -> Localization:
    """Gate and fuse ready-made estimates (no estimators run).

    Unreliable estimates are reported and left out; reliable ones pass the
    consistency gate of ``gating``; the rest are fused by ``strategy``
    (default :class:`~factorloc.fusion.graph.GraphFusion`). One step report
    per estimate, in the order given, with ``seconds = 0``.
    """
    ests = list(estimates)
    for i, e in enumerate(ests):
        if not isinstance(e, Estimate):
            raise InputError(f"estimates[{i}] must be a factorloc.Estimate, got {type(e).__name__}")
    strategy = strategy or GraphFusion()
    cfg = gating or GatingConfig()
    return fuse_gated(gate([StepRun(e.step, e) for e in ests], cfg), strategy, gating=cfg)

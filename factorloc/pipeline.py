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
from collections.abc import Sequence
from typing import Any

import numpy as np

from factorloc.config import Config, GatingConfig
from factorloc.errors import FactorlocError, InputError
from factorloc.estimators.base import Hypotheses, Step
from factorloc.estimators.compass import CompassStep
from factorloc.estimators.correlation import CorrelationStep
from factorloc.estimators.icp import UNCONSTRAINED_SIGMA_M, IcpStep
from factorloc.estimators.odometry import OdometryStep
from factorloc.fusion.base import FusionStrategy
from factorloc.fusion.graph import GraphFusion
from factorloc.fusion.product import ProductFusion
from factorloc.gating import consistency_gate, seed_audit, unconstrained_position
from factorloc.geometry import Pose2
from factorloc.types import FULL, Component, Estimate, Localization, Query, Reference, StepReport, StepStatus

log = logging.getLogger(__name__)


def default_steps(config: Config) -> list[Step]:
    """The patent's hierarchy, cheapest first, built from ``config`` (disabled steps left out)."""
    steps: list[tuple[bool, Step]] = [
        (config.odometry.enabled, OdometryStep(config.odometry)),
        (config.compass.enabled, CompassStep(config.compass)),
        (config.correlation.enabled, CorrelationStep(config.correlation)),
        (config.icp.enabled, IcpStep(config.icp)),
    ]
    return [step for enabled, step in steps if enabled]


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

    def localize(self, query: Query, *, seeded: bool = True) -> Localization:
        """Run the hierarchy on ``query``.

        With ``seeded=False`` every step runs blind (no hypotheses from the
        earlier ones): the ablation of the patent's central claim.
        """
        if not isinstance(query, Query):
            raise InputError(f"query must be a factorloc.Query, got {type(query).__name__}")
        hypotheses = Hypotheses()
        produced: list[tuple[Step, Estimate | None, str, float, bool]] = []
        for step in self.steps:
            t0 = time.perf_counter()
            failure = ""
            try:
                est = step.estimate(self._prepared[step.name], query, hypotheses if seeded else Hypotheses())
            except FactorlocError as exc:
                est, failure = None, f"{type(exc).__name__}: {exc}"
                log.warning("step %s failed on query %r: %s", step.name, query.id, failure)
            dt = time.perf_counter() - t0
            produced.append((step, est, failure, dt, bool(failure)))
            if est is not None and est.reliable:
                hypotheses = hypotheses.plus(est)
        reports, fused_inputs = _gate(produced, self.config.gating)
        return _result(fused_inputs, reports, self.strategy, self.config, query)


def _gate(
    produced: list[tuple[Step, Estimate | None, str, float, bool]], gating: GatingConfig
) -> tuple[list[StepReport], list[Estimate]]:
    ran = [est for _, est, _, _, _ in produced if est is not None]
    contradicted = {id(ran[i]): why for i, why in seed_audit(ran).items()} if gating.seed_audit else {}
    reliable = [est for est in ran if est.reliable and id(est) not in contradicted]
    verdicts = consistency_gate(reliable, gating.consistency_probability) if gating.consistency else []
    verdict_of = {id(v.estimate): v for v in verdicts}
    reports: list[StepReport] = []
    fused_inputs: list[Estimate] = []
    for step, est, failure, dt, failed in produced:
        if failed:
            reports.append(StepReport(step.name, StepStatus.FAILED, None, failure, dt))
        elif est is None:
            reports.append(StepReport(step.name, StepStatus.SKIPPED, None, "inputs absent", dt))
        elif not est.reliable:
            reports.append(StepReport(step.name, StepStatus.UNRELIABLE, est, est.reason or "unreliable", dt))
        elif id(est) in contradicted:
            reports.append(StepReport(step.name, StepStatus.INCONSISTENT, est, contradicted[id(est)], dt))
        else:
            verdict = verdict_of.get(id(est))
            part = est if verdict is None else verdict.accepted_estimate()
            if part is None:
                reports.append(StepReport(step.name, StepStatus.INCONSISTENT, est, verdict.reason, dt))
            else:
                fused_inputs.append(part)
                if verdict is None or verdict.fully_accepted:
                    reason = est.reason or verdict_reason(verdict)
                else:
                    reason = f"partly fused: {verdict.reason}"
                reports.append(StepReport(step.name, StepStatus.FUSED, est, reason, dt))
    return reports, fused_inputs


def verdict_reason(verdict: object) -> str:
    """The consistency verdict's reason, for estimates that gave none of their own."""
    return getattr(verdict, "reason", "") if verdict is not None else ""


def _result(
    fused_inputs: list[Estimate], reports: list[StepReport], strategy: FusionStrategy, config: Config | None, query: Query | None
) -> Localization:
    if not fused_inputs:
        seed = query.odometry.T_world_robot if query is not None and query.odometry is not None else Pose2()
        return Localization(seed, np.diag([math.inf] * 3), tuple(reports), strategy.name, FULL, config)
    fused = strategy.fuse(fused_inputs)
    undetermined, cov = fused.undetermined, np.array(fused.covariance, dtype=np.float64)
    if Component.X not in undetermined and unconstrained_position(cov, UNCONSTRAINED_SIGMA_M):
        # only estimates that are "unknown" along some direction measured the position (one wall, no seed):
        # the position is not determined, whatever its value across the wall
        undetermined = tuple(c for c in FULL if c in undetermined or c in (Component.X, Component.Y))
        cov[:2, :] = 0.0
        cov[:, :2] = 0.0
        cov[0, 0] = cov[1, 1] = math.inf
    return Localization(fused.pose, cov, tuple(reports), strategy.name, undetermined, config)


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
    To localize many queries against one reference, build a :class:`Localizer`
    once: the reference-only work (keypoints, pyramids, KD-trees) is cached.
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
    produced = [(_Named(e.step), e, "", 0.0, False) for e in ests]
    reports, fused_inputs = _gate(produced, gating or GatingConfig())
    return _result(fused_inputs, reports, strategy, None, None)


class _Named:
    """Stand-in for a step in reports made by :func:`fuse`."""

    def __init__(self, name: str) -> None:
        self.name = name

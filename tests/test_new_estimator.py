"""A new estimator takes part in the hierarchy through typed fields only.

Everything a new step needs is in this file: the estimator (a config dataclass and a Step), one field of the
root config (here a subclass of :class:`~factorloc.Config`; in the library, a field of ``Config``) and one entry
of the step registry (:data:`factorloc.pipeline.STEPS`). Its reliability and its verdict on its seed reach the
gate as :class:`~factorloc.verdicts.Check` records and :class:`~factorloc.verdicts.SeedEvidence`, nothing else.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from factorloc import Config, Estimate, Localizer, Odometry, Pose2, Query, Reference, Scan, StepStatus
from factorloc.estimators.base import Hypotheses, sigma_checks
from factorloc.evaluation import Case, EvaluationSet, evaluate
from factorloc.pipeline import STEPS, default_steps
from factorloc.verdicts import Check, SeedEvidence, Unit


# --- the new estimator: a "beacon" that measures the position from a landmark at a known place ---------------------
@dataclass(frozen=True)
class BeaconConfig:
    enabled: bool = True
    max_sigma_position_m: float = 0.10
    max_seed_offset_m: float = 0.5


class BeaconStep:
    """Reads the true position from ``query.id`` (``"x,y,sigma"``): a stand-in for a landmark detector."""

    name = "beacon"

    def __init__(self, config: BeaconConfig = BeaconConfig()) -> None:
        self.config = config

    def prepare(self, reference: Reference) -> Any:
        return None

    def estimate(self, prepared: Any, query: Query, hypotheses: Hypotheses) -> Estimate | None:
        if not query.id:
            return None
        x, y, sigma = (float(v) for v in query.id.split(","))
        est = Estimate.position(self.name, x, y, sigma, sigma)
        checks = sigma_checks(est, self.config.max_sigma_position_m)
        seed = hypotheses.position()
        evidence = None
        if seed is not None:  # the beacon tests the seed it was given against its own fix
            offset = math.hypot(x - seed[0], y - seed[1])
            test = Check.at_most(
                "beacon.seed_offset", "distance from the seed", offset, self.config.max_seed_offset_m, Unit.METRE
            )
            evidence = SeedEvidence(position_step=seed[4], checks=(test,))
        reliable = all(c.passed for c in checks)
        return Estimate(est.step, est.components, est.values, est.covariance, reliable, checks=checks, seed=evidence)


@dataclass(frozen=True)
class ConfigWithBeacon(Config):
    beacon: BeaconConfig = field(default_factory=BeaconConfig)


REGISTRY = (*STEPS, ("beacon", BeaconStep))


# --- the checks -----------------------------------------------------------------------------------------------------
REF = Reference(scan=Scan(np.array([[1.0, 0.0], [0.0, 1.0], [-1.0, 0.0]])))


def _localize(query: Query, config: ConfigWithBeacon) -> Any:
    steps = [s for s in default_steps(config, REGISTRY) if s.name in ("odometry", "beacon")]
    return Localizer(REF, config, steps=steps).localize(query)


def test_the_new_step_is_configured_from_yaml_keys_and_built_by_the_registry() -> None:
    cfg = ConfigWithBeacon.from_dict({"beacon": {"max_sigma_position_m": 0.05}, "compass": {"enabled": False}})
    assert cfg.beacon.max_sigma_position_m == 0.05
    assert [s.name for s in default_steps(cfg, REGISTRY)] == ["odometry", "correlation", "icp", "beacon"]
    assert ConfigWithBeacon.from_dict(cfg.to_dict()) == cfg


def test_the_new_step_is_fused_gated_and_audits_its_seed_through_typed_fields() -> None:
    cfg = ConfigWithBeacon()
    odometry = Odometry(Pose2(1.0, 2.0, 0.3), 0.2, 0.2, 0.05)
    # agrees with the odometry: fused with it
    loc = _localize(Query(odometry=odometry, id="1.05,2.02,0.02"), cfg)
    assert [r.status for r in loc.steps] == [StepStatus.FUSED, StepStatus.FUSED]
    assert math.hypot(loc.pose.x - 1.05, loc.pose.y - 2.02) < 0.005
    # its σ rule fails: unreliable, counted under its own code
    loc = _localize(Query(odometry=odometry, id="1.05,2.02,0.3"), cfg)
    assert loc.step("beacon").status is StepStatus.UNRELIABLE and loc.step("beacon").rule_codes == ("beacon.sigma_position",)
    assert loc.step("beacon").reason == "σ position 0.3 m > 0.1 m"
    # unreliable, 3 m from the seed: its seed evidence contradicts the odometry, which the seed audit drops
    loc = _localize(Query(odometry=odometry, id="4.0,2.0,0.3"), cfg)
    odo = loc.step("odometry")
    assert odo.status is StepStatus.INCONSISTENT and odo.rule_codes == ("gate.seed_audit",)
    assert odo.reason == "seed contradicted by beacon (distance from the seed 3 m > 0.5 m)"
    assert not loc.determined
    # reliable and 3 m off: the consistency gate weighs it against the odometry instead (the earlier step loses the tie)
    loc = _localize(Query(odometry=odometry, id="4.0,2.0,0.02"), cfg)
    assert loc.step("odometry").rule_codes == ("gate.consistency.position",)
    assert loc.step("beacon").status is StepStatus.FUSED


def test_the_new_step_is_scored_and_its_rules_counted_by_the_evaluation() -> None:
    cfg = ConfigWithBeacon()
    truth = Pose2(1.0, 2.0, 0.3)
    odometry = Odometry(truth, 0.2, 0.2, 0.05)
    cases = [Case(Query(odometry=odometry, id=f"1.0{i},2.0,{s}"), truth) for i, s in enumerate([0.02, 0.02, 0.3, 0.4])]
    steps = [s for s in default_steps(cfg, REGISTRY) if s.name in ("odometry", "beacon")]
    report = evaluate(EvaluationSet(REF, tuple(cases)), config=cfg, steps=steps).to_json()
    beacon = report["steps"]["beacon"]
    assert beacon["reliable_rate"] == 0.5 and beacon["gate_reasons"] == {"unreliable: beacon.sigma_position": 2}
    assert beacon["gate_rules"][0]["text"] == "σ position 0.3–0.4 m > 0.1 m"

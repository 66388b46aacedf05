"""All seven strategies run through the same ``evaluate`` and produce the keys of docs/evaluation.md;
on a synthetic trajectory each is accurate against ground truth."""

from __future__ import annotations

import json

import pytest
from synthetic_trajectories import BOUNDS

from factorloc.baselines import ExtendedKalmanFilter, MarkovGridLocalization, MonteCarloLocalization
from factorloc.evaluation import evaluate
from factorloc.evaluation.offline import smoothed_report
from factorloc.fusion import GraphFusion, ProductFusion
from factorloc.fusion.robust import RobustGraphFusion
from factorloc.fusion.smoother import FixedLagSmoother, TrajectorySmoother

KEYS = [
    "position_rmse_m",
    "position_median_m",
    "heading_rmse_deg",
    "heading_median_deg",
    "nees_mean",
    "outside_99_rate",
    "confidently_wrong_rate",
    "latency_median_ms",
    "latency_p95_ms",
]

STRATEGIES = {
    # per query: the stretch without ICP falls back on the absolute odometry (measured 0.107 m)
    "product": (ProductFusion, 0.15),
    "graph": (GraphFusion, 0.15),
    "robust": (lambda: RobustGraphFusion("cauchy"), 0.15),
    "smoother": (TrajectorySmoother, 0.03),
    "fixed_lag": (lambda: FixedLagSmoother(5), 0.03),
    "ekf": (ExtendedKalmanFilter, 0.03),
    "mcl": (lambda: MonteCarloLocalization(500, BOUNDS, seed=0), 0.03),
    "markov": (lambda: MarkovGridLocalization(BOUNDS, resolution_m=0.1, n_theta=72), 0.05),
}


@pytest.fixture(scope="module")
def run():
    from synthetic_trajectories import make_synthetic

    return make_synthetic(24, seed=7, no_icp=(8, 12), outlier_at=3).run()


@pytest.mark.parametrize("name", list(STRATEGIES))
def test_strategy_gives_the_evaluation_keys_and_is_accurate(run, name: str) -> None:
    factory, max_rmse = STRATEGIES[name]
    d = evaluate(run, factory()).to_json()
    json.dumps(d)
    for k in KEYS:
        assert k in d, k
    for step in ("odometry", "compass", "icp"):
        assert {"reliable_rate", "latency_median_ms"} <= set(d["steps"][step])
    assert {"none", "no_depth", "outlier"} <= set(d["by_fault"])
    assert d["position_rmse_m"] < max_rmse
    assert d["heading_rmse_deg"] < 1.5
    assert d["position_determined_rate"] == 1.0


def test_offline_smoothed_report_has_the_keys_and_beats_per_query_fusion_where_icp_is_missing(run) -> None:
    offline = smoothed_report(run).to_json()
    product = evaluate(run, ProductFusion()).to_json()
    for k in KEYS:
        assert k in offline
    assert offline["strategy"] == "smoother_offline"
    assert offline["by_fault"]["no_depth"]["position_rmse_m"] < product["by_fault"]["no_depth"]["position_rmse_m"]

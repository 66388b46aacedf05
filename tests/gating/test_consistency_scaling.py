"""Issue #21, reproducer 5 (``fuse`` of n estimates): the consistency gate's leave-one-out products are O(n) per
round (prefix and suffix sums); checked here against the direct O(n²)-per-round definition."""

from __future__ import annotations

import numpy as np
import pytest

import factorloc as fl
from factorloc.errors import FusionError
from factorloc.gating import consistency_gate
from factorloc.gating.consistency import _inv
from factorloc.stats import chi2_quantile, mahalanobis_sq


def _reference_rejections(estimates, probability):
    """Worst-first leave-one-out on positions, written directly with numpy (no heading, no ties)."""
    threshold = chi2_quantile(probability, 2)
    active = list(range(len(estimates)))
    rejected = []
    while len(active) >= 2:
        d2 = {}
        for i in active:
            others = [j for j in active if j != i]
            info = sum(np.linalg.inv(estimates[j].covariance[:2, :2]) for j in others)
            vec = sum(np.linalg.inv(estimates[j].covariance[:2, :2]) @ estimates[j].values[:2] for j in others)
            cov_o = np.linalg.inv(info)
            d2[i] = mahalanobis_sq(estimates[i].values[:2] - cov_o @ vec, estimates[i].covariance[:2, :2] + cov_o)
        worst = max(active, key=lambda i: d2[i])
        if d2[worst] <= threshold:
            break
        rejected.append(worst)
        active.remove(worst)
    return sorted(rejected)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_the_vectorized_gate_rejects_what_the_definition_rejects(seed):
    rng = np.random.default_rng(seed)
    ests = []
    for i in range(25):
        spread = 1.0 if i % 4 == 0 else 0.02
        sx, sy = rng.uniform(0.01, 0.05, 2)
        c = rng.uniform(-0.5, 0.5) * sx * sy
        ests.append(fl.Estimate.position(f"e{i}", *rng.normal(0, spread, 2), covariance=[[sx * sx, c], [c, sy * sy]]))
    verdicts = consistency_gate(ests)
    got = sorted(i for i, v in enumerate(verdicts) if not v.accepted)
    assert got == _reference_rejections(ests, 0.999)
    assert got  # the outliers are there to be found


def test_the_gate_refuses_to_invert_a_singular_matrix():
    with pytest.raises(FusionError, match="singular"):
        _inv(np.array([[1.0, 1.0, 1.0]]))
    with pytest.raises(FusionError, match="positive"):
        _inv(np.array([[0.0]]))

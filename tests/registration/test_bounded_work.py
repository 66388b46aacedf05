"""Issue #21, reproducer 5: the work of the global search and the ICP step is bounded by a budget checked before
allocating, whatever the coordinates or the point count (timings: ``benchmarks/bench_bad_input.py``)."""

from __future__ import annotations

import numpy as np
import pytest

import factorloc as fl
from factorloc.errors import InputError
from factorloc.estimators.icp.reference import MAX_SCAN_POINTS, bounded_points
from factorloc.registration.global_search import (
    MAX_FIELD_CELLS,
    GlobalSearchParams,
    build_field,
    reference_fields,
    score_lattice,
    search,
)
from factorloc.sim import apartment


def _room() -> np.ndarray:
    t = np.linspace(0.0, 1.0, 100)
    walls = [np.stack([4 * t, 0 * t]), np.stack([4 + 0 * t, 3 * t]), np.stack([4 * t, 3 + 0 * t]), np.stack([0 * t, 3 * t])]
    return np.concatenate(walls, axis=1).T - [2.0, 1.5]


def test_a_query_far_outside_the_field_scores_zero_without_a_huge_pad():
    field = build_field(_room(), 0.3, 0.3, 0.9)
    # the seed 10⁹ m away once padded the field to (3333333351, 49) cells, 608 GiB
    scores = score_lattice(field, _room(), np.array([0.0, 0.5]), np.array([1e9, 0.0]), (49, 49))
    assert scores.shape == (2, 49, 49) and not scores.any()
    near = score_lattice(field, _room(), np.array([0.0]), np.array([-0.3 * 24, -0.3 * 24]), (49, 49))
    assert near.max() > 0.5  # the same call still finds the room at the centre offset


def test_search_around_a_far_seed_returns_no_candidate():
    assert search(_room(), _room(), center_m=(1e9, 0.0)) == []


def test_a_field_beyond_the_cell_budget_is_refused_before_allocating():
    pts = np.array([[0.0, 0.0], [1000.0, 1000.0]])
    with pytest.raises(InputError, match=r"would need 4(\.\d+)?e\+08 cells, more than 1\.6e\+07"):
        build_field(pts, 0.05, 0.08, 0.24)
    assert MAX_FIELD_CELLS == 16_000_000


def test_reference_fields_use_only_points_within_reach():
    spread = np.array([[1.0, 0.0], [1000.0, 0.0], [0.0, 1000.0], [1000.0, 1000.0]])
    coarse, fine = reference_fields(spread)  # only the first is within max_range + radius: a small field
    assert coarse.values.size < 10_000 and fine.values.size < 200_000
    with pytest.raises(InputError, match="no reference point lies within 20 m"):
        reference_fields(spread[1:], GlobalSearchParams())


def test_bounded_points_keeps_the_ends_and_is_deterministic():
    pts = np.arange(2 * 10_001, dtype=float).reshape(-1, 2)
    kept = bounded_points(pts)
    assert len(kept) == MAX_SCAN_POINTS and kept[0].tolist() == pts[0].tolist() and kept[-1].tolist() == pts[-1].tolist()
    assert np.array_equal(kept, bounded_points(pts))
    assert bounded_points(pts[:10]) is pts[:10] or len(bounded_points(pts[:10])) == 10


def test_a_dense_query_scan_is_thinned_with_a_note_and_still_localizes():
    from factorloc.sim import generate_scenario

    s = generate_scenario(apartment(), n_queries=1, seed=5)
    q = s.queries[0]
    rng = np.random.default_rng(0)
    assert q.query.scan is not None, "every simulated query carries a laser scan"
    scan = q.query.scan.points_m
    dense = scan[rng.integers(0, len(scan), 3 * MAX_SCAN_POINTS)] + rng.normal(0.0, 0.003, (3 * MAX_SCAN_POINTS, 2))
    loc = fl.localize(s.reference, fl.Query(scan=fl.Scan(dense), odometry=q.query.odometry))
    icp = next(r for r in loc.steps if r.name == "icp")
    assert icp.estimate is not None
    assert icp.estimate.diagnostics["downsampled_query_points"] == [3 * MAX_SCAN_POINTS, MAX_SCAN_POINTS]

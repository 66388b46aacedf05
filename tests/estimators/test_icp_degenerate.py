"""Issue #21, reproducer 8: degenerate geometry is detected, not fused — a straight wall leaves the position along it
to the other steps, a round scan leaves the heading to them, and present-but-unusable inputs are reported as
``unusable: <why>`` with a typed check, not as "inputs absent"."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest

import factorloc as fl
from factorloc.estimators.icp.covariance import heading_strength
from factorloc.gating import StepRun, gate
from factorloc.registration.icp2d import align, prepare_target

TRUTH = fl.Pose2(0.0, 0.0, 0.0)
ODOMETRY = fl.Odometry(fl.Pose2(0.2, 0.05, 0.03), 0.3, 0.3, 0.1)


def _wall(rng: np.random.Generator, n: int = 400) -> np.ndarray:
    x = np.linspace(-5.0, 5.0, n)
    return np.stack([x, np.full(n, 2.0)], axis=1) + rng.normal(0.0, 0.005, (n, 2))


def _circle(rng: np.random.Generator, r: float = 3.0, n: int = 400) -> np.ndarray:
    t = np.linspace(0.0, 2.0 * math.pi, n, endpoint=False)
    return np.stack([r * np.cos(t), r * np.sin(t)], axis=1) + rng.normal(0.0, 0.005, (n, 2))


def _icp(loc: fl.Localization):
    return next(r for r in loc.steps if r.name == "icp")


def test_a_straight_wall_does_not_fuse_a_position_along_it():
    rng = np.random.default_rng(0)
    loc = fl.localize(fl.Reference(scan=fl.Scan(_wall(rng))), fl.Query(scan=fl.Scan(_wall(rng)), odometry=ODOMETRY))
    icp = _icp(loc).estimate
    assert icp is not None and icp.sigma("x") > 10.0  # unknown along the wall (x)
    assert icp.sigma("y") < 0.1  # known across it (σ across the wall itself 1 cm; with the heading's lever arm 5 cm)
    sigma = np.sqrt(np.diag(loc.covariance))
    assert sigma[0] == pytest.approx(ODOMETRY.sigma_x_m, rel=0.01)  # along the wall: the odometry's σ, not ICP's
    assert abs(loc.pose.x - TRUTH.x) <= 3.0 * sigma[0] and abs(loc.pose.y - TRUTH.y) <= 3.0 * sigma[1]


def test_a_round_scan_does_not_fuse_a_heading():
    rng = np.random.default_rng(1)
    loc = fl.localize(fl.Reference(scan=fl.Scan(_circle(rng))), fl.Query(scan=fl.Scan(_circle(rng)), odometry=ODOMETRY))
    report = _icp(loc)
    assert report.status is fl.StepStatus.FUSED
    assert report.estimate.kind == "position"  # the heading is left to the other steps
    (check,) = [c for c in report.estimate.checks if c.code == "icp.constraint.heading"]
    limit = fl.Config().icp.reliability.min_heading_strength
    assert check.passed and check.value < limit and "left to the other steps" in check.note
    assert "heading unconstrained" in report.reason
    assert math.sqrt(loc.covariance[2, 2]) == pytest.approx(ODOMETRY.sigma_theta_rad, rel=1e-6)


def _room(rng: np.random.Generator) -> np.ndarray:
    t = np.linspace(0.0, 1.0, 100)
    room = np.concatenate([np.stack([4 * t, 0 * t]), np.stack([4 + 0 * t, 3 * t]), np.stack([4 * t, 3 + 0 * t])], axis=1).T
    return room - [2.0, 1.5] + rng.normal(0.0, 0.005, room.shape)


def test_a_room_keeps_its_heading():
    room = _room(np.random.default_rng(2))
    loc = fl.localize(fl.Reference(scan=fl.Scan(room)), fl.Query(scan=fl.Scan(room), odometry=ODOMETRY))
    assert _icp(loc).estimate.kind == "full"


def test_points_the_alignment_does_not_match_leave_the_heading_strength_alone():
    # a wall 25 m away that only the query sees (a partial overlap, as in a loop closure): the heading strength is
    # scaled by the correspondences' own lever arms, so the unmatched far points change nothing. Scaled by every
    # query point's mean squared range it read 0.0050 here instead of 0.28 — at the limit, and the room's heading
    # was dropped (the ACES map lost its closures that way, docs/calibration/icp.md)
    rng = np.random.default_rng(2)
    room = _room(rng)
    far = np.stack([np.full(150, 25.0), np.linspace(-10.0, 10.0, 150)], axis=1) + rng.normal(0.0, 0.005, (150, 2))
    target = prepare_target(room)
    alone = heading_strength(align(target, room, fl.Pose2(0.01, 0.0, 0.0)))
    with_far = heading_strength(align(target, np.concatenate([room, far]), fl.Pose2(0.01, 0.0, 0.0)))
    assert alone > 0.2 and with_far == pytest.approx(alone, rel=0.02)
    loc = fl.localize(fl.Reference(scan=fl.Scan(room)), fl.Query(scan=fl.Scan(np.concatenate([room, far])), odometry=ODOMETRY))
    assert _icp(loc).estimate.kind == "full" and _icp(loc).status is fl.StepStatus.FUSED


def test_the_heading_strength_is_the_schur_complement_of_the_heading_over_the_lever():
    # the closed-form 2×2 inverse against numpy's solve (whose LAPACK kernel, and so its rounding, depends on the
    # CPU): the same number to rounding, on real alignments (a room, a wall) and on random positive semi-definite
    # Hessians of every conditioning
    rng = np.random.default_rng(5)
    results = []
    for pts in (_room(rng), _wall(rng), _circle(rng)):
        results.append(align(prepare_target(pts), pts, fl.Pose2(0.02, -0.01, 0.01)))
    for _ in range(200):
        J = rng.normal(size=(50, 3)) * 10.0 ** rng.uniform(-3, 2, size=3)
        lever = float(rng.uniform(0.1, 10.0) * (J[:, 2] ** 2).sum())
        results.append(replace(results[0], hessian=J.T @ J, heading_lever_m2=lever))
    for r in results:
        h = np.asarray(r.hessian)
        hpp = h[:2, :2] + 1e-9 * max(h[0, 0] + h[1, 1], 1e-300) * np.eye(2)
        schur = h[2, 2] - h[2, :2] @ np.linalg.solve(hpp, h[:2, 2])
        expected = min(max(schur / r.heading_lever_m2, 0.0), 1.0)
        assert heading_strength(r) == pytest.approx(expected, rel=1e-9, abs=1e-12)
    assert heading_strength(results[2]) < 0.01 < 0.2 < heading_strength(results[0])  # a circle, a room


@pytest.mark.parametrize(
    ("reference", "query", "why"),
    [
        (
            fl.Reference(cloud=fl.PointCloud(np.column_stack([np.arange(500.0) % 7, np.arange(500.0) % 5, np.full(500, 5.0)]))),
            None,
            "reference 'reference': cloud has 0 point(s) in the height band",
        ),
        (fl.Reference(scan=fl.Scan(np.arange(600.0).reshape(300, 2) + 2e9)), None, "beyond ±1e+09 m"),
        (
            None,
            fl.PointCloud(np.column_stack([np.arange(500.0) % 7, np.arange(500.0) % 5, np.full(500, 5.0)])),
            "query scan: cloud has 0 point(s) in the height band",
        ),
    ],
)
def test_present_but_unusable_inputs_are_reported_as_unusable(reference, query, why):
    rng = np.random.default_rng(3)
    ref = reference or fl.Reference(scan=fl.Scan(_wall(rng)))
    q = fl.Query(cloud=query, odometry=ODOMETRY) if query is not None else fl.Query(scan=fl.Scan(_wall(rng)), odometry=ODOMETRY)
    report = _icp(fl.localize(ref, q))
    assert report.status is fl.StepStatus.SKIPPED
    assert report.reason.startswith("unusable: ") and why in report.reason
    assert [c.code for c in report.checks] == ["icp.inputs_usable"] and not report.checks[0].passed


def test_absent_inputs_are_still_inputs_absent():
    rng = np.random.default_rng(4)
    report = _icp(fl.localize(fl.Reference(scan=fl.Scan(_wall(rng))), fl.Query(odometry=ODOMETRY)))
    assert report.status is fl.StepStatus.SKIPPED and report.reason == "inputs absent" and report.checks == ()


def test_the_gate_reports_unusable_with_its_check():
    (report,) = gate([StepRun("icp", None, unusable="reference 'r': no point in range")]).reports
    assert report.reason == "unusable: reference 'r': no point in range"
    assert report.status is fl.StepStatus.SKIPPED and [c.code for c in report.checks] == ["icp.inputs_usable"]


def _corridor_scan(rng: np.random.Generator, noise_m: float, half_width_m: float = 1.0, step_rad: float = math.radians(0.5)):
    """A 360° scan from the middle of a 30 m corridor (walls at y = ±half_width), range noise ``noise_m`` (1σ)."""
    a = np.arange(-math.pi, math.pi, step_rad)
    s = np.sin(a)
    a, s = a[np.abs(s) > 0.08], s[np.abs(s) > 0.08]  # beams within 15 m along the walls
    r = half_width_m / np.abs(s) + rng.normal(0.0, noise_m, len(a))
    return np.column_stack([r * np.cos(a), r * np.sin(a)])


def test_the_constraint_strength_without_the_normals_own_noise():
    """Range noise tilts the PCA normals at random, which widens their scatter along the walls: a noisier laser's
    corridor looks constrained (on MIT CSAIL, +1 cm of range noise took corridor loops from 0.010 to 0.049, above
    the 0.03 limit, and two 180°-flipped loops through; docs/calibration/icp.md). The debiased strength takes the
    normals' own variance, (1 − quality)/(k − 2), off; a room keeps its strength."""
    from factorloc.estimators.icp.covariance import constraint_strength

    rng = np.random.default_rng(3)
    raw, debiased = [], []
    for noise in (0.0, 0.01, 0.02):
        ref, qry = _corridor_scan(rng, noise), _corridor_scan(rng, noise)
        res = align(prepare_target(ref), qry, fl.Pose2())
        v = res.normal_variances_rad2
        assert v is not None and v.shape == (res.n_inliers,) and np.all((v >= 0) & (v <= 1.0 / 5.0))
        raw.append(constraint_strength(res))
        debiased.append(constraint_strength(res, debias=True))
    limit = fl.Config().icp.reliability.min_constraint
    assert raw[0] < 1e-3 and debiased[0] <= raw[0]
    assert raw[2] > raw[1] > raw[0]  # the noise alone widens the scatter (measured 0, 0.019, 0.064)
    assert all(d < 0.7 * r for d, r in zip(debiased[1:], raw[1:], strict=True))  # measured: 0.27 and 0.60 of it
    assert debiased[1] < 0.5 * limit  # 1 cm (real lasers' range noise is about that): a corridor again
    assert raw[2] > 2 * limit > debiased[2]  # 2 cm, as large as the nearest points' spacing: only partly removed
    room = _room(np.random.default_rng(4))
    res = align(prepare_target(room), room + np.random.default_rng(5).normal(0, 0.01, room.shape), fl.Pose2())
    assert constraint_strength(res, debias=True) > 0.9 * constraint_strength(res) > 0.1

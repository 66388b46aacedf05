"""Point-to-line ICP: accuracy on a synthetic room, agreement with Open3D, input checks."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial import cKDTree

from factorloc.errors import InputError
from factorloc.geometry import Pose2
from factorloc.registration.icp2d import IcpParams, PreparedScan, align, prepare_target
from factorloc.registration.kernels import L2, Cauchy, Huber, Tukey
from factorloc.registration.open3d_peer import open3d_icp

TRUE = Pose2(0.6, -0.4, math.radians(25.0))


def _query(room: np.ndarray, rng: np.random.Generator, sigma_m: float = 0.005) -> np.ndarray:
    """The room seen from TRUE (query frame), every 2nd point, with Gaussian noise."""
    pts = TRUE.inverse().transform_points(room[::2])
    return pts + rng.normal(0.0, sigma_m, pts.shape)


def test_align_recovers_the_true_pose_from_an_offset_seed(room_points: np.ndarray) -> None:
    target = prepare_target(room_points)
    src = _query(room_points, np.random.default_rng(0))
    seed = Pose2(TRUE.x + 0.15, TRUE.y - 0.10, TRUE.theta + math.radians(4.0))
    res = align(target, src, seed, IcpParams(min_correspondence_m=0.1), Cauchy(0.05))
    err = TRUE.between(res.T_target_source)
    assert math.hypot(err.x, err.y) < 0.002
    assert abs(math.degrees(err.theta)) < 0.05
    assert res.converged
    assert res.fitness > 0.99
    assert res.rmse_m < 0.008


def test_align_agrees_with_open3d_point_to_plane_on_the_same_pair(room_points: np.ndarray) -> None:
    target = prepare_target(room_points)
    src = _query(room_points, np.random.default_rng(1))
    seed = Pose2(TRUE.x - 0.05, TRUE.y + 0.05, TRUE.theta - math.radians(2.0))
    ours = align(target, src, seed).T_target_source
    peer = open3d_icp(room_points, src, seed, method="point_to_plane", target_normals=target.normals).T_target_source
    d = ours.between(peer)
    assert math.hypot(d.x, d.y) < 0.003
    assert abs(math.degrees(d.theta)) < 0.1


def test_align_reports_no_fit_when_the_scans_do_not_overlap(room_points: np.ndarray) -> None:
    target = prepare_target(room_points)
    far = room_points[::4] + np.array([100.0, 100.0])
    res = align(target, far, Pose2())
    assert res.fitness == 0.0
    assert res.n_inliers < 3
    assert not res.converged


def test_align_rejects_malformed_input(room_points: np.ndarray) -> None:
    target = prepare_target(room_points)
    with pytest.raises(InputError, match="N×2"):
        align(target, np.zeros((10, 3)), Pose2())
    with pytest.raises(InputError, match=">= 3 points"):
        align(target, np.zeros((2, 2)), Pose2())
    with pytest.raises(InputError, match="min_correspondence_m"):
        IcpParams(min_correspondence_m=2.0, max_correspondence_m=1.0)


# --------------------------------------------------------------------------
# the fast align against a plain reference implementation of the same algorithm
# --------------------------------------------------------------------------
def _reference_align(target, src, T_init: Pose2, params: IcpParams, kernel, max_gate: float | None = None) -> dict:
    """The ICP of :func:`align` written plainly (one cKDTree-semantics query per association, the rotation
    Jacobian about the source origin built per point, ``numpy.linalg.solve``): the slow, readable twin that the
    vectorized implementation must reproduce."""
    usable = target.usable(params.min_normal_quality)
    rho2 = np.sum(src * src, axis=1)
    rho_rms, rho_max = math.sqrt(rho2.mean()), math.sqrt(rho2.max())
    sp2, sb2 = params.sigma_point_m**2, params.sigma_bearing_rad**2
    var_src = sp2 + sb2 * rho2
    theta, t = T_init.theta, np.array([T_init.x, T_init.y])
    converged, it, moved, last_gate = False, 0, math.inf, -1.0
    max_gate = params.max_correspondence_m if max_gate is None else max_gate
    for it in range(1, params.max_iterations + 1):
        gate = max(params.min_correspondence_m, max_gate * params.shrink ** (it - 1))
        q = src @ np.array([[math.cos(theta), -math.sin(theta)], [math.sin(theta), math.cos(theta)]]).T + t
        if gate != last_gate or moved > params.reassociate_m:
            _, j = target.tree.query(q, k=1, distance_upper_bound=gate)
            ok = usable[j]
            if np.count_nonzero(ok) < 3:
                break
            w_pair = ok * (2.0 * sp2 / (var_src + sp2 + sb2 * target.range2_ext[j]))
            n, c = target.n_ext[j], target.c_ext[j]
            moved, last_gate = 0.0, gate
        r = np.sum(n * q, axis=1) - c
        J = np.column_stack([n, n[:, 1] * (q[:, 0] - t[0]) - n[:, 0] * (q[:, 1] - t[1])])
        w = kernel.weight(r) * w_pair
        H = (J.T * w) @ J + 1e-9 * np.eye(3)
        if not abs(np.linalg.det(H)) > 1e-300:
            break
        dx, dy, dth = -np.linalg.solve(H, (J.T * w) @ r)
        step = math.hypot(dx, dy) + abs(dth) * rho_rms
        if step > gate:
            dx, dy, dth = dx * gate / step, dy * gate / step, dth * gate / step
        theta, t = theta + dth, t + [dx, dy]
        moved += math.hypot(dx, dy) + abs(dth) * rho_max
        if gate <= params.min_correspondence_m and math.hypot(dx, dy) < params.convergence_translation_m:
            if abs(dth) < params.convergence_rotation_rad:
                converged = True
                break
    T = Pose2(float(t[0]), float(t[1]), float(theta))
    q = T.transform_points(src)
    d_src, j = target.tree.query(q, k=1)
    sel = usable[np.where(d_src < params.min_correspondence_m, j, len(target))]
    jj, qi = j[sel], q[sel]
    n = target.n_ext[jj]
    r = np.sum(n * qi, axis=1) - target.c_ext[jj]
    J = np.column_stack([n, n[:, 1] * (qi[:, 0] - t[0]) - n[:, 0] * (qi[:, 1] - t[1])])
    var = var_src[sel] + sp2 + sb2 * target.range2_ext[jj]
    w = kernel.weight(r) * (2.0 * sp2 / var)
    d_tgt, _ = cKDTree(q).query(target.points_m, k=1)
    cap = params.chamfer_cap_m
    rin = r[np.abs(r) < params.fitness_distance_m]
    return {
        "pose": T.as_array(),
        "iterations": it,
        "converged": converged and len(r) >= 3,
        "fitness": np.mean(d_src < params.fitness_distance_m),
        "rmse_m": math.sqrt(np.mean(rin**2)) if len(rin) else math.inf,
        "chamfer_m": 0.5 * (np.minimum(d_src, cap).mean() + np.minimum(d_tgt, cap).mean()),
        "hessian": (J.T * w) @ J,
        "jacobians": J,
        "residuals_m": r,
        "weights": w,
        "variances_m2": var,
    }


def _assert_same(res, ref: dict) -> None:
    np.testing.assert_allclose(res.T_target_source.as_array(), ref["pose"], rtol=0, atol=1e-9)
    assert res.iterations == ref["iterations"] and res.converged == ref["converged"]
    assert res.fitness == pytest.approx(ref["fitness"], abs=1e-12)
    assert res.chamfer_m == pytest.approx(ref["chamfer_m"], abs=1e-9)
    assert res.rmse_m == pytest.approx(ref["rmse_m"], rel=1e-7)
    for key in ("jacobians", "residuals_m", "weights", "variances_m2"):
        np.testing.assert_allclose(getattr(res, key), ref[key], rtol=1e-7, atol=1e-9, err_msg=key)
    np.testing.assert_allclose(res.hessian, ref["hessian"], rtol=1e-7, atol=1e-6)


def _random_scene(rng: np.random.Generator, n: int) -> np.ndarray:
    """Random walls (segments) around the origin, ``n`` noisy points in total."""
    a = rng.uniform(-math.pi, math.pi, 8)
    ends = np.column_stack([np.cos(a), np.sin(a)]) * rng.uniform(1.5, 8.0, (8, 1))
    t = rng.uniform(0.0, 1.0, n)
    seg = rng.integers(0, 8, n)
    p0, p1 = ends[seg], ends[(seg + 1) % 8]
    return p0 + t[:, None] * (p1 - p0) + rng.normal(0.0, 0.01, (n, 2))


PARAMS = {
    "library default": IcpParams(),
    "step default (reassociation after 1 cm)": IcpParams(
        min_correspondence_m=0.1, convergence_translation_m=1e-3, convergence_rotation_rad=3e-4, reassociate_m=0.01
    ),
    "range-dependent noise": IcpParams(sigma_bearing_rad=0.003, max_correspondence_m=0.4),
    "fixed gate, never reassociated, 3 iterations": IcpParams(
        max_correspondence_m=0.3, min_correspondence_m=0.3, shrink=1.0, reassociate_m=math.inf, max_iterations=3
    ),
    "wide slow gate, tight convergence, strict normals": IcpParams(
        max_correspondence_m=2.5,
        shrink=0.9,
        convergence_translation_m=1e-6,
        convergence_rotation_rad=1e-7,
        min_normal_quality=0.9,
        fitness_distance_m=0.05,
        chamfer_cap_m=0.2,
        sigma_bearing_rad=0.01,
        reassociate_m=0.05,
    ),
}
KERNELS = {"cauchy": Cauchy(0.05), "huber": Huber(0.03), "tukey": Tukey(0.1), "l2": L2()}


@pytest.mark.parametrize("params", list(PARAMS.values()), ids=list(PARAMS))
@pytest.mark.parametrize("kernel", list(KERNELS.values()), ids=list(KERNELS))
def test_align_reproduces_the_reference_implementation_on_random_scenes(params: IcpParams, kernel) -> None:
    rng = np.random.default_rng(11)
    for _ in range(6):
        tgt_pts = _random_scene(rng, int(rng.integers(60, 400)))
        truth = Pose2(*rng.normal(0.0, [0.5, 0.5, 0.2]))
        src = truth.inverse().transform_points(tgt_pts[rng.permutation(len(tgt_pts))[:150]])
        src = src + rng.normal(0.0, 0.01, src.shape)
        seed = Pose2(truth.x + rng.normal(0, 0.1), truth.y + rng.normal(0, 0.1), truth.theta + rng.normal(0, 0.05))
        target = prepare_target(tgt_pts, params)
        _assert_same(align(target, src, seed, params, kernel), _reference_align(target, src, seed, params, kernel))


@pytest.mark.parametrize("kernel", list(KERNELS.values()), ids=list(KERNELS))
def test_align_reproduces_the_reference_implementation_on_degenerate_scenes(room_points, corridor_points, kernel) -> None:
    rng = np.random.default_rng(5)
    line = np.column_stack([np.linspace(-3, 3, 200), np.full(200, 2.0)])  # one wall: collinear points
    twice = np.vstack([room_points[::3], room_points[::3]])  # every point duplicated
    for pts in (line, corridor_points[::5], twice):
        for params in (IcpParams(), PARAMS["range-dependent noise"]):
            target = prepare_target(pts, params)
            src = Pose2(0.05, -0.02, 0.01).inverse().transform_points(pts[::2])
            src = src + rng.normal(0.0, 0.003, src.shape)
            _assert_same(align(target, src, Pose2(), params, kernel), _reference_align(target, src, Pose2(), params, kernel))


def test_align_reproduces_the_reference_implementation_far_from_the_seed(room_points) -> None:
    """Seeds off by up to a metre and 30°: the trust region clips the first steps, the gate override and the
    shrinking gate decide which points pair up."""
    rng = np.random.default_rng(8)
    target = prepare_target(room_points)
    src = _query(room_points, rng)
    for k in range(8):
        seed = Pose2(TRUE.x + rng.normal(0, 0.5), TRUE.y + rng.normal(0, 0.5), TRUE.theta + rng.normal(0, 0.3))
        gate = [None, 0.3, 1.5, 3.0][k % 4]
        for kernel in (Cauchy(0.05), L2()):
            res = align(target, src, seed, IcpParams(), kernel, max_correspondence_m=gate)
            _assert_same(res, _reference_align(target, src, seed, IcpParams(), kernel, max_gate=gate))


def test_align_handles_degenerate_inputs_like_the_reference(room_points) -> None:
    """Three points, a scan far from the target, identical points, a room 1000 km from its origin: a result
    (no crash), the reference's result."""
    params = IcpParams()
    one_spot = np.tile([[1.0, 2.0]], (20, 1))
    target = prepare_target(room_points)
    off = np.array([1e6, -1e6])
    cases = [
        (target, room_points[[0, 150, 300]], Pose2()),  # three points
        (target, room_points[::5], Pose2(1e8, -1e8, 1.0)),  # the seed puts the scan 1e8 m away
        (prepare_target(one_spot), room_points[::5], Pose2()),  # all target points identical
        (prepare_target(one_spot), one_spot[:5] - [1.0, 2.0], Pose2(1.0, 2.0, 0.0)),  # both
        (prepare_target(room_points + off), room_points[::5], Pose2(1e6 + 0.03, -1e6 - 0.02, 0.01)),
    ]
    for tgt, src, seed in cases:
        _assert_same(align(tgt, src, seed, params), _reference_align(tgt, src, seed, params, Cauchy(0.05)))
    unbounded = IcpParams(max_correspondence_m=math.inf)  # the gate never shrinks: 40 iterations, no convergence
    src = _query(room_points, np.random.default_rng(9))
    _assert_same(align(target, src, TRUE, unbounded), _reference_align(target, src, TRUE, unbounded, Cauchy(0.05)))
    for seed in (Pose2(1e300, -1e300, 2.0), Pose2(-1.7e308, 1.7e308, 0.0)):  # absurd but finite seeds
        res = align(target, room_points[::5] * 1e3, seed)
        assert res.n_inliers == 0 and res.fitness == 0.0 and res.chamfer_m == 0.5 and not res.converged
    far = align(target, room_points[::5], Pose2(1e8, -1e8, 1.0))
    assert far.fitness == 0.0 and far.n_inliers == 0 and far.chamfer_m == pytest.approx(0.5)
    shifted = align(*cases[-1][:2], cases[-1][2], params).T_target_source
    assert abs(shifted.x - 1e6) < 1e-6 and abs(shifted.y + 1e6) < 1e-6 and abs(shifted.theta) < 1e-9
    # every source point at one spot: H has rank 1 (only the 1e-9 regulariser elsewhere), so the pose is not
    # reproducible to 1e-9 — but the result is finite and the 20 identical pairs agree
    spot = align(target, one_spot, Pose2(), params)
    assert np.isfinite(spot.T_target_source.as_array()).all() and np.isfinite(spot.hessian).all()
    assert spot.n_inliers == 20 and np.ptp(spot.residuals_m) == 0.0


def test_align_rejects_non_finite_points(room_points: np.ndarray) -> None:
    target = prepare_target(room_points)
    src = room_points[::4].copy()
    src[3, 1] = np.nan
    with pytest.raises(InputError, match="NaN"):
        align(target, src, Pose2())
    with pytest.raises(InputError, match="NaN"):
        prepare_target(src)
    src[3, 1] = -np.inf
    with pytest.raises(InputError, match="infinite"):
        align(target, src, Pose2())


def test_align_rejects_empty_tiny_huge_and_foreign_inputs(room_points: np.ndarray) -> None:
    target = prepare_target(room_points)
    for bad in (np.zeros((0, 2)), np.zeros((1, 2)), np.zeros(6), np.zeros((4, 2, 1))):
        with pytest.raises(InputError, match="N×2|>= 3 points"):
            align(target, bad, Pose2())
        with pytest.raises(InputError, match="N×2|>= 3 points"):
            prepare_target(bad)
    with pytest.raises(InputError, match="beyond"):
        align(target, room_points[::4] + 2e9, Pose2())
    with pytest.raises(InputError, match="beyond"):
        prepare_target(room_points * 1e10)
    with pytest.raises(InputError, match="T_init"):
        align(target, room_points[::4], (0.0, 0.0, 0.0))

    class Geman:  # a RobustKernel the compiled core does not know
        def weight(self, r):
            return 1.0 / (1.0 + r * r) ** 2

    with pytest.raises(InputError, match="kernel must be one of"):
        align(target, room_points[::4], Pose2(), IcpParams(), Geman())
    with pytest.raises(InputError, match="PreparedScan.normals"):
        PreparedScan(target.points_m, target.normals[:-1], target.quality, target.tree, target.ranges_m)


def test_align_accepts_strided_integer_and_float32_sources(room_points: np.ndarray) -> None:
    target = prepare_target(room_points)
    src = _query(room_points, np.random.default_rng(4))
    seed = Pose2(TRUE.x + 0.05, TRUE.y, TRUE.theta)
    ref = align(target, np.ascontiguousarray(src), seed)
    strided = np.asfortranarray(src)
    assert not strided.flags.c_contiguous
    np.testing.assert_array_equal(align(target, strided, seed).T_target_source.as_array(), ref.T_target_source.as_array())
    f32 = align(target, src.astype(np.float32), seed).T_target_source
    assert abs(f32.x - ref.T_target_source.x) < 1e-4
    grid = np.round(room_points[::4] * 50).astype(np.int64)  # integer coordinates (2 cm units)
    assert align(prepare_target(grid), grid, Pose2()).fitness == 1.0


@pytest.fixture(scope="module", params=["intel", "aces"])
def laser_pairs(request, shared_data) -> list[tuple[np.ndarray, np.ndarray, Pose2]]:
    """(reference scan, query scan, odometry seed) of every 25th relation of a laser log whose robot moved < 5 m."""
    from factorloc.datasets.rosbag import read_laser_log
    from factorloc.evaluation.relations import read_relations

    laser = shared_data / "laser"
    log = read_laser_log(laser / f"{request.param}.sort.bag")
    rel = read_relations(laser / f"{request.param}.relations").subset(25)
    out = []
    for t1, t2 in zip(rel.t1_s, rel.t2_s, strict=True):
        if log.odometry.distance_between(t1, t2)[0] < 5.0:
            out.append((log.scans.at(t1, 2e-3).points_m, log.scans.at(t2, 2e-3).points_m, log.odometry.between(t1, t2)))
    assert len(out) > 20
    return out


def test_align_reproduces_the_reference_implementation_on_real_laser_scans(laser_pairs) -> None:
    step = PARAMS["step default (reassociation after 1 cm)"]
    noisy = PARAMS["range-dependent noise"]
    for k, (ref_pts, qry_pts, seed) in enumerate(laser_pairs):
        params, kernel = (step, Cauchy(0.05)) if k % 2 == 0 else (noisy, KERNELS[["huber", "tukey", "l2"][k % 3]])
        target = prepare_target(ref_pts, params)
        gate = 0.5 if k % 4 == 0 else None
        _assert_same(
            align(target, qry_pts, seed, params, kernel, max_correspondence_m=gate),
            _reference_align(target, qry_pts, seed, params, kernel, max_gate=gate),
        )


def test_align_gate_override_equals_params_with_that_gate(room_points: np.ndarray) -> None:
    from dataclasses import replace

    target = prepare_target(room_points)
    src = _query(room_points, np.random.default_rng(3))
    seed = Pose2(TRUE.x + 0.1, TRUE.y, TRUE.theta + 0.03)
    a = align(target, src, seed, IcpParams(), max_correspondence_m=0.35)
    b = align(target, src, seed, replace(IcpParams(), max_correspondence_m=0.35))
    np.testing.assert_array_equal(a.T_target_source.as_array(), b.T_target_source.as_array())
    assert a.iterations == b.iterations
    c = align(target, src, seed, IcpParams())  # the default 1 m gate runs one more shrink step
    assert c.iterations != a.iterations
    with pytest.raises(InputError, match="max_correspondence_m"):
        align(target, src, seed, IcpParams(min_correspondence_m=0.2), max_correspondence_m=0.1)


def test_icp_params_compiled_vector_follows_replace_and_stays_out_of_the_fields() -> None:
    """The vector the compiled core reads is rebuilt by dataclasses.replace and is no dataclass field (the config's
    to_dict/from_dict round trip sees the parameters only)."""
    from dataclasses import asdict, fields, replace

    p = replace(IcpParams(), shrink=0.5, sigma_bearing_rad=0.002, max_iterations=7)
    assert "_core" not in {f.name for f in fields(p)} and "_core" not in asdict(p)
    assert p._core[2] == 0.5 and p._core[9] == pytest.approx(0.002**2) and p._core[0] == 7
    assert IcpParams(**asdict(p)) == p

"""Every input type rejects bad values with an InputError naming the field; the result's certainty."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc import (
    CameraImage,
    Component,
    Estimate,
    InputError,
    Localization,
    Odometry,
    Panorama,
    PointCloud,
    Pose2,
    Query,
    Reference,
    Scan,
)

IMG = np.zeros((32, 64, 3), np.uint8)


# --- images -------------------------------------------------------------------
@pytest.mark.parametrize(
    "image,match",
    [
        (np.zeros((32, 64, 3), np.float32), "uint8"),
        (np.zeros((32, 64), np.uint8), "H×W×3"),
        (np.zeros((32, 64, 4), np.uint8), "H×W×3"),
        (np.zeros((0, 64, 3), np.uint8), "too small"),
        ([[1, 2, 3]], "numpy array"),
        (None, "numpy array"),
    ],
)
@pytest.mark.parametrize("cls,field", [(Panorama, "Panorama.image_bgr"), (CameraImage, "CameraImage.image_bgr")])
def test_images_reject_wrong_types_and_shapes(cls: type, field: str, image: object, match: str) -> None:
    with pytest.raises(InputError, match=match) as info:
        cls(image)
    assert field in str(info.value)


def test_panorama_column_azimuth_convention() -> None:
    pano = Panorama(np.zeros((16, 360, 3), np.uint8))
    assert math.isclose(pano.azimuth_of_column(180), 0.0, abs_tol=1e-12)  # centre looks forward
    assert math.isclose(pano.azimuth_of_column(90), math.pi / 2)  # left of centre = to the left (CCW)
    assert math.isclose(pano.column_of_azimuth(-math.pi / 2), 270.0)
    u = np.array([0.0, 17.3, 359.9])
    assert np.allclose(pano.column_of_azimuth(pano.azimuth_of_column(u)), u)


def test_camera_image_column_azimuth_uses_fov_and_yaw() -> None:
    cam = CameraImage(np.zeros((480, 640, 3), np.uint8), hfov_rad=math.radians(57.0), yaw_in_robot_rad=math.radians(90.0))
    assert math.isclose(cam.azimuth_of_column(cam.principal_x_px), math.radians(90.0))
    # the left edge (u = -0.5) is half the field of view to the left
    assert math.isclose(cam.azimuth_of_column(-0.5), math.radians(90.0 + 28.5), rel_tol=1e-9)
    assert math.isclose(math.degrees(cam.vfov_rad), 2 * math.degrees(math.atan(240 / cam.focal_px)))


@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"fov_v_rad": 0.0}, "Panorama.fov_v_rad"),
        ({"fov_v_rad": 4.0}, "Panorama.fov_v_rad"),
        ({"azimuth_col0_rad": float("nan")}, "Panorama.azimuth_col0_rad"),
    ],
)
def test_panorama_rejects_bad_geometry(kwargs: dict, match: str) -> None:
    with pytest.raises(InputError, match=match):
        Panorama(IMG, **kwargs)


@pytest.mark.parametrize(
    "kwargs,match", [({"hfov_rad": -1.0}, "hfov_rad"), ({"yaw_in_robot_rad": float("inf")}, "yaw_in_robot_rad")]
)
def test_camera_rejects_bad_geometry(kwargs: dict, match: str) -> None:
    with pytest.raises(InputError, match=match):
        CameraImage(IMG, **kwargs)


def test_images_are_copied_and_read_only() -> None:
    src = np.full((16, 16, 3), 7, np.uint8)
    pano = Panorama(src)
    src[:] = 0
    assert pano.image_bgr[0, 0, 0] == 7
    with pytest.raises(ValueError):
        pano.image_bgr[0, 0, 0] = 1


# --- clouds and scans ------------------------------------------------------------
@pytest.mark.parametrize(
    "cls,good_cols",
    [(PointCloud, 3), (Scan, 2)],
)
@pytest.mark.parametrize(
    "make,match",
    [
        (lambda c: np.full((5, c), np.nan), "NaN"),
        (lambda c: np.full((5, c), np.inf), "NaN or infinite"),
        (lambda c: np.zeros((0, c)), "at least 1 row"),
        (lambda c: np.zeros((5, c + 1)), "shape"),
        (lambda c: np.zeros(5), "shape"),
        (lambda c: np.array([["a"] * c]), "numeric"),
    ],
)
def test_points_reject_nan_empty_and_misshaped(cls: type, good_cols: int, make, match: str) -> None:  # noqa: ANN001
    with pytest.raises(InputError, match=match) as info:
        cls(make(good_cols))
    assert cls.__name__ in str(info.value)


# --- odometry ---------------------------------------------------------------------
def test_odometry_from_distance_follows_the_patent_example() -> None:
    odo = Odometry.from_distance(Pose2(1.0, 0.0, 0.0), distance_m=1.0, drift_ratio=0.05)
    assert math.isclose(odo.sigma_x_m, 0.05) and math.isclose(odo.sigma_y_m, 0.05)
    assert Odometry.from_distance(Pose2(), 0.0).sigma_x_m == 1e-3  # floor, never zero


@pytest.mark.parametrize("field", ["sigma_x_m", "sigma_y_m", "sigma_theta_rad"])
@pytest.mark.parametrize("value", [0.0, -1.0, float("nan")])
def test_odometry_rejects_non_positive_sigmas(field: str, value: float) -> None:
    kwargs = {"T_world_robot": Pose2(), "sigma_x_m": 0.1, "sigma_y_m": 0.1, "sigma_theta_rad": 0.1, field: value}
    with pytest.raises(InputError, match=f"Odometry.{field}"):
        Odometry(**kwargs)


def test_odometry_rejects_negative_distance_and_non_pose() -> None:
    with pytest.raises(InputError, match="distance_m"):
        Odometry.from_distance(Pose2(), -1.0)
    with pytest.raises(InputError, match="T_world_robot"):
        Odometry((0, 0, 0), 0.1, 0.1, 0.1)  # type: ignore[arg-type]


# --- estimates -------------------------------------------------------------------------
@pytest.mark.parametrize(
    "kwargs,match",
    [
        ({"components": ("x",)}, "components"),
        ({"components": ("x", "z")}, "components"),
        ({"values": [1.0]}, "values"),
        ({"values": [1.0, float("nan")]}, "NaN"),
        ({"covariance": [[1.0, 0.0], [0.0, 0.0]]}, "positive definite"),
        ({"covariance": [[1.0, 0.5], [0.0, 1.0]]}, "symmetric"),
        ({"covariance": [[-1.0, 0.0], [0.0, 1.0]]}, "positive definite"),
        ({"step": ""}, "step"),
    ],
)
def test_estimate_rejects_bad_fields(kwargs: dict, match: str) -> None:
    base = {"step": "icp", "components": ("x", "y"), "values": [1.0, 2.0], "covariance": np.eye(2) * 1e-4}
    with pytest.raises(InputError, match=match):
        Estimate(**{**base, **kwargs})


def test_estimate_builders_sigmas_and_json_round_trip() -> None:
    e = Estimate.pose("odometry", Pose2(1, 2, 3.5), 0.1, 0.2, 0.3, reliable=False, reason="far", diagnostics={"n": np.int64(3)})
    assert e.kind == "full" and np.allclose(e.sigmas, [0.1, 0.2, 0.3])
    assert math.isclose(e.value("theta"), 3.5 - 2 * math.pi)
    assert Estimate.from_dict(e.to_dict()) == e
    assert e.marginal(("theta",)).kind == "heading" and math.isclose(e.marginal(["theta"]).sigma("theta"), 0.3)
    with pytest.raises(InputError, match="sigma_theta_rad"):
        Estimate.heading("compass", 0.0, 0.0)
    with pytest.raises(InputError, match="sigmas"):
        Estimate.from_dict({"step": "a", "components": ["theta"], "values": [0.0], "sigmas": [-1.0]})
    # a component the estimate does not measure, or no component at all, is named (not a bare list.index error)
    heading = e.marginal(["theta"])
    for bad in ("x", Component.Y, "z"):
        with pytest.raises(InputError, match=r"'odometry' estimate measures \['theta'\]"):
            heading.sigma(bad)
        with pytest.raises(InputError, match="not"):
            heading.value(bad)


# --- reference / query -----------------------------------------------------------
def test_reference_and_query_check_their_parts() -> None:
    with pytest.raises(InputError, match="at least one"):
        Reference()
    with pytest.raises(InputError, match="Reference.scan"):
        Reference(scan=np.zeros((3, 2)))  # type: ignore[arg-type]
    with pytest.raises(InputError, match=r"Query.images\[1\]"):
        Query(images=(CameraImage(IMG), IMG))  # type: ignore[arg-type]
    with pytest.raises(InputError, match="Query.odometry"):
        Query(odometry=Pose2())  # type: ignore[arg-type]
    q = Query(images=CameraImage(IMG))  # a single image is accepted as a 1-tuple
    assert len(q.images) == 1


# --- certainty --------------------------------------------------------------------------
def _loc(cov: np.ndarray, undetermined: tuple = ()) -> Localization:
    return Localization(Pose2(), cov, (), "product", undetermined)


def test_certainty_matches_the_cumulative_distribution() -> None:
    # isotropic 2D Gaussian: P(|e| <= r) = 1 - exp(-r²/2σ²) (Rayleigh); heading: erf(a/σ√2)
    sigma, sigma_t = 0.02, math.radians(1.0)
    loc = _loc(np.diag([sigma**2, sigma**2, sigma_t**2]))
    r, a = 0.03, math.radians(2.0)
    expected = (1 - math.exp(-(r**2) / (2 * sigma**2))) * math.erf(a / (sigma_t * math.sqrt(2)))
    assert math.isclose(loc.certainty(r, a), expected, rel_tol=1e-9)


def test_certainty_of_an_elongated_gaussian_and_of_undetermined_components() -> None:
    # σx = 1 cm, σy = 1 m, disc of 5 cm: checked against an independent 2D integration (scipy dblquad)
    from scipy.integrate import dblquad

    sx, sy, r = 0.01, 1.0, 0.05
    ref, _ = dblquad(
        lambda y, x: math.exp(-0.5 * (x / sx) ** 2 - 0.5 * (y / sy) ** 2) / (2 * math.pi * sx * sy),
        -r,
        r,
        lambda x: -math.sqrt(r * r - x * x),
        lambda x: math.sqrt(r * r - x * x),
        epsabs=1e-13,
    )
    loc = _loc(np.diag([sx**2, sy**2, 1e-6]))
    assert math.isclose(loc.certainty(r, 1.0), ref, rel_tol=1e-7)
    # a rotated copy of the same covariance gives the same probability
    c, s = math.cos(0.6), math.sin(0.6)
    rot = np.array([[c, -s], [s, c]])
    cov = np.eye(3) * 1e-6
    cov[:2, :2] = rot @ np.diag([sx**2, sy**2]) @ rot.T
    assert math.isclose(_loc(cov).certainty(r, 1.0), ref, rel_tol=1e-7)
    und = _loc(np.diag([math.inf, math.inf, 1e-4]), (Component.X, Component.Y))
    assert und.certainty(1.0, 1.0) == 0.0
    with pytest.raises(InputError, match="radius_m"):
        loc.certainty(-1.0, 0.1)


def test_positive_definite_check_agrees_with_eigenvalues_on_random_and_near_singular_matrices():
    """The LDLᵀ pivot test (plain Python, k ≤ 3) accepts exactly the matrices whose eigenvalues are all > 0."""
    from factorloc.types.estimate import _cholesky_pivots

    rng = np.random.default_rng(4)
    checked = 0
    for _ in range(3000):
        k = int(rng.integers(1, 4))
        # eigenvalues spanning 1e-8..1e4 (σ from 1e-4 to 1e2), some exactly zero or negative
        eig = 10.0 ** rng.uniform(-8, 4, k) * rng.choice([1.0, 1.0, 1.0, -1.0, 0.0], k)
        q, _ = np.linalg.qr(rng.normal(size=(k, k)))
        c = q @ np.diag(eig) @ q.T
        c = 0.5 * (c + c.T)
        lam = np.linalg.eigvalsh(c)
        if abs(lam).min() < 1e-10 * abs(lam).max():
            continue  # numerically singular: either answer is right
        pivots = _cholesky_pivots(c.tolist())
        assert all(p > 0 for p in pivots) == bool(lam.min() > 0), (c, lam, pivots)
        checked += 1
    assert checked > 2000


def test_unrolled_pivots_and_the_exactly_symmetric_path_give_the_general_bits():
    """The 3×3 LDLᵀ pivots unrolled are the general loop's, bit for bit; an exactly symmetric covariance (taken as
    its own mean) gives the same Estimate as the general symmetrization, and a nearly symmetric one is averaged."""
    from factorloc.types.estimate import _cholesky_pivots, _cholesky_pivots3, _covariance

    rng = np.random.default_rng(5)
    for _ in range(2000):
        eig = 10.0 ** rng.uniform(-8, 4, 3) * rng.choice([1.0, 1.0, 1.0, -1.0, 0.0], 3)
        q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
        c = q @ np.diag(eig) @ q.T
        c = 0.5 * (c + c.T)
        assert _cholesky_pivots3(c.tolist()) == _cholesky_pivots(c.tolist())
    a = rng.normal(size=(3, 3))
    c = a @ a.T * 1e-2
    c = 0.5 * (c + c.T)
    c[0, 2] = c[2, 0] = 0.0
    sym = np.array([[0.5 * c[i, j] + 0.5 * c[j, i] for j in range(3)] for i in range(3)])
    assert np.array_equal(_covariance("c", c, 3), sym) and not _covariance("c", c, 3).flags.writeable
    assert np.array_equal(_covariance("c", c.tolist(), 3), sym)  # lists take float_array's path
    tiny = c.copy()
    tiny[0, 1] = tiny[1, 0] = 3e-310  # subnormal: 0.5·a is not exact, so the general mean is taken
    assert np.array_equal(
        _covariance("c", tiny, 3), np.array([[0.5 * tiny[i, j] + 0.5 * tiny[j, i] for j in range(3)] for i in range(3)])
    )
    near = c.copy()
    near[0, 1] *= 1 + 1e-12  # within the tolerance: averaged
    assert _covariance("c", near, 3)[0, 1] == 0.5 * near[0, 1] + 0.5 * near[1, 0]
    bad = c.copy()
    bad[1, 1] = np.nan
    with pytest.raises(InputError, match="contains 1 NaN"):  # float_array's error, as before
        _covariance("c", bad, 3)


def test_component_set_lookup_matches_the_general_form():
    from factorloc.types.components import FULL, HEADING, POSITION, component_set

    assert component_set(("x", "y", "theta")) is FULL and component_set((Component.THETA,)) is HEADING
    assert component_set(["y", "x"]) == POSITION and component_set(("y", "x")) == POSITION
    with pytest.raises(InputError, match="drawn from"):
        component_set((["x"], "y"))
    with pytest.raises(InputError, match="position-only"):
        component_set(("x",))

"""The scenario generator: reproducible from its seed, faults as advertised, ground truth consistent."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc.errors import InputError
from factorloc.geometry import wrap_angle
from factorloc.sim import FAULTS, GeneratorConfig, apartment, generate_scenario, relight, render_camera

SMALL = GeneratorConfig(panorama_width_px=512, panorama_height_px=64)


def test_same_seed_same_scenario_and_single_queries_regenerate_identically() -> None:
    a = generate_scenario(apartment(), 4, 11, config=SMALL)
    b = generate_scenario(apartment(), 4, 11, config=SMALL)
    assert a == b
    only = generate_scenario(apartment(), 4, 11, config=SMALL, only_queries=[2])
    assert only.queries == (a.queries[2],)
    assert only.references == a.references
    c = generate_scenario(apartment(), 4, 12, config=SMALL)
    assert c.queries[0] != a.queries[0]


def test_queries_are_free_poses_at_the_banded_distances_with_consistent_odometry() -> None:
    s = generate_scenario(apartment(), 6, 5, faults=(), config=SMALL)
    w = apartment()
    ref = s.reference.T_world_reference
    for i, q in enumerate(s.queries):
        lo, hi = SMALL.distance_bands_m[i % 3]
        assert lo <= q.distance_from_reference_m <= hi
        assert q.distance_from_reference_m == pytest.approx(math.dist((q.truth.x, q.truth.y), (ref.x, ref.y)))
        assert w.is_free(np.array([[q.truth.x, q.truth.y]]), SMALL.clearance_m)[0]
        assert q.faults == ()
        odo = q.query.odometry
        e = np.array(
            [
                odo.T_world_robot.x - q.truth.x,
                odo.T_world_robot.y - q.truth.y,
                wrap_angle(odo.T_world_robot.theta - q.truth.theta),
            ]
        )
        assert np.all(np.abs(e) < 5 * np.array([odo.sigma_x_m, odo.sigma_y_m, odo.sigma_theta_rad]))
        assert len(q.query.images) == 1 and q.query.images[0].image_bgr.shape == (480, 640, 3)
        assert q.query.cloud is not None and q.query.scan is not None


def test_kidnapped_odometry_is_off_by_the_push() -> None:
    cfg = GeneratorConfig(panorama_width_px=512, panorama_height_px=64, fault_probability=1.0, path_length_range_m=(0.5, 1.0))
    s = generate_scenario(apartment(), 3, 2, faults=("kidnapped",), config=cfg)
    for q in s.queries:
        assert "kidnapped" in q.faults
        odo = q.query.odometry
        off = math.dist((odo.T_world_robot.x, odo.T_world_robot.y), (q.truth.x, q.truth.y))
        assert off > 0.5  # pushed 0.7–2 m, drift over ≤ 1 m is only a few cm
        assert off > 3 * max(odo.sigma_x_m, odo.sigma_y_m)  # and the odometry's σ does not cover it


def test_corridor_queries_face_a_side_wall_inside_the_corridor() -> None:
    cfg = GeneratorConfig(panorama_width_px=512, panorama_height_px=64, fault_probability=1.0)
    s = generate_scenario(apartment(), 2, 3, faults=("corridor",), config=cfg)
    x0, y0, x1, y1 = apartment().region("corridor")
    for q in s.queries:
        assert x0 <= q.truth.x <= x1 and y0 <= q.truth.y <= y1
        assert abs(abs(q.truth.theta) - math.pi / 2) < 0.3


def test_lighting_fault_is_the_relit_clean_view() -> None:
    cfg = GeneratorConfig(panorama_width_px=512, panorama_height_px=64, fault_probability=1.0)
    s = generate_scenario(apartment(), 3, 9, faults=("lighting",), config=cfg)
    for q in s.queries:
        p = q.metadata["lighting"]
        clean = render_camera(apartment(), q.truth).image_bgr
        relit = relight(clean, p["gain"], p["gamma"])
        lit = q.query.images[0].image_bgr
        if p["shadows"] == 0:
            assert np.array_equal(lit, relit)
        else:  # shadows only darken the relit view
            assert np.all(lit.astype(int) <= relit.astype(int) + 1)
            assert np.mean(lit.astype(int) < relit.astype(int) - 5) > 0.005


def test_unknown_fault_is_refused() -> None:
    with pytest.raises(InputError, match="unknown fault"):
        generate_scenario(apartment(), 1, 0, faults=("earthquake",))
    assert "kidnapped" in FAULTS

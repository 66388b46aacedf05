"""The renderers against plane geometry (not against themselves)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from factorloc import CameraImage, Panorama, PointCloud, Pose2
from factorloc.errors import InputError
from factorloc.sim import (
    DepthCamera,
    Face,
    Material,
    Obstacle,
    PinholeCamera,
    Wall,
    World,
    apartment,
    render_camera,
    render_cloud,
    render_cloud_360,
    render_panorama,
    render_scan,
)

BLUE = Face(Material("plain", (1.3, 0.35, 0.35)))  # BGR gains: a blue paint
RED = Face(Material("plain", (0.35, 0.35, 1.3)))


def square_room(size_m: float = 10.0, face: Face = BLUE, obstacles: tuple[Obstacle, ...] = ()) -> World:
    """A square room [0, size]², walls 2.5 m high, inner faces ``face`` (outer walls CCW: left face inside)."""
    s = size_m
    corners = [(0.0, 0.0), (s, 0.0), (s, s), (0.0, s)]
    walls = tuple(Wall(corners[i], corners[(i + 1) % 4], left=face, right=Face()) for i in range(4))
    return World("square", walls, obstacles, wall_height_m=2.5, floor=Material("parquet"), ceiling=Material("ceiling"))


def _blueness(img: np.ndarray) -> np.ndarray:
    return img[..., 0].astype(float) - img[..., 2].astype(float)


def _redness(img: np.ndarray) -> np.ndarray:
    return img[..., 2].astype(float) - img[..., 0].astype(float)


def _circular_shift(a: np.ndarray, b: np.ndarray) -> float:
    """Sub-pixel column shift s such that b ≈ roll(a, s), by circular cross-correlation of all rows."""
    fa = np.fft.rfft(a - a.mean(axis=1, keepdims=True), axis=1)
    fb = np.fft.rfft(b - b.mean(axis=1, keepdims=True), axis=1)
    xc = np.fft.irfft((np.conj(fa) * fb).sum(axis=0), n=a.shape[1])
    k = int(np.argmax(xc))
    y0, y1, y2 = xc[k - 1], xc[k], xc[(k + 1) % len(xc)]
    frac = 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)
    s = k + frac
    return s if s < a.shape[1] / 2 else s - a.shape[1]


# --------------------------------------------------------------------------
# panorama
# --------------------------------------------------------------------------
def test_panorama_follows_the_panorama_type_convention() -> None:
    pano = render_panorama(apartment(), Pose2(3.0, 2.2, 0.3), 1.0, 1024, math.radians(60))
    assert isinstance(pano, Panorama)
    assert pano.image_bgr.shape == (128, 1024, 3)
    assert pano.azimuth_col0_rad == pytest.approx(math.pi)
    assert pano.fov_v_rad == pytest.approx(math.radians(60))


@pytest.mark.parametrize("dtheta_rad", [0.2, -1.1, 2.5])
def test_rotating_the_robot_shifts_the_panorama_by_dtheta_w_over_2pi(dtheta_rad: float) -> None:
    world = apartment()
    W = 1024
    a = render_panorama(world, Pose2(2.0, 2.0, 0.4), 1.0, W, math.radians(60)).image_bgr.mean(axis=2)
    b = render_panorama(world, Pose2(2.0, 2.0, 0.4 + dtheta_rad), 1.0, W, math.radians(60)).image_bgr.mean(axis=2)
    expected = dtheta_rad * W / (2 * math.pi)  # azimuth decreases to the right: a CCW turn moves the view right
    assert _circular_shift(a, b) == pytest.approx(expected, abs=1.0)


def _wall_height_px(img: np.ndarray) -> float:
    """Apparent height (rows) of the blue wall, skirting included, in the centre column."""
    col = _blueness(img[:, img.shape[1] // 2 - 2 : img.shape[1] // 2 + 3]).mean(axis=1)
    wall = np.median(col[np.argsort(col)[-20:]])
    return float(np.count_nonzero(col > 0.3 * wall))


def test_halving_the_distance_to_a_wall_doubles_its_apparent_height() -> None:
    world = square_room(10.0, BLUE)
    H, fov = 1024, math.radians(100)
    f = 0.5 * H / math.tan(0.5 * fov)
    far = render_panorama(world, Pose2(5.0, 5.0, 0.0), 1.0, 512, fov, height_px=H).image_bgr  # 5 m from the east wall
    near = render_panorama(world, Pose2(7.5, 5.0, 0.0), 1.0, 512, fov, height_px=H).image_bgr  # 2.5 m
    h_far, h_near = _wall_height_px(far), _wall_height_px(near)
    assert h_near / h_far == pytest.approx(2.0, rel=0.02)
    assert h_far == pytest.approx(f * 2.5 / 5.0, abs=2.0)  # cylindrical projection: f·H_wall/d
    assert h_near == pytest.approx(f * 2.5 / 2.5, abs=2.0)


def test_the_horizon_row_sees_the_wall_at_camera_height() -> None:
    """Row H/2 is the horizon: the skirting (0–8 cm) must appear exactly f·(z_cam − 0.04)/d below it."""
    world = square_room(10.0, BLUE)
    H, fov = 512, math.radians(90)
    f = 0.5 * H / math.tan(0.5 * fov)
    img = render_panorama(world, Pose2(7.0, 5.0, 0.0), 1.0, 512, fov, height_px=H).image_bgr
    col = _blueness(img[:, 254:259]).mean(axis=1)
    # the wall/floor boundary: last row that is clearly wall-blue or skirting
    bottom = np.nonzero(col > 0.5 * col.max())[0].max()
    expected = H / 2 + f * 1.0 / 3.0  # floor edge of the wall at d = 3 m
    assert bottom == pytest.approx(expected, abs=1.5)


def test_an_obstacle_occludes_the_wall_behind_it() -> None:
    pillar = Obstacle.box(4.8, 6.8, 5.2, 7.2, 2.5, BLUE, name="pillar")
    world = square_room(10.0, RED, (pillar,))
    W, H, fov = 2048, 256, math.radians(60)
    img = render_panorama(world, Pose2(5.0, 5.0, math.pi / 2), 1.0, W, fov, height_px=H).image_bgr
    f = 0.5 * H / math.tan(0.5 * fov)
    rows = slice(int(H / 2 - f * 1.5 / 5.0) + 4, int(H / 2 + f * 1.0 / 5.0) - 2)  # where the far wall would be
    half = math.atan2(0.2, 1.8)  # the pillar's front face subtends ±6.3°
    centre = W // 2
    inside = slice(centre - int(0.9 * half * W / (2 * math.pi)), centre + int(0.9 * half * W / (2 * math.pi)))
    assert (_redness(img[rows, inside]) < 0).all(), "the red wall shows through the pillar"
    assert (_blueness(img[rows, inside]) > 50).all()
    outside = img[rows, centre + int(1.3 * half * W / (2 * math.pi)) : centre + int(2.0 * half * W / (2 * math.pi))]
    assert (_redness(outside) > 50).all(), "the wall beside the pillar must be visible"


def test_a_low_obstacle_hides_only_the_lower_part_of_the_wall() -> None:
    box = Obstacle.box(4.0, 6.0, 6.0, 6.5, 0.5, BLUE, top=Material("plain", (0.6, 0.6, 0.6)), name="low box")
    world = square_room(10.0, RED, (box,))
    W, H, fov = 1024, 512, math.radians(100)
    f = 0.5 * H / math.tan(0.5 * fov)
    img = render_panorama(world, Pose2(5.0, 5.0, math.pi / 2), 1.0, W, fov, height_px=H).image_bgr
    col = img[:, W // 2 - 1 : W // 2 + 2].astype(float).mean(axis=1)
    # the box's front face (d = 1 m, z 0..0.5) spans rows H/2 + f·0.5 .. H/2 + f·1.0; the wall (d = 5 m) above it
    top_of_front = H / 2 + f * 0.5 / 1.0
    wall_bottom_visible = H / 2 + f * 0.5 / 1.5  # line of sight over the box's back edge (d = 1.5 m, z = 0.5)
    wall_top = H / 2 - f * 1.5 / 5.0
    red = (col[:, 2] - col[:, 0]) > 50
    blue = (col[:, 0] - col[:, 2]) > 50
    assert red[int(wall_top) + 2 : int(wall_bottom_visible) - 2].all()
    assert blue[int(top_of_front) + 2 : int(H / 2 + f * 1.0) - 2].all()
    # between: the box's top (grey, neither paint) is seen at rows wall_bottom_visible .. top_of_front
    assert not red[int(wall_bottom_visible) + 2 : int(top_of_front) - 2].any()
    assert not blue[int(wall_bottom_visible) + 2 : int(top_of_front) - 2].any()


def test_sensor_inside_an_obstacle_is_refused() -> None:
    with pytest.raises(InputError, match="inside an obstacle"):
        render_panorama(apartment(), Pose2(3.75, 1.75, 0.0))


# --------------------------------------------------------------------------
# camera
# --------------------------------------------------------------------------
@pytest.mark.parametrize("x_m, yaw_in_robot_rad", [(5.0, 0.0), (3.5, 0.0), (6.5, 0.3)])
def test_camera_sees_a_pillar_edge_at_its_geometric_azimuth(x_m: float, yaw_in_robot_rad: float) -> None:
    """Parallax: the pillar's left edge is where plane geometry puts it, from several positions."""
    pillar = Obstacle.box(4.8, 6.8, 5.2, 7.2, 2.5, BLUE, name="pillar")
    world = square_room(10.0, RED, (pillar,))
    T = Pose2(x_m, 4.0, math.pi / 2 - 0.1)
    img = render_camera(world, T, PinholeCamera(yaw_in_robot_rad=yaw_in_robot_rad))
    assert isinstance(img, CameraImage) and img.image_bgr.shape == (480, 640, 3)
    row = _blueness(img.image_bgr[230:250]).mean(axis=0)
    blue_cols = np.nonzero(row > 0)[0]
    u_left = blue_cols.min() - 0.5  # boundary between last red and first blue column
    # the visible left silhouette corner of the pillar (seen from below-left or below-right)
    corners = np.array([[4.8, 6.8], [5.2, 6.8], [5.2, 7.2], [4.8, 7.2]])
    az = np.arctan2(corners[:, 1] - T.y, corners[:, 0] - T.x) - T.theta
    expected = float(az.max())  # the leftmost corner in azimuth
    f = img.focal_px
    assert float(img.azimuth_of_column(u_left)) == pytest.approx(expected, abs=1.0 / f)


def test_camera_centre_column_looks_along_the_camera_yaw() -> None:
    """A vertical pillar straight ahead of a yawed camera is centred in its image."""
    pillar = Obstacle.box(6.9, 6.9, 7.1, 7.1, 2.5, BLUE, name="pillar")
    world = square_room(10.0, RED, (pillar,))
    T = Pose2(5.0, 5.0, 0.2)
    yaw = math.atan2(2.0, 2.0) - 0.2
    img = render_camera(world, T, PinholeCamera(yaw_in_robot_rad=yaw)).image_bgr
    cols = np.nonzero(_blueness(img[235:245]).mean(axis=0) > 0)[0]
    assert (cols.min() + cols.max()) / 2 == pytest.approx(319.5, abs=1.0)


# --------------------------------------------------------------------------
# depth
# --------------------------------------------------------------------------
def _surface_distance(world: World, pts_world: np.ndarray) -> np.ndarray:
    """Distance of each world point to the nearest plan surface (walls, obstacle faces and tops, floor, ceiling)."""
    seg = world.segments
    p = pts_world
    e = seg.p1 - seg.p0
    rel = p[:, None, :2] - seg.p0[None]
    t = np.clip((rel * e[None]).sum(-1) / (e * e).sum(-1)[None], 0, 1)
    d2 = np.linalg.norm(rel - t[..., None] * e[None], axis=2)
    d2 = np.where((p[:, 2:3] >= -1e-6) & (p[:, 2:3] <= seg.height_m[None] + 1e-6), d2, np.inf)
    best = np.minimum(d2.min(axis=1), np.minimum(np.abs(p[:, 2]), np.abs(p[:, 2] - world.wall_height_m)))
    for ob in world.obstacles:
        from matplotlib.path import Path as MplPath

        inside = MplPath(np.asarray(ob.vertices_xy)).contains_points(p[:, :2])
        best = np.where(inside, np.minimum(best, np.abs(p[:, 2] - ob.height_m)), best)
    return best


def _to_world(cloud: PointCloud, T: Pose2) -> np.ndarray:
    return np.column_stack([T.transform_points(cloud.points_m[:, :2]), cloud.points_m[:, 2]])


@pytest.mark.parametrize("pose", [Pose2(3.0, 2.2, 0.3), Pose2(8.0, 4.1, math.pi), Pose2(8.0, 6.0, -0.4), Pose2(1.0, 1.5, -1.2)])
def test_noise_free_cloud_points_lie_on_plan_surfaces(pose: Pose2) -> None:
    world = apartment()
    cloud = render_cloud(world, pose, DepthCamera(), rng=None)
    assert isinstance(cloud, PointCloud) and len(cloud) > 1000
    d = _surface_distance(world, _to_world(cloud, pose))
    assert d.max() < 2e-5  # float32 rounding only


def test_noisy_cloud_points_lie_within_the_noise_of_plan_surfaces() -> None:
    world, pose, cam = apartment(), Pose2(3.0, 2.2, 0.3), DepthCamera()
    noisy = render_cloud(world, pose, cam, np.random.default_rng(7))
    depth = noisy.points_m[:, 0]
    d = _surface_distance(world, _to_world(noisy, pose))
    assert np.mean(d < 4.0 * cam.noise_sigma_m(depth) + 1e-5) > 0.999


def test_depth_noise_has_the_published_standard_deviation() -> None:
    world, pose, cam = apartment(), Pose2(3.0, 2.2, 0.3), DepthCamera()
    clean = render_cloud(world, pose, cam, None).points_m
    noisy = render_cloud(world, pose, cam, np.random.default_rng(3)).points_m
    depth = clean[:, 0]  # camera yaw 0: depth is the robot-frame x
    ray_error = (np.linalg.norm(noisy - [0, 0, cam.height_m], axis=1) - np.linalg.norm(clean - [0, 0, cam.height_m], axis=1)) * (
        depth / np.linalg.norm(clean - [0, 0, cam.height_m], axis=1)
    )
    z = ray_error / (0.0012 + 0.0019 * (depth - 0.4) ** 2)
    assert np.std(z) == pytest.approx(1.0, abs=0.03)
    assert abs(np.mean(z)) < 0.02


def test_cloud_respects_the_depth_range_and_field_of_view() -> None:
    cam = DepthCamera()
    pts = render_cloud(apartment(), Pose2(5.0, 4.1, 0.0), cam, None).points_m  # looking down the corridor
    assert pts[:, 0].min() >= 0.4 - 1e-6 and pts[:, 0].max() <= 4.5 + 1e-6
    az = np.arctan2(pts[:, 1], pts[:, 0])
    assert np.abs(az).max() <= math.radians(29.0) + 1e-6
    assert len(pts) <= 320 * 240


def test_glass_returns_no_depth() -> None:
    """The corridor's east end (x = 10) is a glass door: the depth camera sees nothing on it."""
    pose = Pose2(8.0, 4.1, 0.0)
    pts = _to_world(render_cloud(apartment(), pose, DepthCamera(), None), pose)
    on_glass = (np.abs(pts[:, 0] - 10.0) < 0.01) & (pts[:, 1] > 3.5) & (pts[:, 1] < 4.7) & (pts[:, 2] > 0.05) & (pts[:, 2] < 2.45)
    assert on_glass.sum() == 0
    assert len(pts) > 1000  # the corridor walls still return


def test_360_cloud_covers_every_direction() -> None:
    pose = Pose2(3.0, 2.2, 0.3)
    cloud = render_cloud_360(apartment(), pose, DepthCamera(stride_px=4), None)
    az = np.arctan2(cloud.points_m[:, 1], cloud.points_m[:, 0])
    hist, _ = np.histogram(az, bins=36, range=(-math.pi, math.pi))
    assert hist.min() > 0
    assert _surface_distance(apartment(), _to_world(cloud, pose)).max() < 2e-5


def test_scan_points_lie_on_walls() -> None:
    pose = Pose2(3.0, 2.2, 0.3)
    scan = render_scan(apartment(), pose, n_beams=720, height_m=0.3)
    pts = np.column_stack([pose.transform_points(scan.points_m), np.full(len(scan), 0.3)])
    assert len(scan) > 600
    assert _surface_distance(apartment(), pts).max() < 2e-5


def test_bad_sensor_inputs_are_refused_with_the_field_named() -> None:
    w = apartment()
    with pytest.raises(InputError, match="sensor height 3.0 m"):
        render_panorama(w, Pose2(2.6, 2.2, 0.0), height_m=3.0)
    with pytest.raises(InputError, match="camera must be a PinholeCamera"):
        render_camera(w, Pose2(2.6, 2.2, 0.0), DepthCamera())
    with pytest.raises(InputError, match="T_world_robot must be a Pose2"):
        render_cloud(w, (2.6, 2.2, 0.0))
    with pytest.raises(InputError, match="DepthCamera.max_range_m"):
        DepthCamera(min_range_m=2.0, max_range_m=1.0)
    with pytest.raises(InputError, match="PinholeCamera.hfov_rad"):
        PinholeCamera(hfov_rad=4.0)


# --------------------------------------------------------------------------
# render_scan's real-lidar error model
# --------------------------------------------------------------------------
_WHITE_ONLY = dict(systematic_sigma_m=0.0, beam_divergence_rad=0.0, spot_exit_m=0.0, pose_sigma_m=0.0, pose_sigma_rad=0.0)


def _range_errors(world: World, pose: Pose2, rng: np.random.Generator, **kw) -> np.ndarray:
    exact = np.hypot(*render_scan(world, pose, n_beams=720).points_m.T)
    noisy = np.hypot(*render_scan(world, pose, n_beams=720, rng=rng, **kw).points_m.T)
    return noisy - exact


def test_scan_statistical_noise_is_white_with_the_given_sigma() -> None:
    rng = np.random.default_rng(1)
    e = np.concatenate([_range_errors(square_room(), Pose2(3.0, 4.0, 0.2), rng, sigma_m=0.005, **_WHITE_ONLY) for _ in range(5)])
    assert np.std(e) == pytest.approx(0.005, rel=0.05)
    assert abs(np.corrcoef(e[:-1], e[1:])[0, 1]) < 0.05  # independent from beam to beam


def test_scan_systematic_error_is_one_offset_per_wall_and_scan() -> None:
    # without statistical noise and mixed pixels, every beam on a wall carries that wall's offset
    world, pose = square_room(), Pose2(3.0, 4.0, 0.2)
    rng = np.random.default_rng(2)
    offsets = []
    for _ in range(100):
        e = _range_errors(world, pose, rng, **{**_WHITE_ONLY, "sigma_m": 0.0, "systematic_sigma_m": 0.0075})
        v = np.sort(e)
        groups = np.split(v, np.flatnonzero(np.diff(v) > 1e-5) + 1)  # points are stored as float32: 10 µm apart
        assert len(groups) <= 4  # four walls, four offsets
        assert max(float(g.max() - g.min()) for g in groups) < 1e-5
        offsets.extend(float(g.mean()) for g in groups)
    # a fresh offset per scan: 100 scans × 4 walls, σ as asked
    assert np.std(offsets) == pytest.approx(0.0075, rel=0.15)
    assert abs(np.mean(offsets)) < 0.002


def test_scan_mixed_pixels_fall_between_the_edge_surfaces() -> None:
    # a pillar 2 m in front of the far wall: beams next to its edges may return a range in between
    pillar = Obstacle(((6.0, 4.8), (6.4, 4.8), (6.4, 5.2), (6.0, 5.2)), 2.5)
    world, pose = square_room(obstacles=(pillar,)), Pose2(2.0, 5.0, 0.0)
    exact = render_scan(world, pose, n_beams=720)
    rng = np.random.default_rng(3)
    between = 0
    for _ in range(20):
        pts = pose.transform_points(
            render_scan(
                world, pose, n_beams=720, rng=rng, sigma_m=0.0, systematic_sigma_m=0.0, pose_sigma_m=0.0, pose_sigma_rad=0.0
            ).points_m
        )
        x = pts[:, 0]
        in_gap = (x > 6.5) & (x < 9.9) & (np.abs(pts[:, 1] - 5.0) < 0.5)  # free space behind the pillar
        between += int(in_gap.sum())
    assert between > 0  # spots straddling the pillar's edges (4.6 mrad divergence, 0.5° beams) give phantom points
    assert between < 20 * 6  # but only at the edges: at most a few beams per scan
    no_mix = render_scan(world, pose, n_beams=720, rng=rng, sigma_m=0.0, **_WHITE_ONLY)
    assert np.allclose(no_mix.points_m, exact.points_m)


def test_scan_sensor_pose_error_moves_the_whole_scan_rigidly_with_the_given_sigma() -> None:
    # without range errors, a scan with the sensor-pose error is the exact scan of a slightly moved sensor: ICP
    # against the exact scan recovers one rigid motion per scan, with the σ asked for
    from factorloc.registration.icp2d import align, prepare_target

    world, pose = square_room(), Pose2(3.0, 4.0, 0.2)
    exact = render_scan(world, pose, n_beams=720).points_m
    target = prepare_target(exact)
    rng = np.random.default_rng(4)
    offsets = []
    for _ in range(60):
        moved = render_scan(
            world, pose, n_beams=720, rng=rng, sigma_m=0.0, **{**_WHITE_ONLY, "pose_sigma_m": 0.02, "pose_sigma_rad": 0.01}
        )
        r = align(target, moved.points_m, Pose2())
        assert r.rmse_m < 5e-3  # a rigid motion of the whole scan (residuals from the corners only)
        offsets.append((r.T_target_source.x, r.T_target_source.y, r.T_target_source.theta))
    o = np.array(offsets)
    assert np.std(o[:, :2]) == pytest.approx(0.02, rel=0.25)
    assert np.std(o[:, 2]) == pytest.approx(0.01, rel=0.25)
    assert np.allclose(render_scan(world, pose, n_beams=720, rng=rng, sigma_m=0.0, **_WHITE_ONLY).points_m, exact)


def test_scan_error_model_leaves_the_callers_random_stream_as_before() -> None:
    # the statistical noise takes n_beams normals from rng; the rest comes from a spawned child
    world, pose = apartment(), Pose2(3.0, 2.2, 0.3)
    a = np.random.default_rng(5)
    render_scan(world, pose, rng=a)
    b = np.random.default_rng(5)
    b.normal(0.0, 1.0, 360)
    assert a.random(4).tolist() == b.random(4).tolist()


def test_scan_error_model_parameters_are_checked() -> None:
    with pytest.raises(InputError, match="systematic_sigma_m"):
        render_scan(apartment(), Pose2(3.0, 2.2, 0.3), systematic_sigma_m=-0.01)
    with pytest.raises(InputError, match="mixed_min_jump_m"):
        render_scan(apartment(), Pose2(3.0, 2.2, 0.3), mixed_min_jump_m=0.0)

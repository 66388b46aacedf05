"""The scenario format: exact round trip, and one clear error per kind of damage."""

from __future__ import annotations

import math
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import yaml

from factorloc import CameraImage, Odometry, Panorama, PointCloud, Pose2, Query, Reference, Scan
from factorloc.datasets import Scenario, ScenarioQuery, ScenarioReference, load_scenario, save_scenario
from factorloc.errors import DatasetError, InputError
from factorloc.sim import apartment


def _img(rng: np.random.Generator, h: int, w: int) -> np.ndarray:
    return rng.integers(0, 256, (h, w, 3), dtype=np.uint8)


def make_scenario(seed: int = 0, with_world: bool = True) -> Scenario:
    rng = np.random.default_rng(seed)
    ref = Reference(
        Panorama(_img(rng, 32, 256), math.radians(55.0)),
        PointCloud(rng.normal(size=(500, 3))),  # float64: not float32-exact
        Scan(rng.normal(size=(90, 2)).astype(np.float32).astype(np.float64)),
        Pose2(2.6, 2.2, 0.1),
        "living room",
    )
    queries = []
    for i in range(3):
        images = (
            CameraImage(_img(rng, 48, 64), math.radians(57.0), 0.3 * i),
            CameraImage(_img(rng, 48, 64), math.radians(40.0), -0.5, 0.05, 30.5),
        )
        odo = Odometry(Pose2(1.0 + i, 2.0, -0.3 * i), 0.05 * (i + 1), 0.07, 0.02)
        cloud = PointCloud(rng.normal(size=(200, 3)).astype(np.float32).astype(np.float64)) if i != 1 else None
        q = Query(images, None, cloud, None, odo, f"q{i:03d}")
        queries.append(
            ScenarioQuery(
                q,
                timestamp_s=10.0 * i + 0.25,
                truth=Pose2(1.1 + i, 2.05, -0.3 * i + 0.01) if i != 2 else None,
                faults=("occlusion", "lighting") if i == 1 else (),
                reference_id="ref0",
                distance_from_reference_m=1.5 + i if i != 0 else None,
                metadata={"path_length_m": 2.0 + i, "notes": ["a", "b"]},
            )
        )
    pano_query = Query((), Panorama(_img(rng, 16, 128)), None, Scan(np.array([[1.0, 2.0], [3.0, 4.0]])), None, "qpano")
    queries.append(ScenarioQuery(pano_query, 99.0))
    return Scenario(
        name="hand-made",
        references=(ScenarioReference("ref0", ref, {"height_m": 1.0}),),
        queries=tuple(queries),
        world=apartment() if with_world else None,
        seed=seed,
        description="a small scenario for the format tests",
        metadata={"generator": "tests", "nested": {"k": [1, 2.5, None]}},
    )


@pytest.fixture
def saved(tmp_path: Path) -> Path:
    return save_scenario(make_scenario(), tmp_path / "scen")


def _edit_manifest(root: Path, edit) -> None:  # noqa: ANN001
    m = yaml.safe_load((root / "scenario.yaml").read_text())
    edit(m)
    (root / "scenario.yaml").write_text(yaml.safe_dump(m, sort_keys=False))


# --------------------------------------------------------------------------
# round trip
# --------------------------------------------------------------------------
def test_load_of_save_equals_the_original(saved: Path) -> None:
    original = make_scenario()
    loaded = load_scenario(saved)
    assert loaded == original
    assert loaded.reference.cloud.points_m.dtype == np.float64
    assert np.array_equal(loaded.reference.cloud.points_m, original.reference.cloud.points_m)
    assert loaded.queries[0].query.images[1].cx_px == 30.5


def test_equality_sees_a_one_pixel_change(saved: Path) -> None:
    loaded = load_scenario(saved)
    img = cv2.imread(str(saved / "queries/q000/image0.png"))
    img[3, 4, 1] ^= 1
    cv2.imwrite(str(saved / "queries/q000/image0.png"), img)
    assert load_scenario(saved) != loaded


def test_float32_exact_clouds_are_stored_as_float32(saved: Path) -> None:
    assert np.load(saved / "queries/q000/cloud.npy").dtype == np.float32
    assert np.load(saved / "references/ref0/cloud.npy").dtype == np.float64  # not float32-exact: kept


def test_jpeg_images_load_close_to_the_original(tmp_path: Path) -> None:
    s = make_scenario(with_world=False)
    root = save_scenario(s, tmp_path / "jpg", image_format="jpg", jpeg_quality=95)
    loaded = load_scenario(root)
    assert (root / "queries/q000/image0.jpg").is_file()
    assert loaded.reference.panorama.image_bgr.tobytes() == s.reference.panorama.image_bgr.tobytes()  # panoramas stay PNG
    assert loaded.queries[0].query.images[0].image_bgr.shape == (48, 64, 3)


def test_save_refuses_to_overwrite_unless_asked(saved: Path) -> None:
    with pytest.raises(InputError, match="not empty"):
        save_scenario(make_scenario(), saved)
    save_scenario(make_scenario(1), saved, overwrite=True)
    assert load_scenario(saved) == make_scenario(1)


def test_a_hand_written_minimal_scenario_loads(tmp_path: Path) -> None:
    """The minimal example of docs/data-format.md: one reference panorama, one query image, odometry."""
    root = tmp_path / "mini"
    (root / "ref").mkdir(parents=True)
    cv2.imwrite(str(root / "ref" / "pano.png"), np.full((64, 512, 3), 128, np.uint8))
    cv2.imwrite(str(root / "q1.jpg"), np.full((480, 640, 3), 90, np.uint8))
    (root / "scenario.yaml").write_text(
        """
format: factorloc-scenario
format_version: 1
name: my-robot
references:
  - id: kitchen
    T_world_reference: {x_m: 0.0, y_m: 0.0, theta_rad: 0.0}
    panorama: {file: ref/pano.png, fov_v_rad: 1.0}
queries:
  - id: q1
    odometry: {x_m: 0.5, y_m: 0.1, theta_rad: 0.2, sigma_x_m: 0.05, sigma_y_m: 0.05, sigma_theta_rad: 0.1}
    images:
      - {file: q1.jpg, hfov_rad: 0.995}
"""
    )
    s = load_scenario(root / "scenario.yaml")
    assert s.reference.panorama.width_px == 512
    q = s.queries[0]
    assert q.id == "q1" and q.reference_id == "kitchen" and q.truth is None and q.faults == ()
    assert q.query.odometry.T_world_robot == Pose2(0.5, 0.1, 0.2)
    assert q.query.images[0].hfov_rad == 0.995


# --------------------------------------------------------------------------
# damage: one test per kind
# --------------------------------------------------------------------------
def test_missing_directory(tmp_path: Path) -> None:
    with pytest.raises(DatasetError, match="does not exist"):
        load_scenario(tmp_path / "nowhere")


def test_missing_manifest(saved: Path) -> None:
    (saved / "scenario.yaml").unlink()
    with pytest.raises(DatasetError, match="scenario.yaml does not exist"):
        load_scenario(saved)


def test_unparseable_manifest(saved: Path) -> None:
    (saved / "scenario.yaml").write_text("format: [unclosed\n")
    with pytest.raises(DatasetError, match="cannot be parsed as YAML"):
        load_scenario(saved)


def test_unknown_version(saved: Path) -> None:
    _edit_manifest(saved, lambda m: m.update(format_version=2))
    with pytest.raises(DatasetError, match=r"scenario.yaml: field 'format_version': unknown version 2"):
        load_scenario(saved)


def test_wrong_format_name(saved: Path) -> None:
    _edit_manifest(saved, lambda m: m.update(format="rosbag"))
    with pytest.raises(DatasetError, match="field 'format'"):
        load_scenario(saved)


def test_missing_image_file(saved: Path) -> None:
    (saved / "queries/q001/image1.png").unlink()
    with pytest.raises(DatasetError, match=r"field 'queries\[1\]\.images\[1\]\.file'.*q001/image1.png.*does not exist"):
        load_scenario(saved)


def test_missing_cloud_file(saved: Path) -> None:
    (saved / "references/ref0/cloud.npy").unlink()
    with pytest.raises(DatasetError, match=r"references\[0\]\.cloud\.file"):
        load_scenario(saved)


def test_wrong_image_size(saved: Path) -> None:
    cv2.imwrite(str(saved / "queries/q002/image0.png"), np.zeros((40, 64, 3), np.uint8))
    with pytest.raises(DatasetError, match=r"queries\[2\]\.images\[0\]': wrong image size.*64×40 px, the manifest says 64×48"):
        load_scenario(saved)


def test_unreadable_image(saved: Path) -> None:
    (saved / "references/ref0/panorama.png").write_bytes(b"not a png")
    with pytest.raises(DatasetError, match=r"references\[0\]\.panorama\.file.*not a readable image"):
        load_scenario(saved)


def test_nan_truth_pose(saved: Path) -> None:
    _edit_manifest(saved, lambda m: m["queries"][0]["truth"].update(x_m=float("nan")))
    with pytest.raises(DatasetError, match=r"field 'queries\[0\]\.truth\.x_m': must be finite"):
        load_scenario(saved)


def test_nan_odometry_heading(saved: Path) -> None:
    _edit_manifest(saved, lambda m: m["queries"][1]["odometry"].update(theta_rad=float("inf")))
    with pytest.raises(DatasetError, match=r"queries\[1\]\.odometry\.theta_rad"):
        load_scenario(saved)


def test_non_positive_sigma(saved: Path) -> None:
    _edit_manifest(saved, lambda m: m["queries"][0]["odometry"].update(sigma_y_m=0.0))
    with pytest.raises(DatasetError, match=r"queries\[0\]\.odometry\.sigma_y_m': must be > 0"):
        load_scenario(saved)


def test_missing_field(saved: Path) -> None:
    _edit_manifest(saved, lambda m: m["references"][0].pop("T_world_reference"))
    with pytest.raises(DatasetError, match=r"field 'references\[0\]\.T_world_reference': is missing"):
        load_scenario(saved)


def test_non_numeric_field(saved: Path) -> None:
    _edit_manifest(saved, lambda m: m["queries"][0]["images"][0].update(hfov_rad="wide"))
    with pytest.raises(DatasetError, match=r"queries\[0\]\.images\[0\]\.hfov_rad': must be a real number"):
        load_scenario(saved)


def test_nan_in_a_cloud_file(saved: Path) -> None:
    pts = np.load(saved / "queries/q000/cloud.npy")
    pts[5, 1] = np.nan
    np.save(saved / "queries/q000/cloud.npy", pts)
    with pytest.raises(DatasetError, match=r"queries\[0\]\.cloud\.file.*NaN"):
        load_scenario(saved)


def test_cloud_of_the_wrong_shape(saved: Path) -> None:
    np.save(saved / "queries/q000/cloud.npy", np.zeros((10, 2), np.float32))
    with pytest.raises(DatasetError, match=r"N×3 array, got shape \(10, 2\)"):
        load_scenario(saved)


def test_cloud_point_count_mismatch(saved: Path) -> None:
    _edit_manifest(saved, lambda m: m["queries"][0]["cloud"].update(points=7))
    with pytest.raises(DatasetError, match=r"queries\[0\]\.cloud\.points': says 7 points"):
        load_scenario(saved)


def test_duplicate_query_ids(saved: Path) -> None:
    _edit_manifest(saved, lambda m: m["queries"][1].update(id="q000"))
    with pytest.raises(DatasetError, match="repeats the id 'q000'"):
        load_scenario(saved)


def test_unknown_reference_id(saved: Path) -> None:
    _edit_manifest(saved, lambda m: m["queries"][0].update(reference="ref9"))
    with pytest.raises(DatasetError, match="names reference 'ref9'"):
        load_scenario(saved)


def test_file_outside_the_scenario(saved: Path, tmp_path: Path) -> None:
    shutil.copy(saved / "queries/q000/image0.png", tmp_path / "outside.png")
    _edit_manifest(saved, lambda m: m["queries"][0]["images"][0].update(file="../outside.png"))
    with pytest.raises(DatasetError, match="outside the scenario directory"):
        load_scenario(saved)


def test_damaged_world_file(saved: Path) -> None:
    (saved / "world.yaml").write_text("format_version: 1\nname: x\nwalls: [{start_xy: [0, 0]}]\n")
    with pytest.raises(DatasetError, match=r"field 'world'.*end_xy"):
        load_scenario(saved)


def test_empty_references(saved: Path) -> None:
    _edit_manifest(saved, lambda m: m.update(references=[]))
    with pytest.raises(DatasetError, match="field 'references': must be a non-empty list"):
        load_scenario(saved)


# --------------------------------------------------------------------------
# in-memory validation
# --------------------------------------------------------------------------
def test_scenario_rejects_bad_ids_and_types() -> None:
    s = make_scenario(with_world=False)
    with pytest.raises(InputError, match="identifier"):
        ScenarioReference("bad/id", s.reference)
    with pytest.raises(InputError, match="timestamp_s"):
        ScenarioQuery(s.queries[0].query, float("nan"))
    with pytest.raises(InputError, match="YAML-able"):
        ScenarioQuery(s.queries[0].query, metadata={"obj": object()})


def test_reference_property_needs_exactly_one_reference() -> None:
    s = make_scenario(with_world=False)
    two = Scenario("two", (s.references[0], ScenarioReference("ref1", s.reference)), s.queries)
    with pytest.raises(InputError, match="2 references"):
        _ = two.reference
    assert two.reference_of(two.queries[0]) is s.reference


def test_clouds_may_be_npz_or_ply(saved: Path) -> None:
    import open3d as o3d

    pts = np.load(saved / "queries/q000/cloud.npy")
    np.savez_compressed(saved / "queries/q000/cloud.npz", points_m=pts)
    q2 = np.load(saved / "queries/q002/cloud.npy")
    pc2 = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(q2.astype(np.float64)))
    o3d.io.write_point_cloud(str(saved / "queries/q002/cloud.ply"), pc2)

    def edit(m: dict) -> None:
        m["queries"][0]["cloud"]["file"] = "queries/q000/cloud.npz"
        m["queries"][2]["cloud"]["file"] = "queries/q002/cloud.ply"

    _edit_manifest(saved, edit)
    loaded = load_scenario(saved)
    assert np.array_equal(loaded.queries[0].query.cloud.points_m, pts.astype(np.float64))
    assert np.allclose(loaded.queries[2].query.cloud.points_m, q2, atol=1e-6)
    np.savez(saved / "queries/q000/cloud.npz", other=pts)
    with pytest.raises(DatasetError, match="has no array 'points_m'"):
        load_scenario(saved)

"""World model: files, validation, geometry queries, offline textures."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from factorloc.errors import InputError
from factorloc.sim import (
    BASE_TEXTURES,
    DECAL_IMAGES,
    Face,
    Material,
    Obstacle,
    Wall,
    World,
    apartment,
    builtin_worlds,
    load_world,
    save_world,
    world_by_name,
)
from factorloc.sim.textures import atlas_of, base_texture, decal_image


def test_apartment_is_a_ten_by_eight_plan_with_rooms_doors_and_a_corridor() -> None:
    w = apartment()
    assert "apartment" in builtin_worlds()
    assert w.bounds_xy == (0.0, 0.0, 10.0, 8.0)
    assert len(w.walls) >= 20 and len(w.obstacles) >= 5
    assert w.region("corridor") is not None and w.region("reference") is not None
    # doors: a straight line from the living room to the bedroom through the corridor is open
    assert w.line_of_sight(np.array([[1.6, 2.0]]), np.array([[3.6, 6.0]]))[0]
    # …and walls block elsewhere
    assert not w.line_of_sight(np.array([[1.0, 2.0]]), np.array([[1.0, 6.0]]))[0]
    plain = [f for f in w.segments.faces if f.material.texture == "plain" and not f.decals]
    assert len(plain) >= 5  # some low-texture walls, as in real flats


@pytest.mark.parametrize("suffix", [".yaml", ".json"])
def test_world_file_round_trip(tmp_path: Path, suffix: str) -> None:
    w = apartment()
    path = save_world(w, tmp_path / f"w{suffix}")
    assert load_world(path) == w
    assert world_by_name(str(path)) == w


def test_world_file_errors_name_the_field(tmp_path: Path) -> None:
    p = tmp_path / "bad.yaml"
    p.write_text("format_version: 1\nname: x\nwalls:\n  - {start_xy: [0, 0], end_xy: [1, 0], colour: red}\n")
    with pytest.raises(InputError, match=r"bad.yaml.*walls\[0\] has unknown key\(s\) \['colour'\]"):
        load_world(p)
    p.write_text("format_version: 9\nname: x\n")
    with pytest.raises(InputError, match="unknown world format version 9"):
        load_world(p)
    with pytest.raises(InputError, match="does not exist"):
        load_world(tmp_path / "missing.yaml")
    with pytest.raises(InputError, match="neither a built-in world"):
        world_by_name("castle")


def test_invalid_geometry_is_refused() -> None:
    with pytest.raises(InputError, match="counter-clockwise"):
        Obstacle(((0, 0), (0, 1), (1, 1), (1, 0)), 1.0)  # clockwise
    with pytest.raises(InputError, match="exceeds wall_height_m"):
        World("w", (Wall((0, 0), (1, 0)),), (Obstacle.box(0, 0, 1, 1, 3.0),), wall_height_m=2.5)
    with pytest.raises(InputError, match="zero length"):
        Wall((1, 1), (1, 1))
    with pytest.raises(InputError, match="tint_bgr"):
        Material("brick", (3.0, 1.0, 1.0))


def test_unknown_texture_is_refused_when_baking() -> None:
    w = World("w", (Wall((0, 0), (4, 0), Face(Material("marble"))),))
    with pytest.raises(InputError, match="Material.texture must be one of"):
        atlas_of(w)


def test_every_texture_and_decal_is_available_offline() -> None:
    for name in BASE_TEXTURES:
        tile = base_texture(name)
        assert tile.dtype == np.uint8 and tile.ndim == 3 and min(tile.shape[:2]) >= 256
    for name in DECAL_IMAGES:
        img = decal_image(name)
        assert img.dtype == np.uint8 and img.shape[2] == 3 and img.std() > 5  # a real picture, not a flat fill


def test_plain_paint_is_low_texture_and_photos_are_not() -> None:
    assert base_texture("plain").std() < 4.0
    assert base_texture("brick").std() > 25.0


def test_clearance_and_free_space() -> None:
    w = apartment()
    pts = np.array([[2.6, 2.2], [0.1, 2.0], [3.75, 1.75], [5.0, 4.1]])
    d = w.clearance(pts)
    assert d[0] > 0.8
    assert d[1] == pytest.approx(0.1)  # 10 cm from the west wall
    assert d[2] == 0.0  # inside the pillar
    assert d[3] == pytest.approx(0.6, abs=1e-9)  # corridor centre: 0.6 m to both walls
    assert w.is_free(pts, 0.3).tolist() == [True, False, False, True]

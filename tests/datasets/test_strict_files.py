"""Issue #21, reproducer 6: the scenario reader is strict — unknown keys named with the nearest known one, ``id:
null`` refused, point files checked against what their headers claim before anything is allocated, YAML alias
expansion bounded — each a :class:`DatasetError` naming the manifest field or the file."""

from __future__ import annotations

import io
import shutil
import zipfile
from pathlib import Path

import numpy as np
import pytest
import yaml

from factorloc._yaml import MAX_ALIAS_EXPANSION, YamlLimitError, load_yaml
from factorloc.datasets import load_scenario
from factorloc.datasets.points_io import read_npy, read_npz, read_ply
from factorloc.errors import DatasetError

SAMPLE = Path(__file__).resolve().parents[2] / "data" / "sample"


@pytest.fixture
def sample(tmp_path: Path) -> Path:
    root = tmp_path / "s"
    shutil.copytree(SAMPLE, root)
    return root


def _replace(root: Path, old: str, new: str) -> None:
    p = root / "scenario.yaml"
    text = p.read_text()
    assert old in text
    p.write_text(text.replace(old, new, 1))


@pytest.mark.parametrize(
    ("old", "new", "field", "hint"),
    [
        ("  odometry:", "  odometery:", "queries[0]", "odometry"),
        ("references:\n- id", "refrences:\n- id", "(top level)", "references"),
        ("  scan:\n    file: queries", "  sacn:\n    file: queries", "queries[0]", "scan"),
        ("    x_m: 2.5999999999999996", "    xm: 2.5999999999999996", "references[0].T_world_reference", "x_m"),
    ],
)
def test_a_misspelt_key_is_an_error_naming_it_and_the_nearest_known(sample, old, new, field, hint):
    _replace(sample, old, new)
    with pytest.raises(DatasetError, match=rf"field '{__import__('re').escape(field)}': has unknown key.*did you mean '{hint}'"):
        load_scenario(sample)


def test_a_null_id_is_refused(sample):
    _replace(sample, "- id: ref0", "- id: null")
    with pytest.raises(DatasetError, match=r"references\[0\].id': must be a string, got NoneType"):
        load_scenario(sample)


def test_a_400_digit_integer_is_a_typed_error(sample):
    _replace(sample, "timestamp_s: 5.0", "timestamp_s: " + "9" * 400)
    with pytest.raises(DatasetError, match=r"timestamp_s': must be finite"):
        load_scenario(sample)
    _replace(sample, "timestamp_s: " + "9" * 400, "timestamp_s: " + "9" * 5000)  # beyond Python's int parsing
    with pytest.raises(DatasetError, match="cannot be parsed as YAML"):
        load_scenario(sample)


def test_a_yaml_alias_bomb_in_the_metadata_is_refused(sample):
    levels = ["a: &a [" + ",".join(["x"] * 10) + "]"]
    levels += [f"  {c}: &{c} [" + ",".join([f"*{p}"] * 10) + "]" for p, c in zip("abcdefgh", "bcdefghi", strict=True)]
    _replace(sample, "metadata:\n  generator", "metadata:\n  " + "\n".join(levels) + "\n  generator")
    with pytest.raises(DatasetError, match="alias bomb"):
        load_scenario(sample)


def test_load_yaml_bounds_aliases_but_keeps_a_few():
    assert load_yaml("a: &x [1, 2]\nb: *x") == {"a": [1, 2], "b": [1, 2]}
    with pytest.raises(YamlLimitError, match="recursive"):
        load_yaml("&a [*a]")
    wide = "a: &a [" + ",".join(["0"] * 1000) + "]\nb: [" + ",".join(["*a"] * (MAX_ALIAS_EXPANSION // 1000 + 1)) + "]"
    with pytest.raises(YamlLimitError, match="expand"):
        load_yaml(wide)
    with pytest.raises(yaml.YAMLError):  # libyaml refuses the nesting itself
        load_yaml("[" * 100_000 + "]" * 100_000)


def test_npy_header_claiming_more_rows_than_the_file_holds(tmp_path):
    p = tmp_path / "scan.npy"
    np.save(p, np.zeros((4, 2)))
    raw = p.read_bytes().replace(b"(4, 2)", b"(1000000000000, 2)".ljust(6))
    p.write_bytes(raw)
    with pytest.raises(DatasetError, match="more than the"):
        read_npy(p)
    np.save(p, np.zeros((4, 2)))
    p.write_bytes(p.read_bytes()[:-8])  # one value short
    with pytest.raises(DatasetError, match="header says shape"):
        read_npy(p)
    np.save(p, np.arange(8.0).reshape(4, 2))
    assert read_npy(p).tolist() == np.arange(8.0).reshape(4, 2).tolist()


def test_a_corrupt_npz_is_a_dataset_error(tmp_path):
    p = tmp_path / "c.npz"
    p.write_bytes(b"PK\x03\x04 not a zip at all")
    with pytest.raises(DatasetError, match="not a readable .npz"):
        read_npz(p)
    head = io.BytesIO()
    np.lib.format.write_array_header_1_0(head, {"descr": "<f8", "fortran_order": False, "shape": (10**12, 3)})
    with zipfile.ZipFile(p, "w") as z:
        z.writestr("points_m.npy", head.getvalue())  # the header alone, no data
    with pytest.raises(DatasetError, match="header says shape"):
        read_npz(p)
    np.savez_compressed(p, points_m=np.ones((5, 3)))
    assert read_npz(p).shape == (5, 3)


def _ply(n_claimed: int, rows: np.ndarray, binary: bool) -> bytes:
    fmt = "binary_little_endian" if binary else "ascii"
    props = "".join(f"property double {c}\n" for c in "xyz")
    head = f"ply\nformat {fmt} 1.0\nelement vertex {n_claimed}\n{props}end_header\n"
    body = rows.astype("<f8").tobytes() if binary else "".join(" ".join(map(str, r)) + "\n" for r in rows).encode()
    return head.encode() + body


@pytest.mark.parametrize("binary", [True, False])
def test_a_ply_shorter_than_its_header_says_is_refused(tmp_path, binary):
    p = tmp_path / "c.ply"
    pts = np.arange(15.0).reshape(5, 3)
    p.write_bytes(_ply(5, pts, binary))
    assert read_ply(p).tolist() == pts.tolist()
    p.write_bytes(_ply(5, pts[:3], binary))  # the corrupt .ply: 5 claimed, 3 present
    with pytest.raises(DatasetError, match="header says 5 vertices"):
        read_ply(p)


def test_a_corrupt_ply_in_a_scenario_names_the_field(sample):
    ply = sample / "queries" / "q0000" / "scan.ply"
    ply.write_bytes(_ply(5, np.ones((2, 3)), True))
    _replace(sample, "file: queries/q0000/scan.npy", "file: queries/q0000/scan.ply")
    _replace(sample, "    points: 360\n", "\n")  # the scan's count is the PLY's business here
    with pytest.raises(DatasetError, match=r"field 'queries\[0\].scan.file'.*header says 5 vertices"):
        load_scenario(sample)


def test_a_npy_header_that_does_not_parse_is_a_dataset_error(tmp_path):  # found by the fuzz suite (a TokenError)
    p = tmp_path / "scan.npy"
    np.save(p, np.zeros((4, 2)))
    raw = bytearray(p.read_bytes())
    raw[raw.index(b"{")] = ord("(")  # the header dict opens with a parenthesis it never closes
    p.write_bytes(bytes(raw))
    with pytest.raises(DatasetError, match="not a readable .npy array"):
        read_npy(p)

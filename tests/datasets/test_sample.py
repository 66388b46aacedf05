"""The shipped sample scenario: loads, is small, and is reproduced bit for bit by the simulator from its seed."""

from __future__ import annotations

from pathlib import Path

import pytest
import yaml

from factorloc.datasets import load_scenario, save_scenario
from factorloc.sim import FAULTS, GeneratorConfig, generate_scenario

SAMPLE = Path(__file__).resolve().parents[2] / "data" / "sample"


@pytest.fixture(scope="module")
def sample():
    if not (SAMPLE / "scenario.yaml").is_file():
        pytest.skip(f"the sample scenario is not in this checkout ({SAMPLE})")
    return load_scenario(SAMPLE)


def test_sample_has_thirty_queries_one_reference_and_every_fault(sample) -> None:
    assert len(sample.queries) == 30
    ref = sample.reference
    assert ref.panorama.image_bgr.shape == (256, 2048, 3)
    assert len(ref.cloud) > 10000 and ref.scan is not None
    tags = {t for q in sample.queries for t in q.faults}
    assert tags == set(FAULTS)
    assert sum(1 for q in sample.queries if not q.faults) >= 15  # mostly clean queries
    assert all(q.truth is not None and q.query.odometry is not None for q in sample.queries)
    d = [q.distance_from_reference_m for q in sample.queries]
    assert min(d) < 0.8 and max(d) > 2.5  # varied difficulty


def test_sample_is_small() -> None:
    if not SAMPLE.is_dir():
        pytest.skip("no sample")
    data_dir = SAMPLE.parent
    size = sum(f.stat().st_size for f in data_dir.rglob("*") if f.is_file())
    assert size <= 5_000_000


def test_simulator_reproduces_the_sample_bit_for_bit(sample, tmp_path: Path) -> None:
    """Regenerate the reference and three queries from the sample's seed; the files must be identical."""
    manifest = yaml.safe_load((SAMPLE / "scenario.yaml").read_text())
    meta = manifest["metadata"]
    picks = [0, 2, 8]  # a clean query, a kidnapped one, occlusion + depth dropout
    regen = generate_scenario(
        "apartment",
        meta["n_queries"],
        sample.seed,
        tuple(meta["faults"]),
        GeneratorConfig(fault_probability=meta["fault_probability"]),
        only_queries=picks,
    )
    out = save_scenario(regen, tmp_path / "regen", image_format="jpg")
    assert (out / "world.yaml").read_bytes() == (SAMPLE / "world.yaml").read_bytes()
    for rel in ("references/ref0/panorama.png", "references/ref0/cloud.npy", "references/ref0/scan.npy"):
        assert (out / rel).read_bytes() == (SAMPLE / rel).read_bytes(), rel
    regen_manifest = yaml.safe_load((out / "scenario.yaml").read_text())
    for i, entry in zip(picks, regen_manifest["queries"], strict=True):
        assert entry == manifest["queries"][i]
        qdir = Path("queries") / entry["id"]
        for f in sorted((out / qdir).iterdir()):
            assert f.read_bytes() == (SAMPLE / qdir / f.name).read_bytes(), f"{qdir / f.name} differs"
    assert regen_manifest["references"] == manifest["references"]

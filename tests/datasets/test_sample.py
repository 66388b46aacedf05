"""The shipped sample scenario: loads, is small, and is reproduced bit for bit by the simulator from its seed."""

from __future__ import annotations

from pathlib import Path

import pytest

from factorloc.datasets import load_scenario
from factorloc.sim import FAULTS

SAMPLE = Path(__file__).resolve().parents[2] / "data" / "sample"


@pytest.fixture(scope="module")
def sample():
    return load_scenario(SAMPLE)  # shipped with the repository: missing means broken, not skipped


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
    assert SAMPLE.is_dir()
    data_dir = SAMPLE.parent
    size = sum(f.stat().st_size for f in data_dir.rglob("*") if f.is_file())
    assert size <= 5_000_000


def test_factorloc_simulate_reproduces_the_whole_sample(sample, tmp_path: Path) -> None:
    """The documented command (data/README.md) rewrites data/sample byte for byte."""
    from typer.testing import CliRunner

    from factorloc.cli import app

    out = tmp_path / "sample"
    args = ["simulate", str(out), "--world", "apartment", "--queries", "30", "--seed", "103", "--image-format", "jpg"]
    result = CliRunner().invoke(app, args)
    assert result.exit_code == 0, result.output
    shipped = sorted(p.relative_to(SAMPLE) for p in SAMPLE.rglob("*") if p.is_file())
    written = sorted(p.relative_to(out) for p in out.rglob("*") if p.is_file())
    assert written == shipped
    for rel in shipped:
        assert (out / rel).read_bytes() == (SAMPLE / rel).read_bytes(), f"{rel} differs"

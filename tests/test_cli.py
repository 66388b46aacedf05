"""The command line: fuse on the patent's worked example against a hand computation."""

from __future__ import annotations

import json
import math
from pathlib import Path

from typer.testing import CliRunner

import factorloc
from factorloc.cli import app

runner = CliRunner()


def test_version() -> None:
    result = runner.invoke(app, ["--version"])
    assert result.exit_code == 0 and factorloc.__version__ in result.output


def test_fuse_json_reproduces_the_hand_computed_patent_example(repo_root: Path) -> None:
    result = runner.invoke(app, ["fuse", str(repo_root / "data" / "examples" / "patent_example.json"), "--json"])
    assert result.exit_code == 0, result.output
    out = json.loads(result.output)
    # hand computation, per axis: x = (1.00/5² + 1.03/2²) / (1/5² + 1/2²) with σ in cm
    wx1, wx4 = 1 / 0.05**2, 1 / 0.02**2  # 400, 2500
    x = (1.00 * wx1 + 1.03 * wx4) / (wx1 + wx4)  # 2975/2900 = 1.025862…
    y = (0.50 * wx1 + 0.48 * wx4) / (wx1 + wx4)  # 1400/2900 = 0.482758…
    var_xy = 1 / (wx1 + wx4)  # 1/2900 m²
    w1, w2, w3 = 1 / 3.0**2, 1 / 1.0**2, 1 / 0.5**2  # headings 10°, 12°, 11.5° (weights per deg²)
    theta_deg = (10.0 * w1 + 12.0 * w2 + 11.5 * w3) / (w1 + w2 + w3)  # 11.5652…°
    var_theta = math.radians(1.0) ** 2 / (w1 + w2 + w3)
    assert math.isclose(out["pose"]["x_m"], x, rel_tol=1e-12)
    assert math.isclose(out["pose"]["y_m"], y, rel_tol=1e-12)
    assert math.isclose(out["pose"]["theta_deg"], theta_deg, rel_tol=1e-12)
    cov = out["covariance"]
    assert math.isclose(cov[0][0], var_xy, rel_tol=1e-9) and math.isclose(cov[1][1], var_xy, rel_tol=1e-9)
    assert math.isclose(cov[2][2], var_theta, rel_tol=1e-9)
    assert abs(cov[0][1]) < 1e-15 and cov[0][2] == 0.0
    assert [s["status"] for s in out["steps"]] == ["fused"] * 4
    # the closed form prints the same numbers
    product = json.loads(runner.invoke(app, ["fuse", str(repo_root / "data/examples/patent_example.json"), "--json", "--strategy", "product"]).output)
    assert math.isclose(product["pose"]["x_m"], x, rel_tol=1e-12)


def test_fuse_rejects_missing_and_malformed_files(tmp_path: Path) -> None:
    result = runner.invoke(app, ["fuse", str(tmp_path / "none.json")])
    assert result.exit_code == 2 and "not found" in result.output
    bad = tmp_path / "bad.json"
    bad.write_text(json.dumps([{"step": "a", "components": ["x"], "values": [1.0], "sigmas": [1.0]}]))
    result = runner.invoke(app, ["fuse", str(bad)])
    assert result.exit_code == 2 and "components" in result.output

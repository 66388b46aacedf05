"""Fuzz: the scenario loader on damaged folders and the CLI on malformed files — a typed error naming the field or
file, one line and exit 2 on the command line, never an escaped exception; a few CLI cases in a subprocess so
that a native crash would show as a signal."""

from __future__ import annotations

import json
import math
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from fuzzkit import SilentResultError, assert_no_defect, classify, fuzz_settings, record
from hypothesis import given
from hypothesis import strategies as st
from typer.testing import CliRunner

import factorloc as fl
from factorloc.cli import app
from factorloc.datasets import Scenario, ScenarioQuery, ScenarioReference, load_scenario, save_scenario

TOKENS = ["null", '""', "-1", "0", "1e400", "9" * 400, "[", "{", "&a x", "*b", "true", "'x'", "[1, 2]", "{a: 1}", "-.inf", ".nan"]


@pytest.fixture(scope="module")
def scenario_dir(tmp_path_factory) -> Path:  # noqa: ANN001
    rng = np.random.default_rng(0)
    ref = fl.Reference(cloud=fl.PointCloud(rng.normal(size=(300, 3))), scan=fl.Scan(rng.normal(size=(60, 2))), name="r")
    queries = []
    for i in range(2):
        odo = fl.Odometry(fl.Pose2(1.0 + i, 2.0, 0.1 * i), 0.05, 0.05, 0.02)
        q = fl.Query(
            scan=fl.Scan(rng.normal(size=(50, 2))), cloud=fl.PointCloud(rng.normal(size=(80, 3))), odometry=odo, id=f"q{i}"
        )
        queries.append(ScenarioQuery(q, timestamp_s=float(i), truth=fl.Pose2(1.0, 2.0, 0.0), reference_id="ref0"))
    return save_scenario(Scenario("fuzz", (ScenarioReference("ref0", ref),), tuple(queries)), tmp_path_factory.mktemp("s") / "s")


def _finite(s: Scenario) -> None:
    for q in s.queries:
        for sensor in (q.query.scan, q.query.cloud):
            if sensor is not None and not np.isfinite(sensor.points_m).all():
                raise SilentResultError(f"query {q.id} holds non-finite points")


@fuzz_settings(default=40, fuzz=1500)
@given(data=st.data())
def test_loader_on_damaged_folders(scenario_dir, tmp_path_factory, data):
    root = tmp_path_factory.mktemp("d") / "s"
    shutil.copytree(scenario_dir, root)
    manifest = root / "scenario.yaml"
    lines = manifest.read_text().splitlines()
    op = data.draw(st.sampled_from(["delete", "value", "key", "file_truncate", "file_flip", "bytes"]))
    i = data.draw(st.integers(0, len(lines) - 1))
    if op == "delete":
        del lines[i]
    elif op == "value" and ":" in lines[i]:
        key = lines[i].split(":", 1)[0]
        lines[i] = f"{key}: {data.draw(st.sampled_from(TOKENS))}"
    elif op == "key" and ":" in lines[i]:
        key, rest = lines[i].split(":", 1)
        j = data.draw(st.integers(0, max(len(key) - 1, 0)))
        lines[i] = key[:j] + data.draw(st.sampled_from(["x", "", "_", "e"])) + key[j + 1 :] + ":" + rest
    elif op == "bytes":
        manifest.write_bytes(data.draw(st.binary(max_size=64)) + manifest.read_bytes()[data.draw(st.integers(0, 64)) :])
    if op in ("delete", "value", "key"):
        manifest.write_text("\n".join(lines) + "\n")
    if op.startswith("file"):
        files = sorted(p for p in root.rglob("*.npy"))
        f = files[data.draw(st.integers(0, len(files) - 1))]
        raw = bytearray(f.read_bytes())
        k = data.draw(st.integers(0, len(raw) - 1))
        if op == "file_truncate":
            raw = raw[:k]
        else:
            raw[k] ^= data.draw(st.integers(1, 255))
        f.write_bytes(bytes(raw))
    outcome = classify("loader.damaged", ("scenario.yaml", ".npy", "scenario"), lambda: load_scenario(root), _finite)
    assert_no_defect(outcome, f"{op} at line {i}")


runner = CliRunner()

JSONS = st.recursive(
    st.one_of(st.none(), st.booleans(), st.floats(), st.integers(-(10**30), 10**30), st.text(max_size=6)),
    lambda children: st.one_of(st.lists(children, max_size=4), st.dictionaries(st.text(max_size=8), children, max_size=4)),
    max_leaves=12,
)
FIELDS = st.fixed_dictionaries(
    {
        "step": st.one_of(st.just("a"), st.text(max_size=3)),
        "components": st.one_of(st.sampled_from([["theta"], ["x", "y"], ["x", "y", "theta"]]), JSONS),
        "values": st.one_of(st.lists(st.floats(), min_size=1, max_size=3), JSONS),
    },
    optional={"sigmas": st.lists(st.floats(), max_size=3), "covariance": JSONS, "reliable": JSONS, "checks": JSONS},
)


def _one_line(result) -> None:  # noqa: ANN001
    if result.exit_code not in (0, 2):
        raise SilentResultError(f"exit {result.exit_code}: {result.output[-200:]}")


@fuzz_settings(default=40, fuzz=1500)
@given(content=st.one_of(JSONS.map(json.dumps), st.lists(FIELDS, max_size=3).map(json.dumps), st.binary(max_size=40)))
def test_cli_fuse_on_malformed_files(tmp_path_factory, content):
    p = tmp_path_factory.mktemp("c") / "e.json"
    p.write_bytes(content if isinstance(content, bytes) else content.encode())
    result = runner.invoke(app, ["fuse", str(p), "--json"])
    err = result.stderr if result.stderr_bytes is not None else result.output
    if result.exit_code == 2:
        lines = err.strip().splitlines()
        outcome = "typed" if len(lines) == 1 and lines[0].startswith("error: ") else "typed-unnamed"
    elif result.exit_code == 0:
        outcome = "sensible"
        out = json.loads(result.stdout)
        if any(v is not None and not math.isfinite(v) for v in out.get("pose", {}).values() if isinstance(v, float)):
            outcome = "silent"
    else:
        outcome = "escaped"
    record("cli.fuse", outcome, err)
    assert_no_defect(outcome, f"{content!r}"[:200])


FACTORLOC = str(Path(sys.executable).with_name("factorloc"))


@fuzz_settings(default=3, fuzz=40)
@given(
    content=st.one_of(
        st.binary(max_size=60),
        st.just(b"[" * 50_000),
        st.just(b'[{"step":"a","components":["theta"],"values":[0],"sigmas":[1e-400]}]'),
    )
)
def test_cli_in_a_subprocess(tmp_path_factory, content):
    p = tmp_path_factory.mktemp("p") / "e.json"
    p.write_bytes(content)
    r = subprocess.run([FACTORLOC, "fuse", str(p)], capture_output=True, text=True, timeout=120, check=False)
    if r.returncode < 0:
        outcome = "crash"
    elif r.returncode == 2 and r.stderr.count("\n") == 1 and r.stderr.startswith("error: "):
        outcome = "typed"
    elif r.returncode == 0:
        outcome = "sensible"
    else:
        outcome = "escaped"
    record("cli.subprocess", outcome, r.stderr)
    assert_no_defect(outcome, f"{content!r}"[:100])

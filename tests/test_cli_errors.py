"""Issue #21, reproducers 6 and 7 on the command line: every error is one line on stderr (never wrapped, whatever
the terminal width) and exit 2, never a traceback — run as the installed program in a subprocess."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

FACTORLOC = str(Path(sys.executable).with_name("factorloc"))
SAMPLE = str(Path(__file__).resolve().parents[1] / "data" / "sample")


def _run(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "COLUMNS": "30", "TERM": "dumb"}
    env.pop("FACTORLOC_TRACEBACK", None)
    return subprocess.run([FACTORLOC, *args], capture_output=True, text=True, env=env, timeout=120, check=False)


def _estimates(tmp_path: Path, content: bytes | str) -> str:
    p = tmp_path / "e.json"
    p.write_bytes(content if isinstance(content, bytes) else content.encode())
    return str(p)


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (b"\xff\xfe[{", "is not UTF-8 text"),
        ("[" * 100_000 + "]" * 100_000, "nests JSON too deep"),
        (
            json.dumps([{"step": "a", "components": ["theta"], "values": [0], "sigmas": [0.1], "reliable": "false"}]),
            "reliable must be a JSON boolean",
        ),
        (
            json.dumps([{"step": "a", "components": ["theta"], "values": [0], "sigmas": [1e-160]}]),
            r"sigmas[0] must be a standard deviation in [1e-09, 1e+06]",
        ),
    ],
)
def test_malformed_estimates_files_give_one_line_and_exit_2(tmp_path, content, message):
    r = _run("fuse", _estimates(tmp_path, content))
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("error: ") and message in r.stderr
    assert "Traceback" not in r.stderr


@pytest.mark.parametrize(
    "args",
    [
        ("localize", SAMPLE, "--no-such-option", "1"),
        ("fuse",),
        ("localize", SAMPLE, "q9999"),
        ("localize", "/nonexistent/scenario/with/a/long/path/that/would/wrap", "q0000"),
    ],
)
def test_usage_and_library_errors_are_one_unwrapped_line(args):
    r = _run(*args)
    assert r.returncode == 2, r.stderr
    assert r.stderr.count("\n") == 1 and r.stderr.startswith("error: "), r.stderr

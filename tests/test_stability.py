"""Same scans, same verdict, whatever the rounding (issue 13).

The fixed cases of ``tests/stability_cases.py`` (one straight wall, a corridor, a sample of real Intel/ACES local
relations) are localized (1) as they are, (2) with every scan point moved by ±1e-9 m, and in subprocesses whose
numerics take other paths: (3) numba's JIT off (the compiled kernels run as plain Python/numpy) and (4) numpy's
AVX-512 dispatch off with numba compiling for Haswell (an AVX2-only CPU). The verdicts (each step's status,
reliability and failed check codes, what is undetermined) must be identical; poses agree to 1e-9 across numerics
paths, and move by at most 20× the perturbation under it (the least-squares solution's own sensitivity: measured
5.8e-9 m for 1e-9 m).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import stability_cases  # beside this file (pytest puts the test's folder on the path)

HERE = Path(__file__).resolve().parent
SHARED = HERE.parents[0].parent / "shared"
SHARED_ARG = SHARED if (SHARED / "data" / "laser").is_dir() else None


def _in_subprocess(env: dict[str, str], tmp_path: Path) -> dict[str, dict[str, object]]:
    args = [sys.executable, str(HERE / "stability_cases.py")]
    if SHARED_ARG is not None:
        args += ["--shared", str(SHARED_ARG)]
    full = {**os.environ, **env, "NUMBA_CACHE_DIR": str(tmp_path / "numba-cache")}
    done = subprocess.run(args, env=full, capture_output=True, text=True, timeout=600, check=False)
    assert done.returncode == 0, done.stderr[-2000:]
    return json.loads(done.stdout)


def _compare(a: dict, b: dict, pose_tol: float) -> None:
    assert a.keys() == b.keys()
    for key in a:
        assert a[key]["steps"] == b[key]["steps"], key
        assert a[key]["undetermined"] == b[key]["undetermined"], key
        diff = np.abs(np.array(a[key]["pose"]) - np.array(b[key]["pose"]))
        assert diff.max() <= pose_tol, (key, diff.max())


@pytest.fixture(scope="module")
def baseline() -> dict[str, dict[str, object]]:
    return stability_cases.run(SHARED_ARG)


def test_the_cases_cover_a_fused_wall_a_fused_corridor_and_real_relations(baseline) -> None:
    assert baseline["single-wall"]["steps"]["icp"]["status"] == "fused"
    assert baseline["corridor"]["steps"]["icp"]["status"] == "fused"
    if SHARED_ARG is not None:
        real = [k for k in baseline if k.startswith(("intel-", "aces-"))]
        assert len(real) >= 20
        assert sum(baseline[k]["steps"]["icp"]["status"] == "fused" for k in real) >= 0.8 * len(real)


@pytest.mark.slow
def test_a_1e9_m_perturbation_changes_no_verdict(baseline) -> None:
    _compare(baseline, stability_cases.run(SHARED_ARG, delta_m=1e-9), pose_tol=2e-8)


@pytest.mark.slow
def test_the_plain_python_kernels_give_the_compiled_verdicts(baseline, tmp_path: Path) -> None:
    _compare(baseline, _in_subprocess({"NUMBA_DISABLE_JIT": "1"}, tmp_path), pose_tol=1e-9)


@pytest.mark.slow
def test_an_avx2_only_cpu_gives_the_same_verdicts(baseline, tmp_path: Path) -> None:
    env = {
        "NPY_DISABLE_CPU_FEATURES": "X86_V4 AVX512_ICL AVX512_SPR",
        "NUMBA_CPU_NAME": "haswell",
        "OPENBLAS_CORETYPE": "Haswell",
    }
    _compare(baseline, _in_subprocess(env, tmp_path), pose_tol=1e-9)

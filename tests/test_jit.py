"""Where numba caches the kernels, and the one-line notice the first time they compile."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from factorloc import jit

SMALL_KERNEL = (
    "import logging; logging.basicConfig(level=logging.INFO, format='%(name)s: %(message)s');"
    "from factorloc.registration.kernels import weight_scalar; print(weight_scalar(2, 1.0, 0.5))"
)


def test_the_cache_is_numbas_own_choice_beside_the_sources_else_the_users(
    monkeypatch: pytest.MonkeyPatch, tmp_path: Path
) -> None:
    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))
    assert jit.cache_location() == str(tmp_path / "mine")
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    monkeypatch.setattr(jit, "_writable", lambda directory: True)  # an editable install, a checkout
    assert jit.cache_location().endswith(os.path.join("factorloc", "registration", "__pycache__"))
    monkeypatch.setattr(jit, "_writable", lambda directory: False)  # a read-only site-packages
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    assert jit.cache_location() == str(tmp_path / "xdg" / "factorloc" / "numba")
    monkeypatch.delenv("XDG_CACHE_HOME")
    assert jit.user_cache_dir() == Path.home() / ".cache" / "factorloc" / "numba"


def test_the_notice_is_given_once_and_only_for_factorlocs_kernels(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setitem(jit._state, "noticed", False)
    heard: list[str] = []
    monkeypatch.setattr(jit, "_callbacks", [heard.append])
    jit._notice(SimpleNamespace(py_func=SimpleNamespace(__module__="someone.else")))
    assert heard == []
    for _ in range(3):
        jit._notice(SimpleNamespace(py_func=SimpleNamespace(__module__="factorloc.registration.icp2d")))
    assert len(heard) == 1 and "compiling factorloc's kernels" in heard[0] and jit.cache_location() in heard[0]


def test_a_first_compile_logs_the_notice_and_a_cached_run_does_not(tmp_path: Path) -> None:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path)}
    first = subprocess.run([sys.executable, "-c", SMALL_KERNEL], capture_output=True, text=True, env=env, check=True)
    again = subprocess.run([sys.executable, "-c", SMALL_KERNEL], capture_output=True, text=True, env=env, check=True)
    assert first.stdout.strip() == again.stdout.strip() == "0.8"
    assert (
        f"factorloc.jit: compiling factorloc's kernels for this machine (once, up to a minute; then cached in {tmp_path})"
        in first.stderr
    )
    assert "compiling" not in again.stderr
    assert any(tmp_path.rglob("*.nbi"))  # the index numba wrote, where we said

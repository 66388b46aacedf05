"""The CLI's console: the terminal's width, or a fixed width when piped."""

from __future__ import annotations

import io

import pytest

from factorloc import cli_console


class _Stream(io.StringIO):
    def __init__(self, tty: bool) -> None:
        super().__init__()
        self._tty = tty

    def isatty(self) -> bool:
        return self._tty


def test_a_piped_console_is_wide_enough_for_the_tables(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.delenv("COLUMNS", raising=False)
    monkeypatch.setattr(cli_console.sys, "stdout", _Stream(tty=False))
    assert cli_console.console_for().width == cli_console.PIPED_WIDTH


def test_columns_or_a_terminal_decide_the_width(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setattr(cli_console.sys, "stderr", _Stream(tty=False))
    monkeypatch.setenv("COLUMNS", "77")
    assert cli_console.console_for(stderr=True).width == 77

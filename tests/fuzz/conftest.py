"""The fuzz suite's tally, printed at the end of the run (see ``fuzzkit``)."""

from __future__ import annotations

import fuzzkit


def pytest_terminal_summary(terminalreporter, exitstatus, config):  # noqa: ANN001, ARG001
    lines = fuzzkit.summary_lines()
    if lines:
        terminalreporter.section(f"fuzz summary (profile {fuzzkit.PROFILE})")
        for line in lines:
            terminalreporter.write_line(line)

"""The command line's console (only rich at import: every ``cli_*`` module may build one at module level)."""

from __future__ import annotations

import os
import sys

from rich.console import Console

__all__ = ["PIPED_WIDTH", "console_for"]

#: Columns of the output when it is not a terminal and ``COLUMNS`` is unset (a log, a pipe): rich's 80 would cut
#: the evaluation table's numbers to "…".
PIPED_WIDTH = 120


def console_for(*, stderr: bool = False) -> Console:
    """The CLI's console: the terminal's width, or :data:`PIPED_WIDTH` when the output is piped or logged."""
    stream = sys.stderr if stderr else sys.stdout
    piped = not stream.isatty() and "COLUMNS" not in os.environ
    return Console(stderr=stderr, width=PIPED_WIDTH if piped else None)

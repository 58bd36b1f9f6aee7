"""The ``rich`` console every command prints through."""

from __future__ import annotations

from typing import Any

from rich.console import Console

#: Width of the console when the output is not a terminal (a pipe, a file, CI logs): wide enough
#: that no line is ever wrapped (rich would otherwise wrap at 80 columns).
PIPE_WIDTH = 1000


def make_console(**kwargs: Any) -> Console:
    """On a terminal, a console of the terminal's width; elsewhere one that never wraps a line."""
    console = Console(**kwargs)
    if console.is_terminal:
        return console
    return Console(width=PIPE_WIDTH, soft_wrap=True, **kwargs)

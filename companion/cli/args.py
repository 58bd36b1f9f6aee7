"""Argument types shared by the subcommands' parsers."""

from __future__ import annotations

import argparse
from pathlib import Path


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"{n}: need at least 1")
    return n


def output_folder(out: str | None, default_name: str) -> Path:
    """The folder a command writes into (``--out``, else ``runs/<default_name>``), created now, so
    that a path that cannot be a folder is refused before anything runs (exit 2)."""
    from companion.cli import exits
    from companion.cli.exits import StartupError

    folder = Path(out) if out else Path("runs") / default_name
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except FileExistsError:
        raise StartupError(
            f"--out {folder}: a file of that name is in the way; pass a folder", exits.BAD_INPUT
        ) from None
    except OSError as err:
        raise StartupError(
            f"--out {folder}: cannot create the folder: {err.strerror}; pass another --out", exits.BAD_INPUT
        ) from None
    return folder

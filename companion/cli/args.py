"""Argument types shared by the subcommands' parsers."""

from __future__ import annotations

import argparse
import contextlib
import os
from pathlib import Path
from typing import Any


class Once(argparse.Action):
    """An option a command reads once (``--params`` of a command that takes one file): given again,
    argparse's usage error (exit 2) names both values, rather than the last one silently winning.
    ``companion demo`` and ``bench app`` take ``--params`` more than once, as overlays."""

    def __call__(
        self, parser: argparse.ArgumentParser, namespace: argparse.Namespace, values: Any, option: str | None = None
    ) -> None:
        before = getattr(namespace, self.dest, None)
        if before is not None and before != self.default:
            parser.error(
                f"{option} given twice ({before}, then {values}): this command reads one file "
                "(overlays of parameter files: companion demo and companion bench app)"
            )
        setattr(namespace, self.dest, values)


def positive_int(text: str) -> int:
    """argparse type: an integer >= 1."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
    if n < 1:
        raise argparse.ArgumentTypeError(f"{n}: need at least 1")
    return n


# the least free space a flight's run folder is started with: the 160 s fused demo writes 42 MB
# (flight.mcap 32 MB of it, the camera's frames), the short demo 5 MB; a longer flight needs more,
# and a disk that fills in flight stops the logs, not the flight (docs/logs.md)
FLIGHT_LOGS_MIN_BYTES = 64 * 1024 * 1024
# a campaign's result files and figures (a landing campaign's JSON and PNGs: under 1 MB)
RESULTS_MIN_BYTES = 4 * 1024 * 1024
_PROBE = b"companion: this folder takes writes\n"


def check_writable(folder: Path, need_bytes: int, option: str = "--out") -> None:
    """Refuse (exit 2, one line) a folder that cannot take a run: write and fsync a small probe
    file there (a read-only or failing file system says so now, not in flight) and check the
    free space against ``need_bytes``. ``option``: how the command line names the folder."""
    from companion.cli import exits
    from companion.cli.exits import StartupError

    probe = folder / f".companion-probe-{os.getpid()}"
    try:
        fd = os.open(probe, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        try:
            os.write(fd, _PROBE)
            os.fsync(fd)
        finally:
            os.close(fd)
        probe.unlink()
        st = os.statvfs(folder)
    except OSError as err:
        with contextlib.suppress(OSError):
            probe.unlink()
        raise StartupError(
            f"{option} {folder}: cannot write there: {err.strerror}; pass another {option}", exits.BAD_INPUT
        ) from None
    free = st.f_bavail * st.f_frsize
    if free < need_bytes:
        raise StartupError(
            f"{option} {folder}: {free / 1e6:.1f} MB free, a run needs at least {need_bytes / 1e6:.0f} MB; "
            f"free some space or pass another {option}",
            exits.BAD_INPUT,
        )


def output_folder(out: str | None, default_name: str, need_bytes: int = FLIGHT_LOGS_MIN_BYTES) -> Path:
    """The folder a command writes into (``--out``, else ``runs/<default_name>``), created now and
    probed (:func:`check_writable`, ``need_bytes`` free), so that a path that cannot be a folder,
    a read-only or a full one is refused before anything runs (exit 2)."""
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
    check_writable(folder, need_bytes)
    return folder


def made_run_folder(out: str | None, prefix: str, need_bytes: int) -> Path:
    """The run folder (``--out``, else runs/PREFIX-<time>), created and probed: one line and exit 2
    (StartupError) when it cannot be made, is read-only or has less room than ``need_bytes``."""
    import time

    from companion.cli import exits
    from companion.cli.exits import StartupError

    run_dir = Path(out) if out else Path("runs") / time.strftime(f"{prefix}-%Y%m%d-%H%M%S")
    try:
        run_dir.mkdir(parents=True, exist_ok=True)
    except OSError as err:
        raise StartupError(
            f"cannot create the run folder {run_dir}: {err.strerror}; pass another --out", exits.BAD_INPUT
        ) from None
    check_writable(run_dir, need_bytes)  # read-only, full: refused before the link opens
    return run_dir

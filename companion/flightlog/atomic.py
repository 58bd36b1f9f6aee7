"""Small result files written whole or not at all, and the room kept for them on a full disk.

:func:`write_text_atomic` writes a temporary file in the same folder, syncs it and renames it over
the target (``os.replace``): a reader sees the previous file or the new one, never an empty or
torn one; on failure (a full disk) the previous file is kept, the temporary removed and the
``OSError`` raised for the caller to report. :class:`Room` holds a little space in a run folder
from its start so that the files written at the end of a flight (``run.json``'s last version,
``summary.json``) still fit when the logs have filled the disk.
"""

from __future__ import annotations

import contextlib
import logging
import os
from pathlib import Path

log = logging.getLogger(__name__)


def write_text_atomic(path: Path, text: str, sync: bool = True) -> None:
    """Replace ``path`` with ``text`` (UTF-8) atomically; ``sync``: fsync the file before the
    rename (a power cut keeps the old or the new one; off on the control path, where a sync may
    block for tens of ms). An ``OSError`` leaves the previous file as it was and is raised."""
    path = Path(path)
    tmp = path.with_name(f".{path.name}.tmp")
    try:
        with tmp.open("w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            if sync:
                os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException:
        with contextlib.suppress(OSError):
            tmp.unlink()
        raise


# what the end of a flight writes once the logs are closed: run.json's last version (12 kB for the
# demo, up to ~60 kB with a long mission plan and fusion set-up) and summary.json (2 kB), each
# written beside its previous version, with margin for the file system's block rounding
ROOM_BYTES = 256 * 1024
ROOM_FILE = ".room"


class Room:
    """:data:`ROOM_BYTES` allocated in ``folder`` (``.room``) from a run's start, given back by
    :meth:`release` just before the files of its end are written. A folder without that much room
    is not refused here (the start-up check is: :func:`companion.cli.args.output_folder`)."""

    def __init__(self, folder: Path) -> None:
        self.path = Path(folder) / ROOM_FILE
        self.held = False
        try:
            fd = os.open(self.path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
        except OSError as err:
            log.warning("%s: cannot keep room for the run's last files: %s", self.path, err)
            return
        try:
            os.posix_fallocate(fd, 0, ROOM_BYTES)  # real blocks: a sparse file would hold nothing
            self.held = True
        except OSError as err:
            log.warning("%s: cannot keep room for the run's last files: %s", self.path, err)
        finally:
            os.close(fd)
        if not self.held:
            self.release()

    def release(self) -> None:
        """Give the room back (idempotent)."""
        self.held = False
        with contextlib.suppress(OSError):
            self.path.unlink(missing_ok=True)

"""What a run's logs lost, and why: the storage faults of the log writers, by cause.

A writer that cannot write any more (a full disk, a read-only or failing file system) stops
writing that file, keeps emptying its queue and counts what it is handed as lost; the flight goes
on. It reports the fault here once (:func:`note_fault`) and, once closed, what it lost
(:func:`note_lost`), which logs the one line naming the cause and the count. A writer in the
logging process reports through :func:`set_forward` (the parent records it as its own), so the
flight's process knows within one hand-over that a folder's logs are incomplete.

The shell and the command line ask :func:`logs_incomplete` (a run folder) and :func:`losses`
(what was lost, by file); the recorder writes the same into ``run.json`` (``storage_faults``).
Causes are an enum: decisions are taken on it, never on an error's text.
"""

from __future__ import annotations

import enum
import errno
import logging
import os
import threading
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger(__name__)


class LossCause(enum.Enum):
    """Why a log lost rows (the value is what the one line says)."""

    DISK_FULL = "disk full"  # ENOSPC, EDQUOT: no room left
    READ_ONLY = "read-only file system"  # EROFS: remounted read-only in flight (a failing card)
    IO_ERROR = "I/O error"  # any other OSError: EIO, a device gone
    QUEUE_FULL = "the writer could not keep up"  # the bounded queue was full: rows not queued


_ERRNO_CAUSE = {errno.ENOSPC: LossCause.DISK_FULL, errno.EDQUOT: LossCause.DISK_FULL, errno.EROFS: LossCause.READ_ONLY}
# below this many free bytes a writer error that carries no errno (the MCAP writer's) is taken for
# a full disk: less than one MCAP chunk or CSV batch fits
_FULL_BELOW_BYTES = 64 * 1024


def cause_of(err: BaseException, path: Path | None = None) -> LossCause:
    """The cause of a write error: by its errno; an error without one (a library's own) by the
    state of ``path``'s file system (full, read-only), else :attr:`LossCause.IO_ERROR`."""
    code = getattr(err, "errno", None)
    if code in _ERRNO_CAUSE:
        return _ERRNO_CAUSE[code]
    if code is None and path is not None:
        try:
            st = os.statvfs(path.parent)
        except OSError:
            return LossCause.IO_ERROR
        if st.f_flag & os.ST_RDONLY:
            return LossCause.READ_ONLY
        if st.f_bavail * st.f_frsize < _FULL_BELOW_BYTES:
            return LossCause.DISK_FULL
    return LossCause.IO_ERROR


@dataclass(frozen=True)
class Loss:
    """What one file lost: ``lost`` units (``unit``: rows, MAVLink records) by ``cause``
    (0 while the file is still open: the count comes at its close)."""

    path: Path
    cause: LossCause
    lost: int
    unit: str


_NAMED = 4  # files named per cause in describe()'s line
_lock = threading.Lock()
_faults: dict[Path, LossCause] = {}  # files that stopped writing, by their first cause
_lost: dict[tuple[Path, LossCause], tuple[int, str]] = {}
_forward: Callable[[Path, LossCause], None] | None = None


def set_forward(fn: Callable[[Path, LossCause], None] | None) -> None:
    """Also hand every new fault to ``fn`` (the logging process: to its parent)."""
    global _forward
    _forward = fn


def note_fault(path: Path, cause: LossCause) -> None:
    """``path`` stopped being written (``cause``); said by the writer, recorded here once."""
    path = Path(path)
    with _lock:
        if path in _faults:
            return
        _faults[path] = cause
    fwd = _forward
    if fwd is not None:
        fwd(path, cause)


def fault_of(path: Path) -> LossCause | None:
    """Why ``path`` stopped being written, if it did."""
    with _lock:
        return _faults.get(Path(path))


def note_lost(path: Path, cause: LossCause, lost: int, unit: str = "rows") -> None:
    """``path`` lost ``lost`` units by ``cause`` (at its close); logs the one line, e.g.
    ``disk full: 483 rows of flight.csv lost (/runs/x)``."""
    if lost <= 0:
        return
    path = Path(path)
    with _lock:
        n, _ = _lost.get((path, cause), (0, unit))
        _lost[(path, cause)] = (n + lost, unit)
    level = logging.WARNING if cause is LossCause.QUEUE_FULL else logging.ERROR
    log.log(level, "%s: %d %s of %s lost (%s)", cause.value, lost, unit, path.name, path.parent)


def losses(run_dir: Path) -> list[Loss]:
    """What the files under ``run_dir`` lost, by file and cause (a file that stopped but is not
    closed yet has ``lost`` 0), in path order."""
    root = Path(run_dir)
    with _lock:
        out = [Loss(p, c, n, u) for (p, c), (n, u) in _lost.items() if p.is_relative_to(root)]
        counted = {x.path for x in out}
        out += [Loss(p, c, 0, "rows") for p, c in _faults.items() if p.is_relative_to(root) and p not in counted]
    return sorted(out, key=lambda x: (str(x.path), x.cause.value))


def forget(run_dir: Path) -> None:
    """Forget what the files under ``run_dir`` lost (a new run starts there)."""
    root = Path(run_dir)
    with _lock:
        for p in [p for p in _faults if p.is_relative_to(root)]:
            del _faults[p]
        for key in [k for k in _lost if k[0].is_relative_to(root)]:
            del _lost[key]


def logs_incomplete(run_dir: Path) -> bool:
    """Whether any log under ``run_dir`` lost something (a storage fault or a full queue)."""
    return bool(losses(run_dir))


def describe(run_dir: Path) -> str:
    """One line for the operator: what the logs under ``run_dir`` lost ("" when nothing), e.g.
    ``logs incomplete: disk full (flight.csv 483 rows, ekf.csv 469 rows, flight.mcap)``."""
    found = losses(run_dir)
    if not found:
        return ""
    by_cause: dict[LossCause, list[str]] = {}
    for x in sorted(found, key=lambda x: -x.lost):
        by_cause.setdefault(x.cause, []).append(f"{x.path.name} {x.lost} {x.unit}" if x.lost else x.path.name)
    parts = []
    for c, files in by_cause.items():  # the largest losses first, at most _NAMED files a cause
        more = f", {len(files) - _NAMED} more" if len(files) > _NAMED else ""
        parts.append(f"{c.value} ({', '.join(files[:_NAMED])}{more})")
    return "logs incomplete: " + "; ".join(parts)

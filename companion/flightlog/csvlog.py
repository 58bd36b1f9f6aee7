"""CSV flight logs: time in seconds first, units in the headers (PlotJuggler-friendly).

Rows are handed to a writer thread through a bounded queue so disk I/O never runs on the
control path (a full queue drops the row and counts it). The writer wakes every
``flush_period_s`` (20 ms), writes what has arrived and flushes it to the OS, so a process that
dies loses at most the rows of that last moment, and a busy control loop is not woken once per
row. ``close()`` writes everything queued and closes the file (also on exceptions, via
``with``); logs still open when the interpreter exits (an uncaught exception, Ctrl-C) are closed
by an ``atexit`` hook, so their queues are written too.

Floats are written as their shortest round-trip decimal (``repr``): reading a value back with
``float()`` gives the very same double, which replay needs.
"""

from __future__ import annotations

import atexit
import collections
import csv
import logging
import threading
import weakref
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType

log = logging.getLogger(__name__)

_OPEN: weakref.WeakSet[CsvLog] = weakref.WeakSet()


@atexit.register
def _close_open_logs() -> None:
    for lg in list(_OPEN):
        lg.close()


class CsvLog:
    def __init__(self, path: str | Path, columns: Sequence[str], max_queue: int = 10000, flush_period_s: float = 0.02):
        if not columns or columns[0] != "time_s":
            raise ValueError(f"the first CSV column must be time_s, got {list(columns)[:1]}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.columns = tuple(columns)
        self.dropped = 0
        self.written = 0
        self._max = int(max_queue)
        self._period = float(flush_period_s)
        self._q: collections.deque[tuple[object, ...]] = collections.deque()  # append/popleft are thread-safe
        self._stop = threading.Event()
        self._fh = self.path.open("w", newline="", encoding="utf-8")
        self._writer = csv.writer(self._fh)
        self._writer.writerow(self.columns)
        self._fh.flush()
        self._thread = threading.Thread(target=self._drain, name=f"csvlog-{self.path.name}", daemon=True)
        self._closed = False
        self._thread.start()
        _OPEN.add(self)

    def write(self, row: Sequence[object]) -> None:
        if self._closed:
            raise RuntimeError(f"{self.path}: log already closed")
        if len(row) != len(self.columns):
            raise ValueError(f"{self.path}: row has {len(row)} fields, header has {len(self.columns)}")
        if len(self._q) >= self._max:
            self.dropped += 1
            return
        self._q.append(tuple(row))

    def _drain(self) -> None:
        failed: OSError | None = None
        q = self._q
        while True:
            stopping = self._stop.wait(self._period)
            n = len(q)
            if failed is not None:
                for _ in range(n):  # keep emptying the queue so memory stays bounded
                    q.popleft()
                self.dropped += n
            elif n:
                done = 0
                try:
                    # csv writes str(v): for floats (and numpy float64) the shortest round-trip decimal
                    for _ in range(n):
                        self._writer.writerow(q.popleft())
                        done += 1
                    self._fh.flush()
                except OSError as err:
                    failed = err
                    self.dropped += n - done
                    log.error("%s: cannot write the log any more: %s", self.path, err)
                self.written += done
            if stopping and not q:
                break

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        _OPEN.discard(self)
        self._stop.set()
        self._thread.join()
        try:
            self._fh.close()
        except OSError as err:
            log.error("%s: closing the log failed: %s", self.path, err)
        if self.dropped:
            log.warning("%s: %d rows dropped (writer could not keep up)", self.path, self.dropped)

    def __enter__(self) -> CsvLog:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None) -> None:
        self.close()


def format_cell(v: object) -> str:
    """A value as the writer puts it in the file: ``str(v)``, which for a float is its shortest
    decimal that reads back as the same double."""
    return "" if v is None else str(v)


def read_csv(path: str | Path) -> dict[str, list[str]]:
    """Columns of a CSV log, as strings (for reports and tests)."""
    with Path(path).open(newline="", encoding="utf-8") as fh:
        rows = list(csv.reader(fh))
    if not rows:
        raise ValueError(f"{path}: empty CSV log")
    header, body = rows[0], rows[1:]
    return {h: [r[i] for r in body] for i, h in enumerate(header)}

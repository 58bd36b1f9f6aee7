"""CSV flight logs: time in seconds first, units in the headers (PlotJuggler-friendly).

Rows are handed through a bounded queue to one writer thread shared by every open log, so disk
I/O and number formatting never run on the control path (a full queue drops the row and counts
it). The writer wakes every ``flush_period_s`` (:data:`FLUSH_PERIOD_S`, 0.2 s), writes each
log's rows as one batch (``csv.writer.writerows``) and flushes it to the OS. A process that
dies without closing its logs (``kill -9``, ``os._exit``) therefore loses at most the rows of the
last 0.2 s of wall time per stream (never more than ``max_queue`` rows). ``close()`` writes
everything queued and closes the file (also on exceptions, via ``with``); logs still open when
the interpreter exits (an uncaught exception, Ctrl-C) are closed by an ``atexit`` hook, so their
queues are written too. One thread waking five times a second (instead of one per file at
50 Hz) keeps the logging's share of a simulated flight small: every wake-up of a Python thread
costs the busy control loop a GIL hand-over (``companion bench log``).

Floats are written as their shortest round-trip decimal (``repr``): reading a value back with
``float()`` gives the very same double, which replay needs.
"""

from __future__ import annotations

import atexit
import collections
import csv
import logging
import os
import threading
import weakref
from collections.abc import Sequence
from pathlib import Path
from types import TracebackType
from typing import ClassVar, Protocol

log = logging.getLogger(__name__)

FLUSH_PERIOD_S = 0.2  # the shared writer's period: what a hard crash can lose, in wall time

_OPEN: weakref.WeakSet[CsvLog] = weakref.WeakSet()


@atexit.register
def _close_open_logs() -> None:
    for lg in list(_OPEN):
        lg.close()


class _Drainable(Protocol):
    def _drain(self) -> None: ...


class BatchSink(Protocol):
    """A second consumer of a log's batches (on the writer thread): ``encode`` gives the CSV
    text ``csv.writer`` would write and one message per row; ``publish`` must not raise."""

    def encode(self, batch: list[tuple[object, ...]]) -> tuple[str, list[bytes]]: ...

    def publish(self, batch: list[tuple[object, ...]], payloads: list[bytes] | None) -> None: ...


class _SharedWriter:
    """The one writer thread of every :class:`CsvLog` (and :class:`~companion.flightlog.mcaplog.McapFlightLog`)
    with the same period."""

    _writers: ClassVar[dict[float, _SharedWriter]] = {}
    _lock = threading.Lock()

    def __init__(self, period_s: float) -> None:
        self.period_s = period_s
        self.logs: set[_Drainable] = set()
        self._cond = threading.Condition()
        self._thread: threading.Thread | None = None

    @classmethod
    def attach(cls, lg: _Drainable, period_s: float) -> _SharedWriter:
        with cls._lock:
            w = cls._writers.get(period_s)
            if w is None:
                w = cls._writers[period_s] = _SharedWriter(period_s)
            with w._cond:
                w.logs.add(lg)
                if w._thread is None:
                    w._thread = threading.Thread(target=w._run, name=f"csvlog-writer-{period_s:g}s", daemon=True)
                    w._thread.start()
        return w

    def detach(self, lg: _Drainable) -> None:
        with self._cond:
            self.logs.discard(lg)

    @classmethod
    def _forget_after_fork(cls) -> None:
        """A forked child has none of its parent's threads: its logs get writers of their own."""
        cls._writers = {}
        cls._lock = threading.Lock()

    def _run(self) -> None:
        while True:
            with self._cond:
                self._cond.wait(self.period_s)
                logs = list(self.logs)
            for lg in logs:
                lg._drain()


os.register_at_fork(after_in_child=_SharedWriter._forget_after_fork)


class CsvLog:
    def __init__(
        self,
        path: str | Path,
        columns: Sequence[str],
        max_queue: int = 10000,
        flush_period_s: float = FLUSH_PERIOD_S,
        sink: BatchSink | None = None,
    ):
        """``sink``: formats each batch (its CSV text plus messages of its own, e.g. the run's
        MCAP) and is handed the batch and its messages once the CSV text is written."""
        if not columns or columns[0] != "time_s":
            raise ValueError(f"the first CSV column must be time_s, got {list(columns)[:1]}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.columns = tuple(columns)
        self._n = len(self.columns)
        self.dropped = 0
        self.written = 0
        self._max = int(max_queue)
        self._q: collections.deque[tuple[object, ...]] = collections.deque()  # append/popleft are thread-safe
        self._io = threading.Lock()  # the writer thread and close() take turns on the file
        self._failed: OSError | None = None
        self._fh = self.path.open("w", newline="", encoding="utf-8")
        self._writer = csv.writer(self._fh)
        self._writer.writerow(self.columns)
        self._fh.flush()
        self._closed = False
        self._sink = sink
        self._shared = _SharedWriter.attach(self, float(flush_period_s))
        _OPEN.add(self)

    def write(self, row: Sequence[object]) -> None:
        if self._closed:
            raise RuntimeError(f"{self.path}: log already closed")
        if len(row) != self._n:
            raise ValueError(f"{self.path}: row has {len(row)} fields, header has {self._n}")
        if len(self._q) >= self._max:
            self.dropped += 1
            return
        self._q.append(tuple(row))

    def _drain(self) -> None:
        """Write (one batch) and flush what has been queued so far."""
        with self._io:
            q = self._q
            n = len(q)
            if not n or self._fh.closed:
                return
            batch = [q.popleft() for _ in range(n)]
            if self._failed is not None:  # keep emptying the queue so memory stays bounded
                self.dropped += n
                return
            payloads: list[bytes] | None = None
            try:
                if self._sink is not None:
                    try:
                        text, payloads = self._sink.encode(batch)
                    except Exception:
                        log.exception("%s: the batch encoder failed; written by csv.writer", self.path)
                        text = ""
                    if payloads is not None:
                        self._fh.write(text)
                    else:
                        self._writer.writerows(batch)
                else:
                    # csv writes str(v): for floats (and numpy float64) the shortest round-trip decimal
                    self._writer.writerows(batch)
                self._fh.flush()
            except OSError as err:
                self._failed = err
                self.dropped += n
                log.error("%s: cannot write the log any more: %s", self.path, err)
                return
            self.written += n
            if self._sink is not None:
                self._sink.publish(batch, payloads)

    @property
    def closed(self) -> bool:
        return self._closed

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        _OPEN.discard(self)
        self._shared.detach(self)
        self._drain()
        with self._io:
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

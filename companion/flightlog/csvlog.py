"""CSV flight logs as the flight writes them (:class:`CsvLog`): time in seconds first, units in
the headers (PlotJuggler-friendly).

Rows go into a bounded queue (a full queue drops the row and counts it) and are handed over a
batch at a time by the shared writer thread (:mod:`companion.flightlog.handover`), so disk I/O
and number formatting never run on the control path. By default the logging process
(:mod:`companion.flightlog.logproc`) formats and writes them; the constructor still writes the
header here, so an unwritable path raises at once and the file exists when it returns. Without a
logging process (it could not be started, it died, or :data:`~companion.flightlog.logproc.IN_PROCESS`)
the writer thread writes the batches here (:class:`~companion.flightlog.csv_file.CsvFile`); rows
not yet handed over are not lost.

Crash safety: a process that dies without closing its logs loses at most the rows of the last
flush period per stream (never more than ``max_queue`` rows). ``close()`` writes everything queued
and returns once the file is complete on disk (also on exceptions, via ``with``); logs still open
at interpreter exit are closed then (:mod:`companion.flightlog.registry`).
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Protocol

from companion.flightlog.csv_file import BatchSink, CsvFile, cut_torn_line, open_csv_file
from companion.flightlog.handover import FLUSH_PERIOD_S, HandedOverLog, SharedWriter, close_files
from companion.flightlog.hooks import FLIGHT, LogHooks
from companion.flightlog.logproc import LogProcess, client
from companion.flightlog.losses import LossCause, cause_of, fault_of, note_lost
from companion.flightlog.registry import CloseOrder, forget, register

log = logging.getLogger(__name__)


class RemoteSink(Protocol):
    """A sink that lives in the logging process (a stream of a remote ``flight.mcap``):
    ``remote_key`` names it there; ``local()`` is its in-process stand-in once the logging
    process is gone (None: the batches then go to the CSV only)."""

    remote_key: tuple[int, str]

    def local(self) -> BatchSink | None: ...


class CsvLog(HandedOverLog):
    def __init__(
        self,
        path: str | Path,
        columns: Sequence[str],
        max_queue: int = 10000,
        flush_period_s: float = FLUSH_PERIOD_S,
        sink: BatchSink | RemoteSink | None = None,
        hooks: LogHooks = FLIGHT,
    ):
        """``sink``: formats each batch (its CSV text plus messages of its own, e.g. the run's
        MCAP) and is handed the batch and its messages once the CSV text is written. A
        :class:`RemoteSink` lives in the logging process; a log with an in-process sink is
        written in this process. ``hooks``: a bench's instruments
        (:class:`~companion.flightlog.hooks.LogHooks`: its batches timed, how they are handed over)."""
        if not columns or columns[0] != "time_s":
            raise ValueError(f"the first CSV column must be time_s, got {list(columns)[:1]}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.columns = tuple(columns)
        self._n = len(self.columns)
        self._queue_dropped = 0  # a full queue
        self._remote_written = 0  # rows handed to the logging process (its count once closed)
        self._remote_dropped = 0
        self._max = int(max_queue)
        self._q: list[tuple[object, ...]] = []  # append and drain's slicing are each atomic (the GIL)
        self._io = threading.Lock()  # the writer thread and close() take turns on the file
        self._closed = False
        self._sink = sink
        remote = sink is None or hasattr(sink, "remote_key")
        self._proc: LogProcess | None = client() if remote else None
        self._file: CsvFile | None = None
        if self._proc is None:
            self._file = CsvFile(self.path, self.columns, self._local_sink())
        else:
            CsvFile(self.path, self.columns).close()  # the header, here: errors raise now
            key = sink.remote_key if sink is not None else None  # type: ignore[union-attr]
            self._id = self._proc.open_csv(self.path, self.columns, key)
            self._post = hooks.hand_over(self._proc)
        self._shared = SharedWriter.attach(self, float(flush_period_s), hooks)
        register(self, CloseOrder.CSV)

    @property
    def written(self) -> int:
        """Rows written (while the logging process writes the file: handed over to it)."""
        return self._remote_written + (self._file.written if self._file is not None else 0)

    @property
    def dropped(self) -> int:
        """Rows lost: a full queue, or a file that could not be written."""
        return self._queue_dropped + self._remote_dropped + (self._file.dropped if self._file is not None else 0)

    @property
    def in_process(self) -> bool:
        """Written by this process (not, or no longer, by the logging process)."""
        return self._file is not None

    def _local_sink(self) -> BatchSink | None:
        s = self._sink
        if s is not None and hasattr(s, "remote_key"):
            return s.local()  # type: ignore[union-attr]
        return s  # type: ignore[return-value]

    def write(self, row: Sequence[object]) -> None:
        if self._closed:
            raise RuntimeError(f"{self.path}: log already closed")
        if len(row) != self._n:
            raise ValueError(f"{self.path}: row has {len(row)} fields, header has {self._n}")
        if len(self._q) >= self._max:
            self._queue_dropped += 1
            return
        self._q.append(row if type(row) is tuple else tuple(row))

    def put(self, row: tuple[object, ...]) -> None:
        """:meth:`write` for a producer that builds every row as a tuple of the header's length
        itself and stops before :meth:`close` (the flight recorder, at the telemetry rate): no
        copy, no checks but the queue's bound."""
        q = self._q
        if len(q) < self._max:
            q.append(row)
        else:
            self._queue_dropped += 1

    @property
    def queue(self) -> list[tuple[object, ...]]:
        """The rows waiting for the writer thread, oldest first. A producer that cannot afford
        even :meth:`put`'s call (the recorder's telemetry hook) appends its rows to this list
        itself (``list.append``: atomic), like :meth:`put`: only while ``len(queue) <
        max_queue``, else :meth:`count_dropped`; the writer thread takes them from the front."""
        return self._q

    @property
    def max_queue(self) -> int:
        return self._max

    def count_dropped(self) -> None:
        """One row not queued: the queue was full (see :attr:`queue`)."""
        self._queue_dropped += 1

    _POST_OP = "rows"
    _CLOSE_OP = "close"

    def _is_local(self) -> bool:
        return self._file is not None

    def _open_local(self) -> None:
        cut_torn_line(self.path)
        self._file = open_csv_file(self.path, self.columns, self._local_sink(), append=True)

    def _write_local(self, batch: list[tuple[object, ...]]) -> None:
        assert self._file is not None
        self._file.write_batch(batch)

    def _close_local(self) -> None:
        assert self._file is not None
        self._file.close()

    def _posted(self, n: int) -> None:
        self._remote_written += n

    def _closed_remote(self, reply: tuple[int, ...]) -> None:
        self._remote_written, self._remote_dropped = reply

    @property
    def closed(self) -> bool:
        return self._closed

    def _say_lost(self) -> None:
        """Once closed: what was lost, by cause (:mod:`companion.flightlog.losses`): rows a full
        queue refused, and rows the file could not take (a full disk, an I/O error)."""
        note_lost(self.path, LossCause.QUEUE_FULL, self._queue_dropped)
        in_file = self.dropped - self._queue_dropped
        if in_file:
            failed = self._file.failed if self._file is not None else None
            cause = fault_of(self.path) or (cause_of(failed, self.path) if failed else LossCause.IO_ERROR)
            note_lost(self.path, cause, in_file)

    def close(self) -> None:
        close_logs([self])


class NullCsvLog(CsvLog):
    """A :class:`CsvLog` opened and closed as usual that takes no rows: :meth:`write` and
    :meth:`put` do nothing (``companion bench log``: what opening and closing the logs cost)."""

    def write(self, row: Sequence[object]) -> None:
        pass

    def put(self, row: tuple[object, ...]) -> None:
        pass


def close_logs(logs: Iterable[CsvLog]) -> None:
    """Close several logs (:meth:`CsvLog.close` each, idempotent) with one wait for the logging
    process (:func:`~companion.flightlog.handover.close_files`): the flight recorder's streams."""
    todo = [lg for lg in dict.fromkeys(logs) if not lg._closed]  # each once, in order
    for lg in todo:
        lg._closed = True
        forget(lg, CloseOrder.CSV)
    try:
        close_files(todo)
    finally:
        for lg in todo:
            lg._say_lost()

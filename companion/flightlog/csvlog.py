"""CSV flight logs: time in seconds first, units in the headers (PlotJuggler-friendly).

Rows are handed through a bounded queue to one writer thread shared by every open log, so
disk I/O and number formatting never run on the control path (a full queue drops the row and
counts it). The writer takes each log's queued rows as one batch (by slicing its list: no per-row
work) every ``flush_period_s`` (:data:`FLUSH_PERIOD_S`, 0.1 s), or sooner: it looks every
:data:`WAKE_PERIOD_S` (0.02 s) and takes them at once when :data:`HANDOVER_ROWS` rows wait
(the simulator running many times faster than real time).

By default the batches are not formatted in this process: the writer thread hands all of them,
one pickle per round, to the **logging process** (:mod:`companion.flightlog.logproc`, one child
per process, started at the first log opened), which formats and writes them (and the run's
``flight.mcap``) on another core. Formatting in this process competed for the GIL with the
control loop: the logs cost the GPS-only demo 45-80 % of its wall time; handing over costs a
fraction of a microsecond per row (``companion bench log``). The constructor still writes the
header here, so an unwritable path raises at once and the file exists when it returns. If the
logging process cannot be started or dies, the logs write in this process (the in-process path:
``csv.writer.writerows`` per batch, flushed to the OS), said once in the log; rows not yet handed
over are not lost. :data:`companion.flightlog.logproc.IN_PROCESS` (or the environment variable
``COMPANION_LOG_IN_PROCESS=1``) forces the in-process path.

Crash safety: a process that dies without closing its logs (``kill -9``, ``os._exit``) loses
at most the rows of the last 0.1 s of wall time per stream (never more than ``max_queue`` rows):
the logging process sees its pipe close, writes everything it was handed and closes its files
(the MCAP with its summary). In the in-process path each batch is flushed to the OS as it is
written, with the same bound. ``close()`` writes everything queued and returns once the file is
complete on disk (also on exceptions, via ``with``); logs still open when the interpreter exits
(an uncaught exception, Ctrl-C) are closed by an ``atexit`` hook, so their queues are written
too. A forked child gets writers (and a logging process) of its own.

Floats are written as their shortest round-trip decimal (``repr``): reading a value back with
``float()`` gives the very same double, which replay needs.
"""

from __future__ import annotations

import abc
import atexit
import csv
import logging
import os
import threading
import time
import weakref
from collections.abc import Iterable, Sequence
from pathlib import Path
from types import TracebackType
from typing import TYPE_CHECKING, ClassVar, Protocol, Self

if TYPE_CHECKING:
    from companion.flightlog.logproc import LogProcess

log = logging.getLogger(__name__)

# the shared writer's period: what a hard crash can lose, in wall time, and what closing a log waits
# for at most (the logging process writing the last batch; 0.2 s made that 30-60 ms of a 1.2 s flight)
FLUSH_PERIOD_S = 0.1
# while rows come faster than HANDOVER_ROWS a period, the writer looks at the queues this often and
# hands them over once HANDOVER_ROWS rows and records wait: the simulator at 160x real time every
# 0.02 s, 1-2 points off the GPS-only demo's logging share (rows kept 0.1 s cost the flight a little
# more; README, issue 15); a flight in real time (a few hundred rows a second) keeps one round a period
WAKE_PERIOD_S = 0.02
HANDOVER_ROWS = 256

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


class RemoteSink(Protocol):
    """A sink that lives in the logging process (a stream of a remote ``flight.mcap``):
    ``remote_key`` names it there; ``local()`` is its in-process stand-in once the logging
    process is gone (None: the batches then go to the CSV only)."""

    remote_key: tuple[int, str]

    def local(self) -> BatchSink | None: ...


class _SharedWriter:
    """The one writer thread of every :class:`CsvLog` (and :class:`~companion.flightlog.mcaplog.McapFlightLog`)
    with the same period; after each round it hands what the logs posted to the logging process."""

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
        from companion.flightlog import logproc

        period = self.period_s
        wait_s, last = period, time.monotonic()
        while True:
            with self._cond:
                self._cond.wait(wait_s)
                logs = list(self.logs)
            now = time.monotonic()
            queued = sum(len(getattr(lg, "_q", ())) for lg in logs)
            # a round once the period is over, or earlier once enough rows wait (a fast simulation):
            # rows handed over young cost the flight less than rows kept for the whole period
            if now - last < period and queued < HANDOVER_ROWS:
                continue
            # looked at every WAKE_PERIOD_S only while the rows come faster than HANDOVER_ROWS a period
            # (a flight in real time keeps one wake-up a period)
            wait_s = min(period, WAKE_PERIOD_S) if queued * period >= HANDOVER_ROWS * (now - last) else period
            last = now
            for lg in logs:
                lg._drain()
            logproc.flush_current()


os.register_at_fork(after_in_child=_SharedWriter._forget_after_fork)


class CsvFile:
    """One CSV file being written, a batch at a time: in this process (the in-process path of
    :class:`CsvLog`) or in the logging process. ``append``: the header is already there (the
    file is continued). An ``OSError`` is logged once with the path; later batches are counted
    in ``dropped``. Not thread-safe (its owner serialises)."""

    def __init__(self, path: Path, columns: tuple[str, ...], sink: BatchSink | None = None, append: bool = False):
        self.path = path
        self.written = 0
        self.dropped = 0
        self.failed: OSError | None = None
        self._sink = sink
        self._fh = path.open("a" if append else "w", newline="", encoding="utf-8")
        self._writer = csv.writer(self._fh)
        if not append:
            self._writer.writerow(columns)
            self._fh.flush()

    def write_batch(self, batch: list[tuple[object, ...]]) -> None:
        """Write one batch and flush it to the OS."""
        n = len(batch)
        if not n or self._fh.closed:
            return
        if self.failed is not None:  # keep emptying the queue so memory stays bounded
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
            self.failed = err
            self.dropped += n
            log.error("%s: cannot write the log any more: %s", self.path, err)
            return
        self.written += n
        if self._sink is not None:
            self._sink.publish(batch, payloads)

    def close(self) -> None:
        try:
            self._fh.close()
        except OSError as err:
            log.error("%s: closing the log failed: %s", self.path, err)


def _cut_torn_line(path: Path) -> None:
    """Drop a last line without its end (a writer killed mid-write) before the file is continued."""
    try:
        with path.open("r+b") as fh:
            size = fh.seek(0, os.SEEK_END)
            if size == 0:
                return
            start = max(0, size - 65536)
            fh.seek(start)
            tail = fh.read()
            if tail.endswith(b"\n"):
                return
            cut = tail.rfind(b"\n")
            fh.truncate(start + cut + 1 if cut >= 0 else start)
    except OSError:
        pass  # CsvFile's own open reports the path's trouble


class HandedOverLog(abc.ABC):
    """The flight's side of a log the logging process writes (:class:`CsvLog`, the simulator's
    :class:`~companion.flightlog.tlog.TelemetryTlog`): what the loop queued is handed over as one
    batch per writer round (:meth:`_drain`), or written here when logging in process; if the
    logging process dies, the file is continued here, first with the batches it was never handed
    (:meth:`_go_local`). A subclass says how its file is continued, written and closed here, and
    names its operations in the logging process (``_POST_OP``, ``_CLOSE_OP``)."""

    _POST_OP: ClassVar[str]
    _CLOSE_OP: ClassVar[str]
    path: Path
    _q: list[tuple[object, ...]]  # appended at the end by the producer, taken from the front by _drain
    _io: threading.Lock  # the writer thread and close() take turns on the file
    _proc: LogProcess | None
    _id: int
    _shared: _SharedWriter

    # ---- the log's own ---------------------------------------------------------------------------
    @abc.abstractmethod
    def _is_local(self) -> bool:
        """Whether the file is written in this process."""

    @abc.abstractmethod
    def _open_local(self) -> None:
        """Continue the file in this process (its torn end cut)."""

    @abc.abstractmethod
    def _write_local(self, batch: list[tuple[object, ...]]) -> None:
        """Write one batch in this process."""

    @abc.abstractmethod
    def _close_local(self) -> None:
        """Close the file written in this process."""

    @abc.abstractmethod
    def _posted(self, n: int) -> None:
        """``n`` rows were handed to the logging process."""

    @abc.abstractmethod
    def _closed_remote(self, reply: tuple[int, ...]) -> None:
        """The logging process closed the file and answered with its counts."""

    # ---- shared --------------------------------------------------------------------------------
    def _go_local(self) -> None:
        """The logging process is gone: continue the file here, first with the batches it was
        never handed (caller holds ``_io``)."""
        assert self._proc is not None
        returned = self._proc.take_returned(self._id)
        self._open_local()
        for op in returned:
            self._write_local(op[2])  # a file that could not be reopened counts them dropped

    def _drain(self) -> None:
        """Hand over (or write, in process) what has been queued so far, as one batch."""
        with self._io:
            if not self._is_local() and self._proc is not None and self._proc.dead:
                self._go_local()
            q = self._q
            n = len(q)
            if not n:
                return
            # two list operations, each atomic under the GIL: rows appended meanwhile stay queued
            batch = q[:n]
            del q[:n]
            if not self._is_local():
                assert self._proc is not None
                if self._proc.post((self._POST_OP, self._id, batch)):
                    self._posted(n)
                    return
                self._go_local()
            self._write_local(batch)

    @abc.abstractmethod
    def close(self) -> None:
        """Write everything queued and close the file (idempotent)."""

    def __enter__(self) -> Self:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    def _close_file(self) -> None:
        """Stop the writer's wake-ups, write everything queued and close the file: in the
        logging process (answered once complete) or here."""
        close_files([self])


def close_files(logs: Sequence[HandedOverLog]) -> None:
    """:meth:`HandedOverLog._close_file` for several logs at once: every last batch and close
    handed to the logging process together, one wait for its answers (instead of one round trip
    per log); logs written here are closed here. A log that fails does not keep the others open
    (each failure is logged with its path, the first raised once every log is done)."""
    first: BaseException | None = None
    remote: dict[int, tuple[LogProcess, list[HandedOverLog]]] = {}
    for lg in logs:
        try:
            lg._shared.detach(lg)
            lg._drain()
            if not lg._is_local():
                assert lg._proc is not None
                remote.setdefault(id(lg._proc), (lg._proc, []))[1].append(lg)
        except Exception as err:
            log.error("%s: closing the log failed: %s", lg.path, err)
            first = first or err
    for proc, group in remote.values():
        replies = proc.request_all([(lg._CLOSE_OP, lg._id) for lg in group])
        for i, lg in enumerate(group):
            try:
                with lg._io:
                    if replies[i] is not None:
                        lg._closed_remote(replies[i])
                    elif not lg._is_local():
                        lg._go_local()
            except Exception as err:
                log.error("%s: closing the log failed: %s", lg.path, err)
                first = first or err
    for lg in logs:
        try:
            if lg._is_local():
                with lg._io:
                    lg._close_local()
        except Exception as err:
            log.error("%s: closing the log failed: %s", lg.path, err)
            first = first or err
    if first is not None:
        raise first


class CsvLog(HandedOverLog):
    def __init__(
        self,
        path: str | Path,
        columns: Sequence[str],
        max_queue: int = 10000,
        flush_period_s: float = FLUSH_PERIOD_S,
        sink: BatchSink | RemoteSink | None = None,
    ):
        """``sink``: formats each batch (its CSV text plus messages of its own, e.g. the run's
        MCAP) and is handed the batch and its messages once the CSV text is written. A
        :class:`RemoteSink` lives in the logging process; a log with an in-process sink is
        written in this process."""
        from companion.flightlog import logproc

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
        self._q: list[tuple[object, ...]] = []  # append and _drain's slicing are each atomic (the GIL)
        self._io = threading.Lock()  # the writer thread and close() take turns on the file
        self._closed = False
        self._sink = sink
        remote = sink is None or hasattr(sink, "remote_key")
        self._proc: LogProcess | None = logproc.client() if remote else None
        self._file: CsvFile | None = None
        if self._proc is None:
            self._file = CsvFile(self.path, self.columns, self._local_sink())
        else:
            CsvFile(self.path, self.columns).close()  # the header, here: errors raise now
            key = sink.remote_key if sink is not None else None  # type: ignore[union-attr]
            self._id = self._proc.open_csv(self.path, self.columns, key)
        self._shared = _SharedWriter.attach(self, float(flush_period_s))
        _OPEN.add(self)

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
        _cut_torn_line(self.path)
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

    def close(self) -> None:
        close_logs([self])


def close_logs(logs: Iterable[CsvLog]) -> None:
    """Close several logs (:meth:`CsvLog.close` each, idempotent) with one wait for the logging
    process (:func:`close_files`): the flight recorder's streams."""
    todo = [lg for lg in dict.fromkeys(logs) if not lg._closed]  # each once, in order
    for lg in todo:
        lg._closed = True
        _OPEN.discard(lg)
    try:
        close_files(todo)
    finally:
        for lg in todo:
            if lg.dropped:
                log.warning("%s: %d rows dropped (writer could not keep up)", lg.path, lg.dropped)


class _FailedFile(CsvFile):
    """A file that could not be reopened: every batch is counted as dropped."""

    def __init__(self, path: Path, err: OSError) -> None:  # no super().__init__: nothing to open
        self.path = path
        self.written = 0
        self.dropped = 0
        self.failed = err

    def write_batch(self, batch: list[tuple[object, ...]]) -> None:
        self.dropped += len(batch)

    def close(self) -> None:
        pass


def open_csv_file(path: Path, columns: tuple[str, ...], sink: BatchSink | None, append: bool) -> CsvFile:
    """A :class:`CsvFile` to continue (or start); one that cannot be opened is reported once by
    path and stands in as a file that counts every batch it is given as dropped (in this process,
    or in the logging process)."""
    try:
        return CsvFile(path, columns, sink, append=append)
    except OSError as err:
        log.error("%s: cannot write the log any more: %s", path, err)
        return _FailedFile(path, err)


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

"""The hand-over: how what the flight queues reaches its files without work on the control path.

Every log queues its rows (or records) in a list; one writer thread per flush period
(:class:`SharedWriter`, shared by every open log) takes each log's queue as one batch (by
slicing the list: no per-row work) every :data:`FLUSH_PERIOD_S`, or sooner when
:data:`HANDOVER_ROWS` rows wait (it then looks every :data:`WAKE_PERIOD_S`: a simulation running
many times faster than real time). Each batch is posted to the logging process
(:mod:`companion.flightlog.logproc`), and everything posted in a round is sent as one message; a
log written in this process (no logging process, or it died) writes its batch there instead.

:class:`HandedOverLog` is that logic for one file (the CSV logs, the simulator's ``.tlog``):
hand over, or continue the file here if the logging process is gone, first with the batches it
was never handed. :func:`close_files` closes several at once with one wait for the logging
process. A forked child gets writer threads of its own.
"""

from __future__ import annotations

import abc
import logging
import os
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path
from types import TracebackType
from typing import ClassVar, Protocol, Self

from companion.flightlog.hooks import FLIGHT, HAND_OVER, LogHooks, Post, batch_stage
from companion.flightlog.logproc import LogProcess, flush_current

log = logging.getLogger(__name__)

# the writer's period: what a hard crash can lose, in wall time, and what closing a log waits for
# at most (the logging process writing the last batch)
FLUSH_PERIOD_S = 0.1
# while rows come faster than HANDOVER_ROWS a period, the writer looks at the queues this often and
# hands them over once HANDOVER_ROWS rows and records wait (rows handed over young cost the flight
# less); a flight in real time (a few hundred rows a second) keeps one round a period
WAKE_PERIOD_S = 0.02
HANDOVER_ROWS = 256


class Drainable(Protocol):
    """What the writer thread serves: a log that hands over (or writes) what it queued."""

    path: Path

    def drain(self) -> None:
        """Hand over (or write) what was queued so far: the writer thread's round, public so a
        test can hand over mid-stream as that thread would."""


class SharedWriter:
    """The one writer thread of every log with the same period
    (:class:`~companion.flightlog.csvlog.CsvLog`, :class:`~companion.flightlog.mcaplog.McapFlightLog`,
    the ``.tlog``); after each round it hands what the logs posted to the logging process.
    Logs opened with :class:`~companion.flightlog.hooks.LogHooks` other than a flight's have a
    writer of their own (one per period and hooks), whose batches and sends are timed with them."""

    _writers: ClassVar[dict[tuple[float, LogHooks], SharedWriter]] = {}
    _lock = threading.Lock()

    def __init__(self, period_s: float, hooks: LogHooks = FLIGHT) -> None:
        self.period_s = period_s
        self.hooks = hooks
        self.logs: dict[Drainable, Callable[[], None]] = {}  # each log and its drain, as bound at attach
        self._flush = hooks.timed(HAND_OVER, flush_current)
        self._cond = threading.Condition()
        self._thread: threading.Thread | None = None

    @classmethod
    def attach(cls, lg: Drainable, period_s: float, hooks: LogHooks = FLIGHT) -> SharedWriter:
        """Serve ``lg`` from now on (its drain timed as ``"<file> batch"`` by ``hooks``)."""
        with cls._lock:
            w = cls._writers.get((period_s, hooks))
            if w is None:
                w = cls._writers[period_s, hooks] = SharedWriter(period_s, hooks)
            with w._cond:
                w.logs[lg] = hooks.timed(batch_stage(lg.path.name), lg.drain)
                if w._thread is None:
                    w._thread = threading.Thread(target=w._run, name=f"csvlog-writer-{period_s:g}s", daemon=True)
                    w._thread.start()
        return w

    def detach(self, lg: Drainable) -> Callable[[], None]:
        """Stop serving ``lg``; returns its drain as this writer called it (for its last batch)."""
        with self._cond:
            return self.logs.pop(lg, lg.drain)

    @classmethod
    def _forget_after_fork(cls) -> None:
        """A forked child has none of its parent's threads: its logs get writers of their own."""
        cls._writers = {}
        cls._lock = threading.Lock()

    def _run(self) -> None:
        period = self.period_s
        wait_s, last = period, time.monotonic()
        while True:
            with self._cond:
                self._cond.wait(wait_s)
                logs = list(self.logs.items())
            if not logs:  # nothing to hand over (another writer's logs' posts are its to send)
                wait_s = period
                continue
            now = time.monotonic()
            queued = sum(len(getattr(lg, "_q", ())) for lg, _ in logs)
            # a round once the period is over, or earlier once enough rows wait (a fast simulation):
            # rows handed over young cost the flight less than rows kept for the whole period
            if now - last < period and queued < HANDOVER_ROWS:
                continue
            # looked at every WAKE_PERIOD_S only while the rows come faster than HANDOVER_ROWS a period
            # (a flight in real time keeps one wake-up a period)
            wait_s = min(period, WAKE_PERIOD_S) if queued * period >= HANDOVER_ROWS * (now - last) else period
            last = now
            for _, drain in logs:
                drain()
            self._flush()


os.register_at_fork(after_in_child=SharedWriter._forget_after_fork)


class HandedOverLog(abc.ABC):
    """The flight's side of a log the logging process writes
    (:class:`~companion.flightlog.csvlog.CsvLog`, the simulator's
    :class:`~companion.flightlog.telemetry_tlog.TelemetryTlog`): what the loop queued is handed
    over as one batch per writer round (:meth:`drain`), or written here when logging in process;
    if the logging process dies, the file is continued here, first with the batches it was never
    handed (:meth:`_go_local`). A subclass says how its file is continued, written and closed here, and
    names its operations in the logging process (``_POST_OP``, ``_CLOSE_OP``)."""

    _POST_OP: ClassVar[str]
    _CLOSE_OP: ClassVar[str]
    path: Path
    _q: list[tuple[object, ...]]  # appended at the end by the producer, taken from the front by drain
    _io: threading.Lock  # the writer thread and close() take turns on the file
    _proc: LogProcess | None
    _post: Post  # hands one batch to _proc: LogHooks.hand_over(_proc), bound once
    _id: int
    _shared: SharedWriter

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

    @property
    def log_process(self) -> LogProcess | None:
        """The logging process this log hands its batches to (None: written here from the start)."""
        return self._proc

    def drain(self) -> None:
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
                if self._post((self._POST_OP, self._id, batch)):
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
            lg._shared.detach(lg)()  # the last batch, as the writer took them
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

"""A live MAVLink link's ``.tlog`` (:class:`TlogWriter`): packets from any thread (the event loop,
a link's reader thread, a MAVSDK callback) through a bounded queue to a writer thread that owns
the file.

The writer thread writes whole records in batches and hands every batch to the OS as soon as the
queue runs empty, so a crash loses nothing the writer has seen, and the control path never does
disk I/O. A full queue drops the packet and counts it (or, with ``drop_when_full=False``, waits:
used under the simulator's virtual clock, where waiting costs no simulated time and keeps files
identical for a seed). Packets may also be handed over as a function that builds them, so
encoding runs on the writer thread too.
"""

from __future__ import annotations

import contextlib
import logging
import os
import queue
import threading
import time
from collections.abc import Callable
from pathlib import Path
from types import TracebackType
from typing import BinaryIO

from companion.autopilot.interface import PacketSource
from companion.autopilot.mavlink_messages import UnknownMessage
from companion.flightlog.losses import LossCause, cause_of, fault_of, note_fault, note_lost
from companion.flightlog.tlog import TIMESTAMP, tlog_timestamp_us, write_all

log = logging.getLogger(__name__)

_BATCH = 4096
_STOP = object()


class _Flush:
    __slots__ = ("done",)

    def __init__(self) -> None:
        self.done = threading.Event()


class _Chunk:
    """Whole records (timestamp + packet) packed by the producer, handed over together."""

    __slots__ = ("data", "records")

    def __init__(self, data: bytes, records: int) -> None:
        self.data = data
        self.records = records


PACKED_RECORDS_PER_CHUNK = 256  # write_packed(): records kept by the producer before they go to the writer


class TlogWriter:
    """Append MAVLink packets to a ``.tlog`` from a writer thread.

    ``clock`` gives the UNIX time of a packet written without an explicit time (default
    ``time.time``; the simulator maps its loop clock onto a fixed epoch). The file is opened
    (and truncated, unless ``append``) here, so a bad path fails at once with a clear error. A
    write error (a full disk) stops the writer: said once with its cause
    (:mod:`companion.flightlog.losses`), the packets refused from then on counted in ``dropped``.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        max_queue: int = 20000,
        drop_when_full: bool = True,
        append: bool = False,
        clock: Callable[[], float] = time.time,
        fh: BinaryIO | None = None,
    ):
        if max_queue < 1:
            raise ValueError(f"max_queue = {max_queue}: must be >= 1")
        self.path = Path(path)
        self.clock = clock
        self.drop_when_full = drop_when_full
        self.written = 0  # records on disk
        self.dropped = 0  # packets refused: queue full, or the writer has failed or closed
        self.queue_dropped = 0  # of which: the queue was full
        self.encode_errors = 0  # deferred packets whose build function raised
        self.unknown_messages: dict[str, int] = {}  # messages the dialect does not define, by name or id
        self.error: str | None = None  # why the writer thread stopped early, if it did
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            # closed by the writer thread; ``fh``: an open unbuffered file instead (a test's that fails)
            self._fh = fh if fh is not None else open(self.path, "ab" if append else "wb", buffering=0)  # noqa: SIM115
        except OSError as err:
            raise OSError(err.errno, f"cannot open MAVLink log {self.path}: {err.strerror}") from None
        self._q: queue.Queue[object] = queue.Queue(max_queue)
        self._packed = bytearray()  # write_packed()'s records not handed to the writer yet
        self._packed_n = 0
        self._closed = False
        self._dead = False
        self._thread = threading.Thread(target=self._run, name=f"tlog-{self.path.name}", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ producer side
    def write(self, packet: PacketSource, t_unix_s: float | None = None) -> bool:
        """Queue one packet (bytes, or a function returning its bytes, called on the writer
        thread; None from it skips the record). False if it was dropped."""
        if self._closed or self._dead:
            self.dropped += 1
            return False
        if self._packed_n:  # write_packed()'s records first, in order (they share the one thread)
            self._hand_over_packed()
        usec = tlog_timestamp_us(self.clock() if t_unix_s is None else t_unix_s)
        return self._enqueue((usec, packet), 1)

    def _enqueue(self, item: object, records: int) -> bool:
        """Queue ``item`` (``records`` records) by the writer's policy: drop and count when full,
        or (``drop_when_full=False``) wait for room, but not on a writer that has died meanwhile."""
        if self.drop_when_full:
            try:
                self._q.put_nowait(item)
            except queue.Full:
                self.dropped += records
                self.queue_dropped += records
                return False
            return True
        while True:
            try:
                self._q.put(item, timeout=0.5)
                return True
            except queue.Full:
                if self._dead:
                    self.dropped += records
                    return False

    def write_packed(self, packet: bytes, t_unix_s: float | None = None) -> None:
        """Append one finished packet from the one thread that packs (the simulator's encoder):
        records are kept here and handed to the writer :data:`PACKED_RECORDS_PER_CHUNK` at a time,
        one queue hand-over instead of one per packet; :meth:`flush` and :meth:`close` hand over
        the rest (what a crash can lose: at most that many records), and so does :meth:`write`
        before its packet: mixed on one thread, the two keep their order. Not thread-safe: one
        thread packs (a log written from several threads uses :meth:`write` alone)."""
        if self._closed or self._dead:
            self.dropped += 1
            return
        usec = tlog_timestamp_us(self.clock() if t_unix_s is None else t_unix_s)
        buf = self._packed
        buf += TIMESTAMP.pack(usec)
        buf += packet
        self._packed_n += 1
        if self._packed_n >= PACKED_RECORDS_PER_CHUNK:
            self._hand_over_packed()

    def _hand_over_packed(self) -> None:
        if not self._packed_n:
            return
        chunk = _Chunk(bytes(self._packed), self._packed_n)
        self._packed.clear()
        self._packed_n = 0
        self._enqueue(chunk, chunk.records)

    def flush(self, timeout_s: float = 5.0) -> bool:
        """Wait until everything queued so far is handed to the OS. False on timeout or if the
        writer has stopped."""
        if self._closed or self._dead:
            return False
        self._hand_over_packed()
        marker = _Flush()
        try:
            self._q.put(marker, timeout=timeout_s)
        except queue.Full:
            return False
        return marker.done.wait(timeout_s) and not self._dead

    def close(self) -> None:
        """Write what is queued, sync and close the file; safe to call twice."""
        if self._closed:
            return
        if not self._dead:
            self._hand_over_packed()
        self._closed = True
        while self._thread.is_alive():
            try:
                self._q.put(_STOP, timeout=0.5)
                break
            except queue.Full:
                continue
        self._thread.join()
        note_lost(self.path, LossCause.QUEUE_FULL, self.queue_dropped, "MAVLink packets")
        stopped = self.dropped - self.queue_dropped  # refused once the writer had stopped (a full disk)
        note_lost(self.path, fault_of(self.path) or LossCause.IO_ERROR, stopped, "MAVLink packets")
        if self.encode_errors:
            log.warning("%s: %d MAVLink packets could not be encoded", self.path, self.encode_errors)
        if self.unknown_messages:
            log.info(
                "%s: left out %d messages pymavlink's ardupilotmega dialect does not define: %s",
                self.path,
                sum(self.unknown_messages.values()),
                ", ".join(f"{k} x {n}" for k, n in sorted(self.unknown_messages.items())),
            )

    def __enter__(self) -> TlogWriter:
        return self

    def __exit__(self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None) -> None:
        self.close()

    # ------------------------------------------------------------------ writer thread
    def _run(self) -> None:
        try:
            self._loop()
        except Exception as err:  # disk full, I/O error: keep what is written, refuse the rest
            self.error = f"{type(err).__name__}: {err}"
            self._dead = True
            cause = cause_of(err, self.path)
            note_fault(self.path, cause)
            log.error(
                "%s: %s: MAVLink log writer stopped: %s (everything before is kept; the flight goes on)",
                self.path,
                cause.value,
                self.error,
            )
        finally:
            self._dead = True
            self._release_waiters()
            with contextlib.suppress(OSError):
                os.fsync(self._fh.fileno())
            self._fh.close()

    def _loop(self) -> None:
        q = self._q
        while True:
            items = [q.get()]
            if q.qsize() < q.maxsize // 2:
                time.sleep(0.01)  # gather a batch: one wake-up and one write per batch, not per packet
            while len(items) < _BATCH:
                try:
                    items.append(q.get_nowait())
                except queue.Empty:
                    break
            buf = bytearray()
            n = 0
            markers: list[_Flush] = []
            stop = False
            for it in items:
                if it is _STOP:
                    stop = True
                    continue
                if isinstance(it, _Flush):
                    markers.append(it)
                    continue
                if isinstance(it, _Chunk):
                    buf += it.data
                    n += it.records
                    continue
                usec: int
                src: PacketSource
                usec, src = it  # type: ignore[misc]
                try:
                    packet: bytes | bytearray | None = src() if callable(src) else src
                except UnknownMessage as err:  # expected of a newer autopilot: counted, said once at close
                    key = str(err.name_or_id)
                    self.unknown_messages[key] = self.unknown_messages.get(key, 0) + 1
                    continue
                except Exception:
                    self.encode_errors += 1
                    if self.encode_errors in (1, 100, 10000):
                        log.exception("%s: cannot encode a MAVLink packet (%d so far)", self.path, self.encode_errors)
                    continue
                if not packet:
                    continue
                buf += TIMESTAMP.pack(usec)
                buf += packet
                n += 1
            try:
                if buf:
                    try:
                        self._write_all(bytes(buf))
                    except BaseException:
                        self.dropped += n
                        raise
                    self.written += n
            finally:
                for m in markers:
                    m.done.set()
            if stop:
                return

    def _write_all(self, data: bytes) -> None:
        write_all(self._fh, data, self.path)

    def _release_waiters(self) -> None:
        while True:
            try:
                it = self._q.get_nowait()
            except queue.Empty:
                return
            if isinstance(it, _Flush):
                it.done.set()
            elif isinstance(it, _Chunk):
                self.dropped += it.records
            elif it is not _STOP:
                self.dropped += 1


def open_tlog(path: str | Path) -> Callable[[bool], TlogWriter]:
    """The :data:`~companion.autopilot.interface.OpenPacketSink` a backend takes: a MAVLink log at
    ``path``, opened when the link connects (appended to on a reconnect)."""
    return lambda append: TlogWriter(path, append=append)

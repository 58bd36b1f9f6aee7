"""The embedded simulator's ``.tlog`` (:class:`TelemetryTlog`), encoded off the control path: the
flight only queues field values, handed over with the CSV logs' batches
(:mod:`companion.flightlog.handover`) and encoded by the logging process
(:class:`~companion.flightlog.tlog_replay.TlogReplayer`)."""

from __future__ import annotations

import dataclasses
import logging
import operator
import threading
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from companion.autopilot.types import FlightMode, TelemetrySample
from companion.flightlog.handover import FLUSH_PERIOD_S, HandedOverLog, SharedWriter
from companion.flightlog.hooks import FLIGHT, LogHooks, row_stage
from companion.flightlog.logproc import client
from companion.flightlog.losses import LossCause, cause_of, fault_of, note_lost
from companion.flightlog.registry import CloseOrder, forget, register
from companion.flightlog.tlog import cut_torn_record
from companion.flightlog.tlog_replay import (
    ACK_RECORD,
    COMMAND_RECORD,
    ROW_RECORD,
    TlogReplayer,
    open_replayer,
)
from companion.guidance.setpoint import VelocitySetpoint

log = logging.getLogger(__name__)

_FIELD_GETTERS: dict[type, Callable[[Any], Any]] = {}


def _field_getter(cls: type) -> Callable[[Any], Any]:
    """Every field of a sample (or setpoint) dataclass, in constructor order, as one tuple:
    ``cls(*getter(s)) == s``."""
    getter = _FIELD_GETTERS.get(cls)
    if getter is None:
        names = [f.name for f in dataclasses.fields(cls) if f.init]
        get = operator.attrgetter(*names)
        getter = _FIELD_GETTERS[cls] = get if len(names) > 1 else (lambda s: (get(s),))
    return getter


def _nothing(*args: Any) -> None:
    pass


class TelemetryTlog(HandedOverLog):
    """A :class:`~companion.flightlog.tlog_encoder.TelemetryEncoder`'s ``.tlog`` (the embedded
    simulator's), encoded off the control path: :meth:`sample`, :meth:`setpoint`, :meth:`command`
    and :meth:`command_ack` only queue the field values with the clock's time; the shared writer
    thread of the CSV logs (:class:`~companion.flightlog.handover.SharedWriter`, every 0.1 s) hands
    them to the logging process (:mod:`companion.flightlog.logproc`), which encodes them with the
    same encoder (:class:`~companion.flightlog.tlog_replay.TlogReplayer`) and writes the records:
    the same bytes as encoding at once (timestamps ``epoch_s + clock()``). ``custom_mode`` is
    evaluated here for every :class:`FlightMode` (the logging process gets the table).

    When logging in process (:data:`companion.flightlog.logproc.IN_PROCESS`, or the logging
    process could not be started) the writer thread encodes and writes the batches here. If the
    logging process dies, the file is continued here (a torn last record cut) with the records it
    was never handed, by a new encoder: its packet sequence numbers start again at 0. A process
    killed outright loses the records of the last 0.1 s; :meth:`close` writes everything queued
    and returns once the file is complete. Use the hooks from one thread."""

    def __init__(
        self,
        path: str | Path,
        *,
        boot_s: float,
        clock: Callable[[], float],
        epoch_s: float,
        custom_mode: Callable[[FlightMode], int],
        **encoder: Any,
    ) -> None:
        self.path = Path(path)
        self._clock = clock
        self._params: dict[str, Any] = {
            "boot_s": float(boot_s),
            "epoch_s": float(epoch_s),
            "custom_modes": {m: custom_mode(m) for m in FlightMode},
            "encoder": encoder,
        }
        self._q = []  # append and the writer's slicing are each atomic (the GIL)
        self._io = threading.Lock()
        self._closed = False
        self._remote_counts = (0, 0, 0)  # the logging process's (written, dropped, encode errors), once closed
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as err:
            raise OSError(err.errno, f"cannot open MAVLink log {self.path}: {err.strerror}") from None
        self._proc = client()
        self._local: TlogReplayer | None = None
        try:
            if self._proc is None:
                self._local = TlogReplayer(self.path, self._params, append=False)
            else:
                self.path.open("wb").close()  # errors raise here; the logging process writes it
                self._id = self._proc.new_id()
                self._proc.post(("tlog", self._id, str(self.path), self._params))
                self._post = FLIGHT.hand_over(self._proc)
        except OSError as err:
            raise OSError(err.errno, f"cannot open MAVLink log {self.path}: {err.strerror}") from None
        self._shared = SharedWriter.attach(self, FLUSH_PERIOD_S)
        register(self, CloseOrder.TLOG)

    def use_hooks(self, hooks: LogHooks) -> None:
        """Instrument this log from now on, before its first record (a bench's
        :class:`~companion.flightlog.hooks.LogHooks`): its hooks (:meth:`sample`,
        :meth:`setpoint`, :meth:`command`, :meth:`command_ack`) bound once timed as
        ``"flight.tlog row"``, its batches handed over by ``hooks.hand_over`` and served by
        those hooks' writer thread (timed as ``"flight.tlog batch"``). The simulator opens its
        ``.tlog`` itself: the run folder's :class:`~companion.flightlog.recorder.FlightRecorder`
        hands it the hooks it was opened with (:meth:`FlightRecorder.share_samples
        <companion.flightlog.recorder.FlightRecorder.share_samples>`)."""
        if self._proc is not None:
            self._post = hooks.hand_over(self._proc)
        self._shared.detach(self)
        self._shared = SharedWriter.attach(self, FLUSH_PERIOD_S, hooks)
        if hooks.stage_timer is not None:
            stage = row_stage(self.path.name)
            self.sample = hooks.timed(stage, self.sample)  # type: ignore[method-assign]
            self.setpoint = hooks.timed(stage, self.setpoint)  # type: ignore[method-assign]
            self.command = hooks.timed(stage, self.command)  # type: ignore[method-assign]
            self.command_ack = hooks.timed(stage, self.command_ack)  # type: ignore[method-assign]

    def take_no_records(self) -> None:
        """From now on (before its first record) every hook does nothing: the file is opened and
        closed with no records (``companion bench log``'s run folder with nothing logged:
        :class:`~companion.flightlog.recorder.NullRecorder`)."""
        self.sample = self.setpoint = _nothing  # type: ignore[method-assign,assignment]
        self.command = self.command_ack = _nothing  # type: ignore[method-assign,assignment]

    # ---- the hooks (the loop thread) ---------------------------------------------------------
    def sample(self, s: TelemetrySample) -> None:
        """Queue one reported sample (at the clock's current time)."""
        cls = type(s)
        get = _FIELD_GETTERS.get(cls) or _field_getter(cls)
        self._q.append((self._clock(), cls, *get(s)))

    def sample_tap(self) -> tuple[Callable[[tuple[Any, ...]], None], Callable[[], float], str]:
        """What a flight recorder listening to the same samples needs to queue each one here from
        the row it builds anyway, instead of :meth:`sample` (:meth:`FlightRecorder.share_samples
        <companion.flightlog.recorder.FlightRecorder.share_samples>`): this log's queue's
        ``append``, its clock and the record's marker. The record is ``(clock(), marker, cls,
        row)``; the row is not copied, so the hand-over pickles its values once for both logs, and
        the logging process rebuilds the sample from it
        (:func:`~companion.flightlog.tlog_replay.sample_from_row`): the same packets and timestamps
        as :meth:`sample`."""
        return self._q.append, self._clock, ROW_RECORD

    def setpoint(self, sp: VelocitySetpoint) -> None:
        """Queue the companion's velocity setpoint (SET_POSITION_TARGET_LOCAL_NED)."""
        self._q.append(
            (self._clock(), VelocitySetpoint, sp.north_m_s, sp.east_m_s, sp.down_m_s, sp.yaw_rad, sp.accel_ne_m_s2)
        )

    def command(self, command: int, params: Sequence[float] = ()) -> None:
        """Queue a COMMAND_LONG from the companion."""
        self._q.append((self._clock(), COMMAND_RECORD, command, tuple(params)))

    def command_ack(self, command: int, result: int) -> None:
        """Queue the autopilot's COMMAND_ACK."""
        self._q.append((self._clock(), ACK_RECORD, command, result))

    # ---- counts -------------------------------------------------------------------------------
    @property
    def written(self) -> int:
        """Records on disk (while the logging process writes the file: counted once closed)."""
        return self._remote_counts[0] + (self._local.written if self._local is not None else 0)

    @property
    def dropped(self) -> int:
        return self._remote_counts[1] + (self._local.dropped if self._local is not None else 0)

    @property
    def encode_errors(self) -> int:
        return self._remote_counts[2] + (self._local.encode_errors if self._local is not None else 0)

    @property
    def in_process(self) -> bool:
        return self._local is not None

    # ---- the shared writer thread, or close(): handover.HandedOverLog ------------------------------
    _POST_OP = "trecs"
    _CLOSE_OP = "tclose"

    def _is_local(self) -> bool:
        return self._local is not None

    def _open_local(self) -> None:
        cut_torn_record(self.path)
        self._local = open_replayer(self.path, self._params)

    def _write_local(self, batch: list[tuple[Any, ...]]) -> None:
        assert self._local is not None
        self._local.apply(batch)

    def _close_local(self) -> None:
        assert self._local is not None
        self._local.close()

    def _posted(self, n: int) -> None:
        pass  # records are counted by the logging process (its answer to the close)

    def _closed_remote(self, reply: tuple[int, ...]) -> None:
        self._remote_counts = (reply[0], reply[1], reply[2])

    def close(self) -> None:
        """Write everything queued, sync and close the file (idempotent)."""
        if self._closed:
            return
        self._closed = True
        forget(self, CloseOrder.TLOG)
        self._close_file()
        if self.dropped:  # only a file that could not be written drops records (the queue is unbounded)
            failed = self._local.failed if self._local is not None else None
            cause = fault_of(self.path) or (cause_of(failed, self.path) if failed else LossCause.IO_ERROR)
            note_lost(self.path, cause, self.dropped, "MAVLink records")
        if self.encode_errors:
            log.warning("%s: %d MAVLink records could not be encoded", self.path, self.encode_errors)

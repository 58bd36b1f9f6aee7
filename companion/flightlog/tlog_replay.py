"""The simulator's ``.tlog`` records encoded into the file (:class:`TlogReplayer`), in the logging
process or, when logging in process, on the writer thread.

:class:`~companion.flightlog.telemetry_tlog.TelemetryTlog` queues field values with their clock
time instead of packets: ``(t, sample class, *fields)`` for a sample, ``(t, VelocitySetpoint,
*fields)``, ``(t, COMMAND_RECORD, command, params)``, ``(t, ACK_RECORD, command, result)``, or
``(t, ROW_RECORD, sample class, flight recorder row)``. Each record is replayed through a
:class:`~companion.flightlog.tlog_encoder.TelemetryEncoder` at its own clock time, so the packets
and their timestamps are those an encoder writing at once would give.
"""

from __future__ import annotations

import contextlib
import dataclasses
import enum
import logging
import os
import typing
from collections.abc import Callable
from pathlib import Path
from typing import Any

from companion.autopilot.types import FlightMode
from companion.flightlog.losses import cause_of, note_fault
from companion.flightlog.tlog import TIMESTAMP, tlog_timestamp_us, write_all
from companion.flightlog.tlog_encoder import TelemetryEncoder
from companion.guidance.setpoint import VelocitySetpoint

log = logging.getLogger(__name__)

# what TelemetryTlog records, besides samples (a sample record holds its class)
COMMAND_RECORD = "command"
ACK_RECORD = "ack"
ROW_RECORD = "row"  # a flight recorder's row of the sample (FlightRecorder.share_samples): (t, ROW_RECORD, cls, row)
_ROW_CONVERSIONS: dict[type, list[tuple[int, Callable[[Any], Any]]]] = {}


def sample_from_row(cls: type, row: tuple[Any, ...]) -> Any:
    """The sample a flight recorder's row stands for (:mod:`companion.flightlog.recorder`: ``time_s,
    seq`` and then the other fields in order, enums as their value and flags as 0/1)."""
    conv = _ROW_CONVERSIONS.get(cls)
    if conv is None:
        hints = typing.get_type_hints(cls)
        names = [f.name for f in dataclasses.fields(cls)]
        if names[0] != "time_s":
            raise TypeError(f"{cls.__name__}: a sample's first field must be time_s, not {names[0]}")
        conv = _ROW_CONVERSIONS[cls] = [
            (i, hints[n])
            for i, n in enumerate(names[1:])
            if hints[n] is bool or (isinstance(hints[n], type) and issubclass(hints[n], enum.Enum))
        ]
    fields = list(row[2:])
    for i, typ in conv:
        fields[i] = typ(fields[i])
    return cls(row[0], *fields)


class TlogReplayer:
    """Encodes :class:`~companion.flightlog.telemetry_tlog.TelemetryTlog`'s records with a
    :class:`TelemetryEncoder` and appends them to the file, a batch at a time (in the logging
    process, or on the writer thread when logging in process): each record is replayed at its own
    clock time, so the packets and their timestamps are those a :class:`TelemetryEncoder` writing
    at once would give. An ``OSError`` (a full disk) stops the file: said once with the path and
    its cause (:mod:`companion.flightlog.losses`); that batch's records and later ones are counted
    in ``dropped``. ``fh``: the open unbuffered binary file to write instead of opening ``path``
    (a test's file that fails). Not thread-safe."""

    def __init__(self, path: Path, params: dict[str, Any], append: bool, fh: typing.BinaryIO | None = None) -> None:
        self.path = Path(path)
        self.written = 0
        self.dropped = 0
        self.encode_errors = 0
        self.failed: OSError | None = None
        self._epoch_s = float(params["epoch_s"])
        self._t = 0.0
        self._buf = bytearray()
        self._n = 0
        self._fh = fh if fh is not None else open(self.path, "ab" if append else "wb", buffering=0)  # noqa: SIM115
        modes: dict[FlightMode, int] = params["custom_modes"]
        self.encoder = TelemetryEncoder(
            self,
            boot_s=params["boot_s"],
            clock=lambda: self._t,
            custom_mode=modes.__getitem__,
            **params["encoder"],
        )

    def write_packed(self, packet: bytes, t_unix_s: float | None = None) -> None:
        self._buf += TIMESTAMP.pack(tlog_timestamp_us(self._epoch_s + self._t if t_unix_s is None else t_unix_s))
        self._buf += packet
        self._n += 1

    def apply(self, records: list[tuple[Any, ...]]) -> None:
        """Encode one batch and hand it to the OS."""
        enc = self.encoder
        for rec in records:
            self._t = rec[0]
            kind = rec[1]
            try:
                if kind is VelocitySetpoint:
                    enc.setpoint(VelocitySetpoint(*rec[2:]))
                elif kind == COMMAND_RECORD:
                    enc.command(rec[2], rec[3])
                elif kind == ACK_RECORD:
                    enc.command_ack(rec[2], rec[3])
                elif kind == ROW_RECORD:
                    enc.sample(sample_from_row(rec[2], rec[3]))
                else:
                    enc.sample(kind(*rec[2:]))
            except Exception:
                self.encode_errors += 1
                if self.encode_errors in (1, 100, 10000):
                    log.exception("%s: cannot encode a record (%d so far)", self.path, self.encode_errors)
        self._write_out()

    def _write_out(self) -> None:
        n, data = self._n, bytes(self._buf)
        self._buf.clear()
        self._n = 0
        if not n:
            return
        if self.failed is not None or self._fh.closed:
            self.dropped += n
            return
        try:
            write_all(self._fh, data, self.path)
        except OSError as err:
            self.failed = err
            self.dropped += n
            cause = cause_of(err, self.path)
            note_fault(self.path, cause)
            log.error(
                "%s: %s: cannot write the MAVLink log any more (%s); the flight goes on", self.path, cause.value, err
            )
            return
        self.written += n

    def close(self) -> None:
        """Sync and close the file (idempotent)."""
        if self._fh.closed:
            return
        with contextlib.suppress(OSError):
            os.fsync(self._fh.fileno())
        try:
            self._fh.close()
        except OSError as err:
            if self.failed is None:  # else said when it stopped
                log.error("%s: closing the MAVLink log failed: %s", self.path, err)


class _FailedReplayer(TlogReplayer):
    """A ``.tlog`` that could not be reopened: every record is counted as dropped."""

    def __init__(self, path: Path, err: OSError) -> None:  # no super().__init__: nothing to open
        self.path = path
        self.written = 0
        self.dropped = 0
        self.encode_errors = 0
        self.failed = err

    def apply(self, records: list[tuple[Any, ...]]) -> None:
        self.dropped += len(records)

    def close(self) -> None:
        pass


def open_replayer(path: Path, params: dict[str, Any]) -> TlogReplayer:
    """A :class:`TlogReplayer` continuing ``path``; one that cannot be opened is reported once by
    path and counts every record it is given as dropped (in this process, or in the logging
    process)."""
    try:
        return TlogReplayer(path, params, append=True)
    except OSError as err:
        cause = cause_of(err, path)
        note_fault(path, cause)
        log.error("%s: %s: cannot write the MAVLink log any more (%s); the flight goes on", path, cause.value, err)
        return _FailedReplayer(path, err)

"""MAVLink telemetry logs (``.tlog``): the link traffic, as pymavlink, MAVExplorer and QGC read it.

A ``.tlog`` is a sequence of records, each an 8-byte big-endian timestamp in microseconds since
the UNIX epoch followed by one raw MAVLink packet (pymavlink ``mavfile.setup_logfile`` /
``mavlogfile``). As pymavlink does, the timestamp's two low bits are cleared (MAVProxy keeps a
link number there; ours is link 0).

The writers: :class:`~companion.flightlog.tlog_writer.TlogWriter` (a live link's packets, from
any thread) and :class:`~companion.flightlog.telemetry_tlog.TelemetryTlog` (the embedded
simulator's telemetry, encoded by :class:`~companion.flightlog.tlog_encoder.TelemetryEncoder` off
the control path).
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

TIMESTAMP = struct.Struct(">Q")  # a record's timestamp, before its packet
MAX_RECORD_BYTES = 8 + 10 + 255 + 2 + 13  # timestamp, MAVLink 2 header, payload, CRC, signature
log = logging.getLogger(__name__)
_LINK_BITS = ~3  # pymavlink/MAVProxy: the two low timestamp bits carry the link number


def tlog_timestamp_us(t_unix_s: float) -> int:
    """The record timestamp for a UNIX time in seconds (microseconds, link bits cleared)."""
    return round(float(t_unix_s) * 1e6) & _LINK_BITS


def write_all(fh: Any, data: bytes, path: Path) -> None:
    """Write every byte to an unbuffered file (a short write is retried; none at all raises)."""
    view = memoryview(data)
    while view:
        k = fh.write(view)
        if k is None or k <= 0:
            raise OSError(f"short write to {path}")
        view = view[k:]


def read_tlog(path: str | Path, types: Sequence[str] | None = None) -> Iterator[Any]:
    """The messages of a ``.tlog`` through pymavlink's own reader (``mavutil.mavlink_connection``),
    in file order; each with its record's time (:func:`record_time_s`). ``types`` filters by message name."""
    from pymavlink import mavutil

    conn = mavutil.mavlink_connection(str(path), dialect="ardupilotmega", robust_parsing=True)
    try:
        want = list(types) if types is not None else None
        while True:
            m = conn.recv_match(type=want)
            if m is None:
                return
            if m.get_type() != "BAD_DATA":
                yield m
    finally:
        conn.close()


def record_time_s(msg: Any) -> float:
    """The time of a message :func:`read_tlog` gave, UNIX seconds: its record's timestamp (pymavlink
    keeps it in ``_timestamp``)."""
    return float(msg._timestamp)


def cut_torn_record(path: Path) -> None:
    """Drop a last ``.tlog`` record that is not whole (its writer killed mid-write) before the
    file is continued: records are walked from the start (8-byte timestamp, unsigned MAVLink 2)."""
    try:
        with path.open("r+b") as fh:
            data = fh.read()
            pos = 0
            while pos + 11 <= len(data) and data[pos + 8] == 0xFD:  # up to the incompat flags
                end = pos + 8 + 12 + data[pos + 9] + (13 if data[pos + 10] & 1 else 0)
                if end > len(data):
                    break
                pos = end
            if 0 < len(data) - pos <= MAX_RECORD_BYTES:
                fh.truncate(pos)
            elif pos != len(data):  # more than a torn record: damage inside, whole records may follow
                log.warning("%s: bytes %d to %d are not whole records: kept", path, pos, len(data))
    except OSError:
        pass  # the writer's own open reports the path's trouble

"""MAVLink telemetry logs (``.tlog``): the link traffic, as pymavlink, MAVExplorer and QGC read it.

A ``.tlog`` is a sequence of records, each an 8-byte big-endian timestamp in microseconds since
the UNIX epoch followed by one raw MAVLink packet (pymavlink ``mavfile.setup_logfile`` /
``mavlogfile``). As pymavlink does, the timestamp's two low bits are cleared (MAVProxy keeps a
link number there; ours is link 0).

:class:`TlogWriter` takes packets from any thread (the event loop, a link's reader thread, a
MAVSDK callback) through a bounded queue; a writer thread owns the file, writes whole records
in batches and hands every batch to the OS as soon as the queue runs empty, so a crash loses
nothing the writer has seen, and the control path never does disk I/O. A full queue drops the
packet and counts it (or, with ``drop_when_full=False``, waits: used under the simulator's
virtual clock, where waiting costs no simulated time and keeps files identical for a seed).
Packets may also be handed over as a function that builds them, so encoding runs on the writer
thread too.

:class:`MavlinkPacker` makes MAVLink 2 packets from pymavlink messages or from decoded fields
(MAVSDK only exposes decoded messages), one sequence counter per source. :class:`TelemetryEncoder`
turns what an autopilot without a MAVLink link reports (:mod:`companion.autopilot.types`
samples) and what the companion sends it into MAVLink, so the embedded simulator's flights give a
``.tlog`` too. The simulator does not encode on its control path: :class:`TelemetryTlog` queues
the field values with the clock time, and the logging process (:mod:`companion.flightlog.logproc`)
replays them through a :class:`TelemetryEncoder` (:class:`TlogReplayer`), giving the same bytes.
"""

from __future__ import annotations

import atexit
import contextlib
import dataclasses
import enum
import logging
import math
import operator
import os
import queue
import struct
import threading
import time
import typing
import weakref
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from types import TracebackType
from typing import Any, Protocol

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from companion.autopilot.interface import PacketSource
from companion.autopilot.mavlink_messages import DirectPacker, velocity_setpoint_fields
from companion.autopilot.types import (
    Attitude,
    FlightMode,
    GlobalPosition,
    GpsRaw,
    HomePosition,
    Imu,
    LandedState,
    PositionNed,
    StatusText,
    TelemetrySample,
    VehicleStatus,
)
from companion.flightlog.csvlog import HandedOverLog
from companion.guidance.setpoint import VelocitySetpoint

log = logging.getLogger(__name__)

_TS = struct.Struct(">Q")
_LINK_BITS = ~3  # pymavlink/MAVProxy: the two low timestamp bits carry the link number
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


class TlogWriter:
    """Append MAVLink packets to a ``.tlog`` from a writer thread.

    ``clock`` gives the UNIX time of a packet written without an explicit time (default
    ``time.time``; the simulator maps its loop clock onto a fixed epoch). The file is opened
    (and truncated, unless ``append``) here, so a bad path fails at once with a clear error.
    """

    def __init__(
        self,
        path: str | Path,
        *,
        max_queue: int = 20000,
        drop_when_full: bool = True,
        append: bool = False,
        clock: Callable[[], float] = time.time,
    ):
        if max_queue < 1:
            raise ValueError(f"max_queue = {max_queue}: must be >= 1")
        self.path = Path(path)
        self.clock = clock
        self.drop_when_full = drop_when_full
        self.written = 0  # records on disk
        self.dropped = 0  # packets refused: queue full, or the writer has failed or closed
        self.encode_errors = 0  # deferred packets whose build function raised
        self.error: str | None = None  # why the writer thread stopped early, if it did
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(self.path, "ab" if append else "wb", buffering=0)  # noqa: SIM115 (closed by the writer thread)
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
        buf += _TS.pack(usec)
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
        if self.dropped:
            log.warning(
                "%s: %d MAVLink packets dropped (queue full, or the writer had stopped)", self.path, self.dropped
            )
        if self.encode_errors:
            log.warning("%s: %d MAVLink packets could not be encoded", self.path, self.encode_errors)

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
            log.error("%s: MAVLink log writer stopped: %s (everything before is kept)", self.path, self.error)
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
                except Exception:
                    self.encode_errors += 1
                    if self.encode_errors in (1, 100, 10000):
                        log.exception("%s: cannot encode a MAVLink packet (%d so far)", self.path, self.encode_errors)
                    continue
                if not packet:
                    continue
                buf += _TS.pack(usec)
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


def read_tlog(path: str | Path, types: Sequence[str] | None = None) -> Iterator[Any]:
    """The messages of a ``.tlog`` through pymavlink's own reader (``mavutil.mavlink_connection``),
    in file order; each has ``_timestamp`` (UNIX seconds). ``types`` filters by message name."""
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


# ---------------------------------------------------------------------------------- encoding
_LANDED = {
    LandedState.UNKNOWN: mavlink2.MAV_LANDED_STATE_UNDEFINED,
    LandedState.ON_GROUND: mavlink2.MAV_LANDED_STATE_ON_GROUND,
    LandedState.IN_AIR: mavlink2.MAV_LANDED_STATE_IN_AIR,
    LandedState.TAKING_OFF: mavlink2.MAV_LANDED_STATE_TAKEOFF,
    LandedState.LANDING: mavlink2.MAV_LANDED_STATE_LANDING,
}
_U16_MAX = 65535


def _i32(x: float) -> int:
    return max(-(2**31), min(2**31 - 1, round(float(x))))


class TelemetryEncoder:
    """MAVLink for an autopilot that has no MAVLink link (the embedded simulator).

    :meth:`sample` encodes what the autopilot reports (HEARTBEAT with mode and armed flag,
    SYS_STATUS, BATTERY_STATUS and EXTENDED_SYS_STATE from a status; ATTITUDE; HIGHRES_IMU;
    LOCAL_POSITION_NED; GLOBAL_POSITION_INT; GPS_RAW_INT; HOME_POSITION; STATUSTEXT) from
    ``system_id``/``component_id``; :meth:`setpoint`, :meth:`command` and :meth:`command_ack`
    encode what the companion sends (SET_POSITION_TARGET_LOCAL_NED, COMMAND_LONG from
    ``companion_component``) and the autopilot's answer. ``custom_mode`` maps a
    :class:`FlightMode` onto the autopilot's HEARTBEAT custom mode. Each packet is
    packed at once by a :class:`~companion.autopilot.mavlink_messages.DirectPacker` (the bytes
    pymavlink gives, without building its message objects) and handed to the writer in chunks
    (:meth:`TlogWriter.write_packed`); ``boot_s`` is the clock time of the autopilot's boot
    (``time_boot_ms``). Use it from one thread.
    """

    def __init__(
        self,
        writer: PackedRecords,
        *,
        boot_s: float,
        clock: Callable[[], float],
        custom_mode: Callable[[FlightMode], int],
        autopilot: int = mavlink2.MAV_AUTOPILOT_PX4,
        vehicle_type: int = mavlink2.MAV_TYPE_QUADROTOR,
        system_id: int = 1,
        component_id: int = mavlink2.MAV_COMP_ID_AUTOPILOT1,
        companion_component: int = mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER,
    ):
        self.writer = writer
        self.boot_s = boot_s
        self.clock = clock
        self.custom_mode = custom_mode
        self.autopilot = autopilot
        self.vehicle_type = vehicle_type
        self.vehicle_id = (system_id, component_id)
        self.companion_id = (system_id, companion_component)
        self._packer = DirectPacker()
        self._velocity = (0.0, 0.0, 0.0)
        self._yaw = 0.0

    def _emit(self, source: tuple[int, int], cls: Any, args: tuple[Any, ...]) -> None:
        try:
            packet = self._packer.pack(cls, args, *source)
        except (struct.error, TypeError, ValueError, OverflowError):  # a value the field cannot hold
            w = self.writer
            w.encode_errors += 1
            if w.encode_errors in (1, 100, 10000):
                log.exception("%s: cannot encode %s (%d so far)", w.path, cls.msgname, w.encode_errors)
            return
        self.writer.write_packed(packet)

    def _ms(self, t: float) -> int:
        return max(0, int((t - self.boot_s) * 1000.0)) & 0xFFFFFFFF

    def _us(self, t: float) -> int:
        return max(0, int((t - self.boot_s) * 1e6))

    def sample(self, s: TelemetrySample) -> None:
        """Encode one reported sample (at the clock's current time)."""
        t = self.clock()
        ms, us = self._ms(t), self._us(t)
        m: list[tuple[Any, tuple[Any, ...]]]
        match s:
            case Attitude():
                self._yaw = s.yaw_rad
                m = [
                    (
                        mavlink2.MAVLink_attitude_message,
                        (
                            ms,
                            s.roll_rad,
                            s.pitch_rad,
                            s.yaw_rad,
                            s.rollspeed_rad_s,
                            s.pitchspeed_rad_s,
                            s.yawspeed_rad_s,
                        ),
                    )
                ]
            case Imu():
                m = [
                    (
                        mavlink2.MAVLink_highres_imu_message,
                        (
                            us,
                            s.accel_x_m_s2,
                            s.accel_y_m_s2,
                            s.accel_z_m_s2,
                            s.gyro_x_rad_s,
                            s.gyro_y_rad_s,
                            s.gyro_z_rad_s,
                            0.0,
                            0.0,
                            0.0,
                            0.0,
                            0.0,
                            0.0,
                            0.0,
                            0b111111,  # fields_updated: accelerometer and gyro
                            0,
                        ),
                    )
                ]
            case PositionNed():
                self._velocity = (s.north_m_s, s.east_m_s, s.down_m_s)
                m = [
                    (
                        mavlink2.MAVLink_local_position_ned_message,
                        (ms, s.north_m, s.east_m, s.down_m, s.north_m_s, s.east_m_s, s.down_m_s),
                    )
                ]
            case GlobalPosition():
                vn, ve, vd = self._velocity
                hdg = round(math.degrees(self._yaw) % 360.0 * 100.0) % 36000
                m = [
                    (
                        mavlink2.MAVLink_global_position_int_message,
                        (
                            ms,
                            _i32(s.lat_deg * 1e7),
                            _i32(s.lon_deg * 1e7),
                            _i32(s.alt_amsl_m * 1000.0),
                            _i32(s.alt_rel_m * 1000.0),
                            round(float(vn) * 100.0),
                            round(float(ve) * 100.0),
                            round(float(vd) * 100.0),
                            hdg,
                        ),
                    )
                ]
            case GpsRaw():
                eph = _U16_MAX if not math.isfinite(s.eph_m) else min(_U16_MAX - 1, round(float(s.eph_m) * 100.0))
                m = [
                    (
                        mavlink2.MAVLink_gps_raw_int_message,
                        (
                            us,
                            s.fix_type,
                            _i32(s.lat_deg * 1e7),
                            _i32(s.lon_deg * 1e7),
                            _i32(s.alt_amsl_m * 1000.0),
                            eph,
                            _U16_MAX,
                            _U16_MAX,
                            _U16_MAX,
                            s.satellites,
                        ),
                    )
                ]
            case VehicleStatus():
                m = self._status(s)
            case HomePosition():
                m = [
                    (
                        mavlink2.MAVLink_home_position_message,
                        (
                            _i32(s.lat_deg * 1e7),
                            _i32(s.lon_deg * 1e7),
                            _i32(s.alt_amsl_m * 1000.0),
                            s.north_m,
                            s.east_m,
                            s.down_m,
                            [1.0, 0.0, 0.0, 0.0],
                            0.0,
                            0.0,
                            0.0,
                            us,
                        ),
                    )
                ]
            case StatusText():
                m = [
                    (
                        mavlink2.MAVLink_statustext_message,
                        (s.severity, s.text.encode("utf-8", errors="replace")[:50], 0, 0),
                    )
                ]
            case _:
                return
        for cls, args in m:
            self._emit(self.vehicle_id, cls, args)

    def _status(self, s: VehicleStatus) -> list[tuple[Any, tuple[Any, ...]]]:
        base = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if s.armed:
            base |= mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
        state = mavlink2.MAV_STATE_ACTIVE if s.armed else mavlink2.MAV_STATE_STANDBY
        prearm = mavlink2.MAV_SYS_STATUS_PREARM_CHECK
        remaining = max(0, min(100, round(float(s.battery_pct))))
        return [
            (
                mavlink2.MAVLink_heartbeat_message,
                (self.vehicle_type, self.autopilot, base, self.custom_mode(s.mode), state, 3),
            ),
            (
                mavlink2.MAVLink_sys_status_message,
                (prearm, prearm, prearm if s.healthy else 0, 0, _U16_MAX, -1, remaining, 0, 0, 0, 0, 0, 0),
            ),
            (
                mavlink2.MAVLink_battery_status_message,
                (
                    0,
                    mavlink2.MAV_BATTERY_FUNCTION_ALL,
                    mavlink2.MAV_BATTERY_TYPE_LIPO,
                    32767,
                    [_U16_MAX] * 10,
                    -1,
                    -1,
                    -1,
                    remaining,
                ),
            ),
            (mavlink2.MAVLink_extended_sys_state_message, (mavlink2.MAV_VTOL_STATE_UNDEFINED, _LANDED[s.landed])),
        ]

    def setpoint(self, sp: VelocitySetpoint) -> None:
        """The companion's velocity setpoint, as SET_POSITION_TARGET_LOCAL_NED."""
        ms = self._ms(self.clock())
        ts, tc = self.vehicle_id
        fields = velocity_setpoint_fields(ms, ts, tc, sp)
        self._emit(self.companion_id, mavlink2.MAVLink_set_position_target_local_ned_message, fields)

    def command(self, command: int, params: Sequence[float] = ()) -> None:
        """A COMMAND_LONG from the companion (up to seven parameters)."""
        p = [float(x) for x in params][:7]
        p += [0.0] * (7 - len(p))
        ts, tc = self.vehicle_id
        self._emit(self.companion_id, mavlink2.MAVLink_command_long_message, (ts, tc, command, 0, *p))

    def command_ack(self, command: int, result: int) -> None:
        """The autopilot's COMMAND_ACK to the companion."""
        ts, tc = self.companion_id
        self._emit(self.vehicle_id, mavlink2.MAVLink_command_ack_message, (command, result, 0, 0, ts, tc))


# ------------------------------------------------------------------- encoded off the control path
class PackedRecords(Protocol):
    """Where a :class:`TelemetryEncoder` puts its packets (:class:`TlogWriter`, or
    :class:`TlogReplayer` in the logging process)."""

    path: Path
    encode_errors: int

    def write_packed(self, packet: bytes, t_unix_s: float | None = None) -> None: ...


# what TelemetryTlog records, besides samples (a sample record holds its class)
_COMMAND = "command"
_ACK = "ack"
_ROW = "row"  # a flight recorder's row of the sample (FlightRecorder.share_samples): (t, _ROW, cls, row)
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


class TlogReplayer:
    """Encodes :class:`TelemetryTlog`'s records with a :class:`TelemetryEncoder` and appends them
    to the file, a batch at a time (in the logging process, or on the writer thread when logging
    in process): each record is replayed at its own clock time, so the packets and their
    timestamps are those a :class:`TelemetryEncoder` writing at once would give. An ``OSError``
    is logged once with the path; later records are counted in ``dropped``. Not thread-safe."""

    def __init__(self, path: Path, params: dict[str, Any], append: bool) -> None:
        self.path = Path(path)
        self.written = 0
        self.dropped = 0
        self.encode_errors = 0
        self.failed: OSError | None = None
        self._epoch_s = float(params["epoch_s"])
        self._t = 0.0
        self._buf = bytearray()
        self._n = 0
        self._fh = open(self.path, "ab" if append else "wb", buffering=0)  # noqa: SIM115 (closed by close())
        modes: dict[FlightMode, int] = params["custom_modes"]
        self.encoder = TelemetryEncoder(
            self,
            boot_s=params["boot_s"],
            clock=lambda: self._t,
            custom_mode=modes.__getitem__,
            **params["encoder"],
        )

    def write_packed(self, packet: bytes, t_unix_s: float | None = None) -> None:
        self._buf += _TS.pack(tlog_timestamp_us(self._epoch_s + self._t if t_unix_s is None else t_unix_s))
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
                elif kind == _COMMAND:
                    enc.command(rec[2], rec[3])
                elif kind == _ACK:
                    enc.command_ack(rec[2], rec[3])
                elif kind == _ROW:
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
            log.error("%s: cannot write the MAVLink log any more: %s", self.path, err)
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
            log.error("%s: closing the MAVLink log failed: %s", self.path, err)


def cut_torn_record(path: Path) -> None:
    """Drop a last ``.tlog`` record that is not whole (its writer killed mid-write) before the
    file is continued: records are walked from the start (8-byte timestamp, unsigned MAVLink 2)."""
    try:
        with path.open("r+b") as fh:
            data = fh.read()
            pos = 0
            while pos + 10 <= len(data) and data[pos + 8] == 0xFD:
                end = pos + 8 + 12 + data[pos + 9] + (13 if data[pos + 10] & 1 else 0)
                if end > len(data):
                    break
                pos = end
            if pos != len(data):
                fh.truncate(pos)
    except OSError:
        pass  # the replayer's own open reports the path's trouble


_OPEN_TLOGS: weakref.WeakSet[TelemetryTlog] = weakref.WeakSet()


@atexit.register
def _close_open_tlogs() -> None:
    for t in list(_OPEN_TLOGS):
        t.close()


class TelemetryTlog(HandedOverLog):
    """A :class:`TelemetryEncoder`'s ``.tlog`` (the embedded simulator's), encoded off the control
    path: :meth:`sample`, :meth:`setpoint`, :meth:`command` and :meth:`command_ack` only queue the
    field values with the clock's time; the shared writer thread of the CSV logs
    (:class:`~companion.flightlog.csvlog._SharedWriter`, every 0.1 s) hands them to the logging
    process (:mod:`companion.flightlog.logproc`), which encodes them with the same
    :class:`TelemetryEncoder` (:class:`TlogReplayer`) and writes the records: the same bytes as
    encoding at once (timestamps ``epoch_s + clock()``). ``custom_mode`` is evaluated here for
    every :class:`FlightMode` (the logging process gets the table).

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
        from companion.flightlog import csvlog, logproc

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
        self._proc = logproc.client()
        self._local: TlogReplayer | None = None
        try:
            if self._proc is None:
                self._local = TlogReplayer(self.path, self._params, append=False)
            else:
                self.path.open("wb").close()  # errors raise here; the logging process writes it
                self._id = self._proc.new_id()
                self._proc.post(("tlog", self._id, str(self.path), self._params))
        except OSError as err:
            raise OSError(err.errno, f"cannot open MAVLink log {self.path}: {err.strerror}") from None
        self._shared = csvlog._SharedWriter.attach(self, csvlog.FLUSH_PERIOD_S)
        _OPEN_TLOGS.add(self)

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
        row)``; the row is not copied, so the hand-over pickles its values once for both logs,
        and the logging process rebuilds the sample from it (:func:`sample_from_row`): the same
        packets and timestamps as :meth:`sample`."""
        return self._q.append, self._clock, _ROW

    def setpoint(self, sp: VelocitySetpoint) -> None:
        """Queue the companion's velocity setpoint (SET_POSITION_TARGET_LOCAL_NED)."""
        self._q.append((self._clock(), VelocitySetpoint, sp.north_m_s, sp.east_m_s, sp.down_m_s, sp.yaw_rad))

    def command(self, command: int, params: Sequence[float] = ()) -> None:
        """Queue a COMMAND_LONG from the companion."""
        self._q.append((self._clock(), _COMMAND, command, tuple(params)))

    def command_ack(self, command: int, result: int) -> None:
        """Queue the autopilot's COMMAND_ACK."""
        self._q.append((self._clock(), _ACK, command, result))

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

    # ---- the shared writer thread, or close(): csvlog.HandedOverLog -------------------------------
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
        _OPEN_TLOGS.discard(self)
        self._close_file()
        if self.dropped:
            log.warning("%s: %d MAVLink records dropped (the file could not be written)", self.path, self.dropped)
        if self.encode_errors:
            log.warning("%s: %d MAVLink records could not be encoded", self.path, self.encode_errors)


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
        log.error("%s: cannot write the MAVLink log any more: %s", path, err)
        return _FailedReplayer(path, err)

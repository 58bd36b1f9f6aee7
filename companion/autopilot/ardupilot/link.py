"""The pymavlink link to ArduPilot: UDP, TCP or a serial port.

A reader thread owns the receive side: it hands each message to the telemetry decoder, sends the
companion's own 1 Hz HEARTBEAT, keeps the signing timestamp file and counts malformed bytes (they
are ignored, never fatal). Calls for the event loop go through :meth:`ArduPilotLink._post`.

With ``signing`` (a :class:`~companion.autopilot.signing.SigningSetup`, from ``[signing]``) every
packet sent is MAVLink 2 signed, and unless ``allow_unsigned`` the vehicle's unsigned or wrongly
signed packets are dropped (RADIO_STATUS / RADIO excepted, as ArduPilot does): a vehicle that does
not sign with our key is then never heard, and connect() fails naming signing.

With ``tlog`` (a :data:`~companion.autopilot.interface.OpenPacketSink`, e.g. a MAVLink ``.tlog``
writer with its own thread), every packet received (as it arrived, from any system on the link)
and every packet sent goes into the sink.
"""

from __future__ import annotations

import abc
import asyncio
import collections
import contextlib
import logging
import math
import os
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Literal

from companion.autopilot.ardupilot.dialect import mavlink, mavutil
from companion.autopilot.interface import (
    AutopilotError,
    AutopilotUnreachable,
    ConnectionUrlError,
    LinkDeviceMissing,
    LinkLatch,
    LinkTraffic,
    OpenPacketSink,
    PacketSink,
    TelemetryCache,
    check_port,
)
from companion.autopilot.liveness import LoopLiveness
from companion.autopilot.signing import (
    SigningError,
    SigningSetup,
    apply_to_mavlink,
    write_timestamp_file,
)
from companion.autopilot.timesync import ClockOffset, ClockOffsetEstimator
from companion.autopilot.types import (
    LandedState,
)

log = logging.getLogger(__name__)

TIMESTAMP_SAVE_PERIOD_S = 30.0  # as ArduPilot saves its signing timestamp
HEARTBEAT_GRACE_S = 3.5  # 1 Hz heartbeats: telemetry proves liveness in between (MAVSDK uses 3 s)


@dataclass
class LinkCounters:
    messages: int = 0
    heartbeats: int = 0
    bad_data: int = 0
    garbage_bytes: int = 0
    read_errors: int = 0
    decode_errors: int = 0  # messages the telemetry decoder raised on (dropped, logged)
    setpoints_sent: int = 0
    setpoints_dropped: int = 0
    commands_sent: int = 0
    stream_requests: int = 0
    stream_rerequests: int = 0  # single streams asked for again, arriving at under half their rate
    signature_rejects: int = 0  # packets dropped by our signing check (unsigned or another key)
    signed_heartbeats: int = 0  # heartbeats of the vehicle whose signature our key verified
    signed_from_vehicle: int = 0  # any packet of the vehicle whose signature our key verified
    heartbeats_withheld: int = 0  # our heartbeat slots skipped while the control loop was stalled


def parse_connection(url: str, baud: int = 57600) -> tuple[str, int, str]:
    """Turn a connection URL into (pymavlink device, baud, kind).

    Accepted: ``udpin:HOST:PORT`` / ``udpin://HOST:PORT`` / ``udp://:PORT`` (listen),
    ``udpout:HOST:PORT`` / ``udpout://HOST:PORT``, ``tcp:HOST:PORT`` / ``tcp://`` /
    ``tcpout://``, ``serial:///dev/ttyX:BAUD``, or a device path (``/dev/ttyX``, ``/dev/ttyX:BAUD``,
    ``COM3``) with ``baud``.
    """
    u = url.strip()
    if not u:
        raise ConnectionUrlError("empty connection URL")
    scheme, sep, rest = u.partition(":")
    scheme = scheme.lower()
    if sep and scheme in ("udpin", "udpout", "udp", "tcp", "tcpout", "tcpin", "serial"):
        rest = rest.removeprefix("//")
        if scheme == "serial":
            dev, _, b = rest.rpartition(":") if rest.rsplit(":", 1)[-1].isdigit() else (rest, "", "")
            return dev, int(b) if b else baud, "serial"
        host, _, port = rest.rpartition(":")
        if not port.isdigit():
            raise ConnectionUrlError(f"connection {url!r}: expected {scheme}:HOST:PORT")
        check_port(url, port)
        if scheme == "udp":  # MAVSDK style udp://:14540 listens
            scheme = "udpin"
        if scheme == "tcpout":
            scheme = "tcp"
        host = host or ("0.0.0.0" if scheme in ("udpin", "tcpin") else "127.0.0.1")
        return f"{scheme}:{host}:{port}", baud, scheme
    # a device path, optionally with :BAUD
    dev, b = u, ""
    head, _, tail = u.rpartition(":")
    if head and tail.isdigit() and not head.endswith(":"):
        dev, b = head, tail
    return dev, int(b) if b else baud, "serial"


class LoopPoster:
    """Calls handed from a thread (the MAVLink reader) to an event loop, run there in the order
    posted. Calls posted while the loop has not yet run the previous ones go in one wake-up (an
    autopilot sends its streams in bursts: one self-pipe write and one loop iteration per burst,
    not per message); one raising call is logged and does not stop the others."""

    def __init__(self) -> None:
        self.loop: asyncio.AbstractEventLoop | None = None
        self._posted: collections.deque[tuple[Callable[..., Any], tuple[Any, ...]]] = collections.deque()
        self._drain_scheduled = False

    def bind(self, loop: asyncio.AbstractEventLoop) -> None:
        """Post to ``loop`` from now on; calls left for a loop that has gone are dropped."""
        self.loop = loop
        self._posted.clear()
        self._drain_scheduled = False

    @property
    def pending(self) -> int:
        """Calls posted that the loop has not run yet."""
        return len(self._posted)

    @property
    def drain_scheduled(self) -> bool:
        """A wake-up of the loop is on its way (the next calls posted share it)."""
        return self._drain_scheduled

    def post(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn(*args)`` on the loop; nothing (and nothing kept) when it is closed or unbound."""
        loop = self.loop
        if loop is None or loop.is_closed():
            return
        self._posted.append((fn, args))
        if self._drain_scheduled:  # the loop has not started the drain yet: it will run this too
            return
        self._drain_scheduled = True
        try:
            loop.call_soon_threadsafe(self._drain)
        except RuntimeError:  # loop closing: nothing will run them
            self._posted.clear()
            self._drain_scheduled = False

    def _drain(self) -> None:
        # cleared before draining: a call posted from now on schedules a drain of its own (at
        # worst an empty one), so none is left waiting
        self._drain_scheduled = False
        posted = self._posted
        while posted:
            fn, args = posted.popleft()
            try:
                fn(*args)
            except Exception:  # as the loop would for a callback of its own: log, go on with the next
                log.exception("error in %s posted from the MAVLink reader", getattr(fn, "__qualname__", fn))


class ArduPilotLink(abc.ABC):
    """The connection, the send lock and the reader thread of :class:`ArduPilotAutopilot`; the
    decoding and the requests are in its subclasses (:mod:`.requests`, :mod:`.telemetry`)."""

    # the state every part shares, set by ArduPilotAutopilot.__init__
    connection: str
    signing: SigningSetup | None
    baud: int
    link_timeout_s: float
    source_system: int
    source_component: int
    target_system: int | None
    target_component: int
    command_timeout_s: float
    command_retries: int
    stream_rates_hz: dict[int, float]
    telemetry: TelemetryCache
    counters: LinkCounters
    rc_channels: tuple[int, ...]
    open_tlog: OpenPacketSink | None
    tlog: PacketSink | None
    _tlog_opened: bool
    _conn: Any
    _loop: asyncio.AbstractEventLoop | None
    _poster: LoopPoster  # the reader thread's calls to the loop (_post)
    _reader: threading.Thread | None
    _running: bool
    _send_lock: threading.Lock
    _acks: dict[int, asyncio.Future[int]]
    _first_hb: asyncio.Future[None] | None
    _last_hb: float
    _last_rx: float
    _latch: LinkLatch
    _last_attitude: float
    _last_stream_request: float
    _highres_accepted: bool  # the vehicle took HIGHRES_IMU: RAW_IMU (its fallback) is not asked for
    stream_check_period_s: float  # the thin-stream check's window (requests.STREAM_CHECK_PERIOD_S)
    _streams_refused: set[int]  # streams the vehicle refused (UNSUPPORTED, DENIED, FAILED)
    _stream_rerequests: dict[int, int]  # thin streams asked for again, how often
    # the thin-stream check's window: (its start, messages of the vehicle per id); None before the
    # streams were first asked for
    _stream_window: tuple[float, dict[int, int]] | None
    _t_boot: float
    copter_mode: int
    _armed: bool
    _landed: LandedState
    _battery_pct: float
    _prearm_ok: bool | None
    _gps_fix: int
    _payload_released: bool
    _have_highres: bool
    _last_text: str
    _texts_seen: int
    params: dict[str, float]
    _param_waiters: dict[str, asyncio.Future[float]]
    servo_outputs: tuple[int, ...]
    _servo_outputs_time: float
    _system_time: tuple[int, float] | None
    _system_time_waiters: list[asyncio.Future[tuple[int, float]]]
    _vehicle_signs: bool
    liveness: LoopLiveness
    foreign_heartbeats: int
    timesync: ClockOffsetEstimator | None
    timesync_period_s: float
    _timesync_lock: threading.Lock
    _next_timesync_s: float
    _timesync_logged: int
    sample_time: Literal["receipt", "autopilot"]
    _sample_offset: ClockOffset | None
    _sample_ages_s: collections.deque[float]
    sample_times_refused: int

    async def connect(self, timeout_s: float = 10.0) -> None:
        if self._conn is not None:
            return
        self._loop = asyncio.get_running_loop()  # set here too: the rest of connect uses it
        self.attach_loop(self._loop)
        device, baud, kind = parse_connection(self.connection, self.baud)
        if kind == "serial" and not os.path.exists(device):
            raise LinkDeviceMissing(f"serial device {device} does not exist (connection {self.connection!r})")
        deadline = self._loop.time() + timeout_s
        while True:
            try:
                self._conn = await self._loop.run_in_executor(None, self._open, device, baud, kind)
                break
            except AutopilotError:
                raise
            except Exception as err:  # pymavlink raises plain OSError / SerialException / socket errors
                # a TCP autopilot (SITL) may not listen yet: retry each second within the timeout
                if kind == "tcp" and isinstance(err, ConnectionError) and self._loop.time() + 1.0 < deadline:
                    log.debug("%s: %s, retrying", self.connection, err)
                    await asyncio.sleep(1.0)
                    continue
                raise AutopilotUnreachable(f"cannot open {self.connection!r}: {err}") from None
        if self.open_tlog is not None:
            try:
                self.tlog = self.open_tlog(self._tlog_opened)
            except OSError as err:
                await self.close()
                raise AutopilotError(str(err)) from None
            self._tlog_opened = True
            self._conn.mav.set_send_callback(self._log_sent)
        self._first_hb = self._loop.create_future()
        self._running = True
        self._reader = threading.Thread(target=self._read_loop, name="ardupilot-reader", daemon=True)
        self._reader.start()
        try:
            await asyncio.wait_for(self._first_hb, max(deadline - self._loop.time(), min(timeout_s, 1.0)))
        except TimeoutError:
            rejects = self.counters.signature_rejects
            await self.close()
            if rejects and self.signing is not None:
                raise SigningError(
                    f"no heartbeat from an autopilot on {self.connection!r} within {timeout_s:.1f} s: MAVLink "
                    f"signing refused {rejects} packets (unsigned, or signed with another key than "
                    f"{self.signing.key.fingerprint} from {self.signing.key.source}); give the vehicle our key "
                    "(`companion signing push`) or set signing.allow_unsigned = true"
                ) from None
            raise AutopilotUnreachable(
                f"no heartbeat from an autopilot on {self.connection!r} within {timeout_s:.1f} s"
            ) from None
        log.info("ArduPilot system %d on %s", self.target_system, self.connection)
        await self._request_streams()

    def _open(self, device: str, baud: int, kind: str = "") -> Any:
        conn = mavutil.mavlink_connection(
            device,
            baud=baud,
            source_system=self.source_system,
            source_component=self.source_component,
            dialect="ardupilotmega",
            robust_parsing=True,
            autoreconnect=True,
            # TCP: one attempt here (connect() retries within its timeout; pymavlink's own retries
            # print to stdout), pymavlink's usual retries for reconnects in flight
            **({"retries": 0} if kind == "tcp" else {}),
        )
        if kind == "tcp":
            conn.retries = 3
        conn.mav.robust_parsing = True
        if self.signing is not None:
            apply_to_mavlink(conn.mav, self.signing)
        return conn

    async def close(self) -> None:
        self._running = False
        reader, self._reader = self._reader, None
        if reader is not None and reader is not threading.current_thread():
            await asyncio.get_running_loop().run_in_executor(None, reader.join, 2.0)
        self._save_signing_timestamp()
        conn, self._conn = self._conn, None
        if conn is not None:
            with contextlib.suppress(Exception):
                conn.close()
        tlog, self.tlog = self.tlog, None
        if tlog is not None:
            await asyncio.get_running_loop().run_in_executor(None, tlog.close)
        for fut in self._acks.values():
            if not fut.done():
                fut.set_exception(AutopilotError("link closed"))
        self._acks.clear()

    @property
    def signing_timestamp(self) -> int | None:
        """Our MAVLink signing timestamp now (10 us units since 2015-01-01; None without a link)."""
        conn = self._conn
        return None if conn is None else int(conn.mav.signing.timestamp)

    @property
    def heartbeat_age_s(self) -> float | None:
        return time.monotonic() - self._last_hb if math.isfinite(self._last_hb) else None

    def link_traffic(self) -> LinkTraffic:
        _, baud, kind = parse_connection(self.connection, self.baud)
        conn = self._conn
        if conn is None:
            return LinkTraffic(baud if kind == "serial" else None)
        mav = conn.mav
        return LinkTraffic(baud if kind == "serial" else None, int(mav.total_bytes_received), int(mav.total_bytes_sent))

    @property
    def link_errors(self) -> int:
        """What this link has lost so far: pymavlink's bad-data reports (one per frame that did
        not check, one per byte skipped looking for the next frame) plus the messages missing
        from the autopilot's sequence numbers (its mav_loss)."""
        conn = self._conn
        return self.counters.bad_data + (int(conn.mav_loss) if conn is not None else 0)

    @property
    def link_ok(self) -> bool:
        if self._conn is None:
            return False
        now = time.monotonic()
        hb_age, rx_age = now - self._last_hb, now - self._last_rx
        fresh = hb_age <= self.link_timeout_s or (rx_age <= self.link_timeout_s and hb_age <= HEARTBEAT_GRACE_S)
        return self._latch.check(now, fresh, self._last_hb)

    def _send(self, fn: Callable[[Any], None]) -> bool:
        conn = self._conn
        if conn is None:
            return False
        try:
            with self._send_lock:
                fn(conn.mav)
        except (OSError, ValueError) as err:
            log.debug("send failed: %s", err)
            return False
        return True

    def attach_loop(self, loop: asyncio.AbstractEventLoop) -> None:
        """The event loop the backend's futures and the reader's calls belong to (what
        :meth:`connect` does first; calls left for a loop that has gone are dropped). Public so a
        test or a fuzzer can drive the message handlers without opening a link."""
        self._loop = loop
        self._poster.bind(loop)

    def _post(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn(*args)`` on the event loop, in the order posted (:class:`LoopPoster`)."""
        self._poster.post(fn, *args)

    def _save_signing_timestamp(self) -> None:
        """Keep our signing timestamp in ``signing.timestamp_file`` (every 30 s and on close)."""
        s, conn = self.signing, self._conn
        if s is None or s.timestamp_file is None or conn is None or not conn.mav.signing.sign_outgoing:
            return
        try:
            write_timestamp_file(s.timestamp_file, conn.mav.signing.timestamp)
        except SigningError as err:
            log.warning("%s", err)

    def _read_loop(self) -> None:
        next_hb = 0.0
        next_hb_alive = math.inf  # withheld: the next heartbeat as soon as the loop is alive again
        next_save = time.monotonic() + TIMESTAMP_SAVE_PERIOD_S
        while self._running:
            conn = self._conn
            if conn is None:
                break
            now = time.monotonic()
            if now >= next_save:
                next_save = now + TIMESTAMP_SAVE_PERIOD_S
                self._save_signing_timestamp()
            # heartbeats only while the control loop is alive (autopilot.liveness): a hung loop
            # must look dead to ArduCopter's GCS failsafe; they resume at once when it is back
            alive = self.liveness.alive
            if now >= next_hb and not alive:
                next_hb = now + 1.0
                self.counters.heartbeats_withheld += 1
                next_hb_alive = now
            elif alive and (now >= next_hb or next_hb_alive <= now):
                next_hb = now + 1.0
                next_hb_alive = math.inf
                # as the GCS's system (255) the type is GCS: ArduPilot forwards heartbeats to its
                # other ports, and a ground station there (MAVProxy) takes a non-GCS type for a
                # second vehicle, 255:191; ArduPilot's GCS failsafe reads the system id only
                self._send(
                    lambda mav: mav.heartbeat_send(
                        mavlink.MAV_TYPE_GCS,
                        mavlink.MAV_AUTOPILOT_INVALID,
                        0,
                        0,
                        mavlink.MAV_STATE_ACTIVE,
                    )
                )
                self._component_heartbeat()
            if self.timesync is not None and now >= self._next_timesync_s and self.target_system is not None:
                self._next_timesync_s = now + self.timesync_period_s
                self._send_timesync_request()
            try:
                m = conn.recv_match(blocking=True, timeout=0.1)
            except Exception as err:  # a read error (bad bytes, serial hiccup) must not kill the reader
                self.counters.read_errors += 1
                log.debug("read error: %s", err)
                time.sleep(0.01)
                continue
            if m is None:
                self._check_streams(now)
                continue
            self._count_stream(m, now)
            tlog = self.tlog
            if tlog is not None and m.get_type() != "BAD_DATA":
                tlog.write(m.get_msgbuf())
            try:
                self._on_message(m)
            except Exception:
                self.counters.decode_errors += 1
                log.exception("error decoding %s", m.get_type())

    def handle_message(self, m: Any) -> None:
        """Decode one received MAVLink message as the reader thread does, on the caller's thread
        (what reaches the loop is posted to it; errors are raised, not counted): for tests and
        tools that feed messages without a link. Not written to the .tlog, not counted as traffic."""
        self._on_message(m)

    def _send_timesync_request(self) -> None:
        """TIMESYNC(tc1 = 0, ts1 = our monotonic clock, ns): the autopilot answers with its boot
        time (docs/clock.md); on the reader thread, which also takes the answers."""
        assert self.timesync is not None
        with self._timesync_lock:
            _, ts1 = self.timesync.request(time.monotonic_ns())
        self._send(lambda mav: mav.timesync_send(0, ts1))

    def _log_sent(self, msg: Any) -> None:
        tlog = self.tlog
        if tlog is not None:
            tlog.write(msg.get_msgbuf())

    def _resolve_first_hb(self) -> None:
        if self._first_hb is not None and not self._first_hb.done():
            self._first_hb.set_result(None)

    # ------------------------------------------------------------------ hooks of the subclasses
    def _component_heartbeat(self) -> None:
        """The companion component's heartbeat, once open (:class:`~.component.ArduPilotComponent`)."""
        return None  # no component open: nothing to send

    @abc.abstractmethod
    def _on_message(self, m: Any) -> None:
        """Decode one received message (:class:`~.telemetry.ArduPilotTelemetry`)."""

    @abc.abstractmethod
    def _count_stream(self, m: Any, now: float) -> None:
        """Count a received message for the thin-stream check (:class:`~.requests.ArduPilotRequests`)."""

    @abc.abstractmethod
    def _check_streams(self, now: float) -> None:
        """Ask for the streams again when telemetry stopped (:class:`~.requests.ArduPilotRequests`)."""

    @abc.abstractmethod
    async def _request_streams(self) -> None:
        """Ask for the telemetry streams on connect (:class:`~.requests.ArduPilotRequests`)."""

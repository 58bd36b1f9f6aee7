"""ArduPilot (ArduCopter) backend over pymavlink: UDP, TCP or a serial port.

A reader thread owns the receive side of the link: it decodes MAVLink into
:mod:`companion.autopilot.types` samples stamped on the shell's monotonic clock at receipt,
hands them to the event loop (``call_soon_threadsafe``) for :attr:`telemetry`, resolves
COMMAND_ACKs, sends the companion's own 1 Hz HEARTBEAT and counts malformed bytes (they are
ignored, never fatal). Commands are COMMAND_LONGs retried until acknowledged; velocity setpoints
are a single non-blocking SET_POSITION_TARGET_LOCAL_NED send.

ArduCopter specifics: it streams nothing until asked (message intervals are requested on
connect and again if telemetry stops while heartbeats go on, e.g. after an autopilot reboot),
companion control is GUIDED (mapped to :attr:`FlightMode.OFFBOARD`), GUIDED velocity times out
after 3 s on the vehicle (it stops and holds), arming is refused until the EKF uses GPS (arm()
retries until ``arm_timeout_s``), takeoff is MAV_CMD_NAV_TAKEOFF in GUIDED, hold is BRAKE (or
LOITER), land is LAND mode, and the parcel is released with MAV_CMD_DO_GRIPPER or
MAV_CMD_DO_SET_SERVO.

With ``signing`` (a :class:`~companion.autopilot.signing.SigningSetup`, from ``[signing]``) every
packet sent is MAVLink 2 signed, and unless ``allow_unsigned`` the vehicle's unsigned or wrongly
signed packets are dropped (RADIO_STATUS / RADIO excepted, as ArduPilot does): a vehicle that does
not sign with our key is then never heard, and connect() fails naming signing.
:meth:`ArduPilotAutopilot.push_signing_key` gives the vehicle the key with SETUP_SIGNING.

With ``tlog`` (a :data:`~companion.autopilot.interface.OpenPacketSink`, e.g. a MAVLink ``.tlog``
writer with its own thread), every packet received (as it arrived, from any system on the link)
and every packet sent goes into the sink.
"""

from __future__ import annotations

import asyncio
import collections
import contextlib
import functools
import logging
import math
import os
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

os.environ["MAVLINK20"] = "1"  # before mavutil picks its dialect module
from pymavlink import mavutil

from companion.autopilot.interface import (
    LINK_DOWN,
    NO_ANSWER,
    Autopilot,
    AutopilotError,
    AutopilotUnreachable,
    CommandRejected,
    ConnectionUrlError,
    LinkDeviceMissing,
    LinkLatch,
    OpenPacketSink,
    PacketSink,
    RcInput,
    TelemetryCache,
)
from companion.autopilot.mavlink_messages import velocity_setpoint_message
from companion.autopilot.signing import (
    AP_KEY_LOAD_OFFSET,
    SigningError,
    SigningKey,
    SigningSetup,
    apply_to_mavlink,
    clock_timestamp,
    read_key_file,
    read_timestamp_file,
    setup_signing_message,
    write_timestamp_file,
)
from companion.autopilot.types import (
    Attitude,
    FlightMode,
    GlobalPosition,
    GpsRaw,
    HomePosition,
    Imu,
    LandedState,
    LandingTarget,
    PositionNed,
    StatusText,
    TelemetrySample,
    VehicleStatus,
)
from companion.guidance.setpoint import VelocitySetpoint

log = logging.getLogger(__name__)

mavutil.set_dialect("ardupilotmega")
mavlink: Any = mavutil.mavlink

G = 9.80665
MAV_CMD_REQUEST_MESSAGE = 512

COPTER_MODES: dict[str, int] = {
    "STABILIZE": 0,
    "ACRO": 1,
    "ALT_HOLD": 2,
    "AUTO": 3,
    "GUIDED": 4,
    "LOITER": 5,
    "RTL": 6,
    "CIRCLE": 7,
    "LAND": 9,
    "DRIFT": 11,
    "SPORT": 13,
    "POSHOLD": 16,
    "BRAKE": 17,
    "SMART_RTL": 21,
}

COPTER_TO_FLIGHT_MODE: dict[int, FlightMode] = {
    0: FlightMode.MANUAL,
    1: FlightMode.MANUAL,
    2: FlightMode.MANUAL,
    3: FlightMode.MISSION,
    4: FlightMode.OFFBOARD,
    5: FlightMode.POSITION,
    6: FlightMode.RTL,
    9: FlightMode.LAND,
    11: FlightMode.MANUAL,
    13: FlightMode.MANUAL,
    16: FlightMode.POSITION,
    17: FlightMode.HOLD,
    21: FlightMode.RTL,
}

LANDED_STATES = {
    1: LandedState.ON_GROUND,
    2: LandedState.IN_AIR,
    3: LandedState.TAKING_OFF,
    4: LandedState.LANDING,
}

# message id -> rate requested on connect (ArduCopter streams nothing until asked)
DEFAULT_STREAM_RATES_HZ: dict[int, float] = {
    30: 50.0,  # ATTITUDE
    105: 50.0,  # HIGHRES_IMU
    27: 50.0,  # RAW_IMU (fallback when HIGHRES_IMU is not supported)
    32: 30.0,  # LOCAL_POSITION_NED
    33: 30.0,  # GLOBAL_POSITION_INT
    24: 5.0,  # GPS_RAW_INT
    1: 5.0,  # SYS_STATUS
    245: 5.0,  # EXTENDED_SYS_STATE
    242: 0.5,  # HOME_POSITION
    147: 1.0,  # BATTERY_STATUS
    65: 5.0,  # RC_CHANNELS
}

# arming refusals that clear by themselves (pre-arm checks while the EKF converges)
ARM_RETRY_RESULTS = frozenset({"FAILED", "TEMPORARILY_REJECTED", "DENIED"})

TRY_PERIOD_TS = 100_000  # 1 s in signing timestamp units (10 us)
TIMESTAMP_SAVE_PERIOD_S = 30.0  # as ArduPilot saves its signing timestamp
HEARTBEAT_GRACE_S = 3.5  # 1 Hz heartbeats: telemetry proves liveness in between (MAVSDK uses 3 s)


def result_name(result: int) -> str:
    """The MAV_RESULT name without its prefix ("FAILED", "DENIED", ...), as CommandRejected carries it."""
    entry = mavlink.enums["MAV_RESULT"].get(result)
    return entry.name.removeprefix("MAV_RESULT_") if entry is not None else f"MAV_RESULT {result}"


def command_name(cmd: int) -> str:
    entry = mavlink.enums["MAV_CMD"].get(cmd)
    return entry.name if entry is not None else f"MAV_CMD {cmd}"


def _command_long(mav: Any, *, ts: int, tc: int, cmd: int, confirmation: int, params: Sequence[float]) -> None:
    mav.command_long_send(ts, tc, cmd, confirmation, *params)


@dataclass
class LinkCounters:
    messages: int = 0
    heartbeats: int = 0
    bad_data: int = 0
    garbage_bytes: int = 0
    read_errors: int = 0
    setpoints_sent: int = 0
    setpoints_dropped: int = 0
    commands_sent: int = 0
    stream_requests: int = 0
    signature_rejects: int = 0  # packets dropped by our signing check (unsigned or another key)
    signed_heartbeats: int = 0  # heartbeats of the vehicle whose signature our key verified
    signed_from_vehicle: int = 0  # any packet of the vehicle whose signature our key verified


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


class ArduPilotAutopilot(Autopilot):
    def __init__(
        self,
        connection: str = "udpin:0.0.0.0:14550",
        *,
        baud: int = 57600,
        link_timeout_s: float = 1.0,
        source_system: int = 255,
        source_component: int = 191,  # MAV_COMP_ID_ONBOARD_COMPUTER
        target_system: int | None = None,
        release: Literal["gripper", "servo"] = "gripper",
        release_servo: int = 9,
        release_pwm: int = 1900,
        hold_mode: Literal["BRAKE", "LOITER"] = "BRAKE",
        arm_timeout_s: float = 8.0,
        release_confirm_timeout_s: float = 2.0,
        command_timeout_s: float = 0.5,
        command_retries: int = 3,
        stream_rates_hz: dict[int, float] | None = None,
        tlog: OpenPacketSink | None = None,
        signing: SigningSetup | None = None,
    ):
        self.connection = connection
        self.signing = signing
        self.baud = baud
        self.link_timeout_s = link_timeout_s
        self.source_system = source_system
        self.source_component = source_component
        self.target_system = target_system
        self.target_component = 1
        self.release = release
        self.release_servo = release_servo
        self.release_pwm = release_pwm
        self.hold_mode = hold_mode
        self.arm_timeout_s = arm_timeout_s
        self.release_confirm_timeout_s = release_confirm_timeout_s
        self.command_timeout_s = command_timeout_s
        self.command_retries = command_retries
        self.stream_rates_hz = dict(DEFAULT_STREAM_RATES_HZ if stream_rates_hz is None else stream_rates_hz)
        self.telemetry = TelemetryCache()
        self.counters = LinkCounters()
        self.rc_channels: tuple[int, ...] = ()
        self.open_tlog = tlog
        self.tlog: PacketSink | None = None
        self._tlog_opened = False  # a reconnect appends to the same file
        self._conn: Any = None
        self._loop: asyncio.AbstractEventLoop | None = None
        # calls from the reader thread waiting for the loop (_post), and whether a drain is on its way
        self._posted: collections.deque[tuple[Callable[..., Any], tuple[Any, ...]]] = collections.deque()
        self._drain_scheduled = False
        self._reader: threading.Thread | None = None
        self._running = False
        self._send_lock = threading.Lock()
        self._acks: dict[int, asyncio.Future[int]] = {}
        self._first_hb: asyncio.Future[None] | None = None
        self._last_hb = -math.inf
        self._last_rx = -math.inf
        self._latch = LinkLatch()
        self._last_attitude = -math.inf
        self._last_stream_request = -math.inf
        self._t_boot = time.monotonic()
        # vehicle state (reader thread writes, event loop reads)
        self.copter_mode = -1
        self._armed = False
        self._landed = LandedState.UNKNOWN
        self._battery_pct = math.nan
        self._prearm_ok: bool | None = None
        self._gps_fix = 0
        self._payload_released = False
        self._have_highres = False
        self._last_text = ""
        self._texts_seen = 0
        self.params: dict[str, float] = {}  # every PARAM_VALUE seen
        self._param_waiters: dict[str, asyncio.Future[float]] = {}
        self.servo_outputs: tuple[int, ...] = ()  # SERVO_OUTPUT_RAW port 0, index 0 = output 1, us
        self._servo_outputs_time = -math.inf
        self._gripper_output: tuple[int, int] | bool | None = False  # False: not looked up yet
        # last SYSTEM_TIME: (time_unix_usec, our wall clock at arrival)
        self._system_time: tuple[int, float] | None = None
        self._system_time_waiters: list[asyncio.Future[tuple[int, float]]] = []
        self.releases_unconfirmed = 0
        self._vehicle_signs = False  # the vehicle's heartbeats carry a signature block

    @classmethod
    def from_config(cls, config: Any, **kwargs: Any) -> ArduPilotAutopilot:
        """Build from a :class:`companion.config.CompanionConfig` (``connection``, link timeout,
        ``[payload]``: gripper or servo; ArduPilot has no actuator-set command)."""
        pl = config.payload
        if pl.release == "actuator":
            raise AutopilotError(
                "payload.release = 'actuator' is PX4's DO_SET_ACTUATOR: on ArduPilot use 'gripper' "
                "(GRIP_ENABLE = 1, SERVOn_FUNCTION = 28) or 'servo' (payload.servo_channel)"
            )
        kwargs.setdefault("release", pl.release)
        kwargs.setdefault("release_servo", pl.servo_channel)
        kwargs.setdefault("release_pwm", pl.servo_pwm_us)
        sc = getattr(config, "signing", None)
        if sc is not None and sc.enabled and "signing" not in kwargs:
            key = read_key_file(sc.key_file, sc.key_format)
            ts_file = Path(sc.timestamp_file) if sc.timestamp_file else None
            if ts_file is not None:
                read_timestamp_file(ts_file)  # a bad file stops us here, before any link is opened
            kwargs["signing"] = SigningSetup(key, sc.link_id, sc.allow_unsigned, ts_file)
            log.info(
                "MAVLink signing on: key %s (%s), link id %d, %s",
                key.fingerprint,
                sc.key_file,
                sc.link_id,
                "unsigned accepted" if sc.allow_unsigned else "unsigned refused",
            )
        return cls(config.connection, link_timeout_s=config.runtime.link_timeout_s, **kwargs)

    # ------------------------------------------------------------------ link
    async def connect(self, timeout_s: float = 10.0) -> None:
        if self._conn is not None:
            return
        self._loop = asyncio.get_running_loop()
        self._posted.clear()  # left from a loop that has gone (a reconnect from another loop)
        self._drain_scheduled = False
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
    def heartbeat_age_s(self) -> float | None:
        return time.monotonic() - self._last_hb if math.isfinite(self._last_hb) else None

    @property
    def link_ok(self) -> bool:
        if self._conn is None:
            return False
        now = time.monotonic()
        hb_age, rx_age = now - self._last_hb, now - self._last_rx
        fresh = hb_age <= self.link_timeout_s or (rx_age <= self.link_timeout_s and hb_age <= HEARTBEAT_GRACE_S)
        return self._latch.check(now, fresh, self._last_hb)

    @property
    def mode(self) -> FlightMode:
        return COPTER_TO_FLIGHT_MODE.get(self.copter_mode, FlightMode.UNKNOWN)

    # ------------------------------------------------------------------ sending
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

    def set_velocity_ned(self, setpoint: VelocitySetpoint) -> None:
        if not self.link_ok or self.target_system is None:
            self.counters.setpoints_dropped += 1
            return
        ts, tc = self.target_system, self.target_component
        t_ms = int((time.monotonic() - self._t_boot) * 1000) & 0xFFFFFFFF
        msg = velocity_setpoint_message(t_ms, ts, tc, setpoint)
        ok = self._send(lambda mav: mav.send(msg))
        if ok:
            self.counters.setpoints_sent += 1
        else:
            self.counters.setpoints_dropped += 1

    def send_rc_override(self, channels: Sequence[int]) -> None:
        """RC_CHANNELS_OVERRIDE for channels 1..18 (channels 1-8: 0 = release to the radio,
        65535 = ignore; 9-18: 0 or 65535 = ignore, 65534 = release); missing channels are ignored."""
        vals = list(channels)[:18]
        ch = [*vals[:8], *[65535] * (8 - min(8, len(vals)))]
        ext = [*vals[8:], *[0] * (18 - max(8, len(vals)))]  # MAVLink 2 extensions, chan9..18
        ts, tc = self.target_system or 1, self.target_component
        self._send(lambda mav: mav.rc_channels_override_send(ts, tc, *ch, *ext))

    async def _command(self, cmd: int, *params: float, what: str = "", retries: int | None = None) -> None:
        """COMMAND_LONG, resent until its COMMAND_ACK arrives. Anything but ACCEPTED raises
        :class:`CommandRejected` with the MAV_RESULT name (with the STATUSTEXT that came with it),
        :data:`NO_ANSWER` when no ack came after the tries, :data:`LINK_DOWN` without a link."""
        name = what or command_name(cmd)
        if self._conn is None or self._loop is None:
            raise CommandRejected(name, LINK_DOWN, "not connected")
        if not self.link_ok:
            raise CommandRejected(name, LINK_DOWN, "link is down")
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        ts, tc = self.target_system or 1, self.target_component
        old = self._acks.pop(cmd, None)
        if old is not None and not old.done():
            old.cancel()
        fut: asyncio.Future[int] = self._loop.create_future()
        self._acks[cmd] = fut
        texts_before = self._texts_seen
        tries = self.command_retries if retries is None else retries
        try:
            for attempt in range(tries):
                self._send(functools.partial(_command_long, ts=ts, tc=tc, cmd=cmd, confirmation=attempt, params=p))
                self.counters.commands_sent += 1
                try:
                    result = await asyncio.wait_for(asyncio.shield(fut), self.command_timeout_s)
                except TimeoutError:
                    continue
                if result == mavlink.MAV_RESULT_IN_PROGRESS:  # keep waiting for the final ack
                    fut = self._loop.create_future()
                    self._acks[cmd] = fut
                    try:
                        result = await asyncio.wait_for(fut, 30.0)
                    except TimeoutError:
                        raise CommandRejected(name, NO_ANSWER, "IN_PROGRESS without a final ack") from None
                if result == mavlink.MAV_RESULT_ACCEPTED:
                    return
                # ArduPilot sends the reason (e.g. "Arm: Need Position Estimate") just before the ack
                reason = self._last_text if self._texts_seen != texts_before else ""
                raise CommandRejected(name, result_name(result), reason)
            raise CommandRejected(name, NO_ANSWER, f"no COMMAND_ACK after {tries} tries{self._signing_hint()}")
        finally:
            if self._acks.get(cmd) is fut:
                del self._acks[cmd]

    def _signing_hint(self) -> str:
        """Why a vehicle may ignore our commands although we hear it: signing."""
        conn = self._conn
        if self.signing is None and self._vehicle_signs:
            return (
                "; the vehicle signs its packets (MAVLink 2 signing) and ignores our unsigned ones: "
                "set signing.enabled with its key"
            )
        if self.signing is not None and conn is not None and conn.mav.signing.badsig_count > 0:
            return (
                f"; the vehicle's signatures fail our key {self.signing.key.fingerprint} "
                f"({conn.mav.signing.badsig_count} packets): it signs with another key and ignores ours"
            )
        return ""

    async def push_signing_key(
        self, key: SigningKey | None, *, initial_timestamp: int | None = None, timeout_s: float = 3.0, tries: int = 3
    ) -> None:
        """Give the vehicle a signing key with SETUP_SIGNING (``key`` None: the all-zero key that
        turns signing off), then sign with it ourselves and wait for a heartbeat its signature
        verifies. ArduPilot does not acknowledge SETUP_SIGNING, refuses it while armed, and once it
        signs drops an unsigned SETUP_SIGNING except on channel 0 (SERIAL0: USB, SITL TCP 5760).
        Raises :class:`SigningError` when the vehicle does not take the key."""
        conn, loop = self._conn, self._loop
        if conn is None or loop is None or self.target_system is None:
            raise SigningError("push_signing_key: not connected to a vehicle")
        if self._armed:
            raise SigningError("push_signing_key: the vehicle is armed (ArduPilot refuses SETUP_SIGNING when armed)")
        ts = clock_timestamp() if initial_timestamp is None else initial_timestamp
        msg = setup_signing_message(conn.mav, self.target_system, self.target_component, key, ts)
        if key is None:
            for _ in range(tries):
                self._send(lambda mav: mav.send(msg))
                await asyncio.sleep(0.1)
            with self._send_lock:
                conn.disable_signing()
            self.signing = None
            log.info("sent SETUP_SIGNING with the zero key: signing off on the vehicle and here")
            return
        old = self.signing
        setup = SigningSetup(
            key,
            old.link_id if old else 1,
            allow_unsigned=old.allow_unsigned if old else False,
            timestamp_file=old.timestamp_file if old else None,
        )
        # one SETUP_SIGNING per try, each with a later timestamp: ArduPilot sets its timestamp to
        # the pushed one + 60 s, so the same message again would turn its clock back and we would
        # drop its packets as replays
        deadline = loop.time() + timeout_s
        for attempt in range(tries):
            if attempt:
                ts = max(ts + TRY_PERIOD_TS, clock_timestamp())
                msg = setup_signing_message(conn.mav, self.target_system, self.target_component, key, ts)
            with self._send_lock:
                conn.mav.send(msg)  # with the link's current signing (none at first)
                # the vehicle starts 60 s past the pushed timestamp; start there too
                apply_to_mavlink(conn.mav, setup, max(clock_timestamp(), ts + AP_KEY_LOAD_OFFSET))
            if attempt == 0:
                self.signing = setup
            seen = self.counters.signed_from_vehicle
            try_end = min(deadline, loop.time() + timeout_s / tries)
            while loop.time() < try_end:
                if self.counters.signed_from_vehicle > seen:
                    log.info("vehicle %d signs with key %s", self.target_system, key.fingerprint)
                    return
                await asyncio.sleep(0.05)
        raise SigningError(
            f"the vehicle did not start signing with key {key.fingerprint} within {timeout_s:.1f} s after "
            f"SETUP_SIGNING ({tries} sent): ArduPilot ignores it while armed, and once signing drops an "
            "unsigned one off channel 0 (SERIAL0/USB; SITL TCP 5760)"
        )

    async def _request_streams(self) -> None:
        async def one(mid: int, hz: float) -> None:
            try:
                await self._command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, mid, 1e6 / hz, retries=2)
            except AutopilotError as err:
                log.info("message %d at %.1f Hz not available: %s", mid, hz, err)

        self._last_stream_request = time.monotonic()
        self.counters.stream_requests += 1
        # one at a time: the ack futures are keyed by command
        for mid, hz in self.stream_rates_hz.items():
            await one(mid, hz)
        with contextlib.suppress(AutopilotError):
            await self._command(mavlink.MAV_CMD_REQUEST_MESSAGE, 242, retries=1)

    def _rerequest_streams_fire_and_forget(self) -> None:
        ts, tc = self.target_system or 1, self.target_component
        for mid, hz in self.stream_rates_hz.items():
            self._send(
                functools.partial(
                    _command_long,
                    ts=ts,
                    tc=tc,
                    cmd=mavlink.MAV_CMD_SET_MESSAGE_INTERVAL,
                    confirmation=0,
                    params=(mid, 1e6 / hz, 0, 0, 0, 0, 0),
                )
            )
        self.counters.stream_requests += 1

    # ------------------------------------------------------------------ commands
    async def set_mode(self, name: str) -> None:
        num = COPTER_MODES[name]
        await self._command(mavlink.MAV_CMD_DO_SET_MODE, mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED, num, what=name)
        self.copter_mode = num  # ACCEPTED means switched; the next heartbeat confirms
        self._push_status()

    async def arm(self) -> None:
        """GUIDED, then arm. Until EKF3 uses GPS (~41 s after boot in SITL) ArduCopter answers
        FAILED to both: GUIDED with "Mode change to GUIDED failed: requires position" (the first
        ~20 s), arming with "Arm: Need Position Estimate". Both are retried every second until
        ``arm_timeout_s``, then the last refusal is raised. Arming in LAND (the mode a LAND
        leaves it in) is refused for good ("Arm: LAND mode not armable"): GUIDED comes first."""
        deadline = time.monotonic() + self.arm_timeout_s
        while True:
            try:
                if self.copter_mode != COPTER_MODES["GUIDED"]:
                    await self.set_mode("GUIDED")
                await self._command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 1, what="arm")
                break
            except CommandRejected as err:
                if err.result not in ARM_RETRY_RESULTS or time.monotonic() + 1.0 > deadline:
                    raise
                log.info("GUIDED/arming refused (EKF/GPS not ready?), retrying: %s", err)
                await asyncio.sleep(1.0)
        self._armed = True
        self._push_status()

    async def disarm(self) -> None:
        await self._command(mavlink.MAV_CMD_COMPONENT_ARM_DISARM, 0, what="disarm")
        self._armed = False
        self._push_status()

    async def takeoff(self, alt_rel_m: float) -> None:
        if self.copter_mode != COPTER_MODES["GUIDED"]:
            await self.set_mode("GUIDED")
        await self._command(mavlink.MAV_CMD_NAV_TAKEOFF, 0, 0, 0, 0, 0, 0, alt_rel_m, what="takeoff")

    async def start_offboard(self) -> None:
        await self.set_mode("GUIDED")

    async def hold(self) -> None:
        await self.set_mode(self.hold_mode)

    async def land(self) -> None:
        await self.set_mode("LAND")

    async def precision_land(self) -> None:
        """LAND: with PLND_ENABLED = 1 and PLND_TYPE = 1 (companion computer) ArduPilot's LAND
        steers onto the LANDING_TARGET it receives (landing.landing_target_output = "body_angles")."""
        await self.set_mode("LAND")

    def send_landing_target(self, target: LandingTarget) -> None:
        """LANDING_TARGET (MAVLink 2 fields included). AC_PrecLand_Companion reads angle_x /
        angle_y / distance (MAV_FRAME_BODY_FRD); the position form is sent as MAV_FRAME_LOCAL_NED."""
        t = target
        frame = mavlink.MAV_FRAME_LOCAL_NED if t.position_valid else mavlink.MAV_FRAME_BODY_FRD
        usec = max(0, int(t.time_s * 1e6))
        self._send(
            lambda mav: mav.landing_target_send(
                usec,
                0,
                frame,
                t.angle_x_rad,
                t.angle_y_rad,
                t.distance_m,
                t.size_x_rad,
                t.size_y_rad,
                t.north_m,
                t.east_m,
                t.down_m,
                [1.0, 0.0, 0.0, 0.0],
                mavlink.LANDING_TARGET_TYPE_VISION_FIDUCIAL,
                int(t.position_valid),
            )
        )

    async def release_payload(self) -> None:
        """DO_GRIPPER release (or DO_SET_SERVO), then confirmed on the output itself.

        ArduCopter ACCEPTs DO_GRIPPER once GRIP_ENABLE = 1 and moves the servo at once (4.7 SITL,
        GRIP_TYPE = 1: SERVOn_FUNCTION = 28 output to GRIP_RELEASE within 0.1 s, STATUSTEXT
        "Gripper load releasing" then "Gripper load released" 0.5 s later); with GRIP_ENABLE = 0
        it answers FAILED, for good. The release counts as done only when SERVO_OUTPUT_RAW shows
        the gripper's output (found from the GRIP_* and SERVOn_FUNCTION parameters) or the
        release servo at the release PWM; CommandRejected FAILED after
        ``release_confirm_timeout_s`` otherwise. An autopilot that sends no SERVO_OUTPUT_RAW or
        no parameters cannot confirm: its ACK is taken (counted in ``releases_unconfirmed``).
        """
        outputs_streamed = True  # the confirmation reads SERVO_OUTPUT_RAW at 10 Hz
        try:
            await self._command(mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 36, 1e5, retries=2)
        except CommandRejected as err:
            outputs_streamed = self._servo_outputs_time > -math.inf
            log.info("SERVO_OUTPUT_RAW not available: %s", err)
        if self.release == "gripper":
            what = "release (gripper)"
            target = await self._find_gripper_output() if outputs_streamed else None
            t_cmd = time.monotonic()
            await self._command(mavlink.MAV_CMD_DO_GRIPPER, 1, mavlink.GRIPPER_ACTION_RELEASE, what=what)
        else:
            what = "release (servo)"
            target = (self.release_servo, self.release_pwm) if outputs_streamed else None
            t_cmd = time.monotonic()
            await self._command(mavlink.MAV_CMD_DO_SET_SERVO, self.release_servo, self.release_pwm, what=what)
        if target is None:
            self.releases_unconfirmed += 1
            log.warning("%s accepted; its output cannot be watched, release not confirmed", what)
        else:
            await self._confirm_output(what, *target, t_cmd)
        self._payload_released = True
        self._push_status()

    async def _confirm_output(self, what: str, channel: int, pwm: int, since: float) -> None:
        end = time.monotonic() + self.release_confirm_timeout_s
        while time.monotonic() < end:
            out = self.servo_outputs
            if self._servo_outputs_time > since and len(out) >= channel and abs(out[channel - 1] - pwm) <= 20:
                log.info("%s confirmed: output %d at %d us", what, channel, out[channel - 1])
                return
            await asyncio.sleep(0.02)
        if self._servo_outputs_time == -math.inf:
            self.releases_unconfirmed += 1
            log.warning("%s accepted; no SERVO_OUTPUT_RAW from the autopilot, release not confirmed", what)
            return
        seen = self.servo_outputs[channel - 1] if len(self.servo_outputs) >= channel else None
        raise CommandRejected(
            what, "FAILED", f"output {channel} at {seen} us, not {pwm} us, {self.release_confirm_timeout_s:.1f} s after"
        )

    async def _find_gripper_output(self) -> tuple[int, int] | None:
        """(output, release PWM) of a servo gripper (GRIP_TYPE = 1, SERVOn_FUNCTION = 28,
        GRIP_RELEASE), looked up once; None when the parameters do not say (or do not answer)."""
        if self._gripper_output is not False:
            return self._gripper_output  # type: ignore[return-value]
        found: tuple[int, int] | None = None
        grip_type = await self.read_param("GRIP_TYPE")
        release = await self.read_param("GRIP_RELEASE") if grip_type == 1 else None
        if release is not None:
            order = [self.release_servo, *(n for n in range(1, 17) if n != self.release_servo)]
            for n in order:
                fn = await self.read_param(f"SERVO{n}_FUNCTION")
                if fn is None:
                    break
                if int(fn) == 28:  # SRV_Channel::k_gripper
                    found = (n, round(release))
                    break
        log.info("gripper output: %s", found)
        self._gripper_output = found
        return found

    async def read_param(self, name: str, timeout_s: float = 0.4, tries: int = 2) -> float | None:
        """One parameter by name (PARAM_REQUEST_READ), None without an answer."""
        if self._loop is None:
            return None
        ts, tc = self.target_system or 1, self.target_component
        for _ in range(tries):
            fut = self._param_waiters.get(name)
            if fut is None or fut.done():
                fut = self._loop.create_future()
                self._param_waiters[name] = fut
            self._send(lambda mav: mav.param_request_read_send(ts, tc, name.encode(), -1))
            try:
                return await asyncio.wait_for(asyncio.shield(fut), timeout_s)
            except TimeoutError:
                continue
            finally:
                if self._param_waiters.get(name) is fut and fut.done():
                    del self._param_waiters[name]
        self._param_waiters.pop(name, None)
        return None

    async def system_time(self, timeout_s: float = 2.0) -> tuple[int, float] | None:
        """A fresh SYSTEM_TIME as ``(time_unix_usec, our wall clock at its arrival)``, requested with
        MAV_CMD_REQUEST_MESSAGE (ArduPilot also streams it); None without one within ``timeout_s``."""
        if self._loop is None or self._conn is None:
            return None
        fut: asyncio.Future[tuple[int, float]] = self._loop.create_future()
        self._system_time_waiters.append(fut)
        ts, tc = self.target_system or 1, self.target_component
        request = functools.partial(
            _command_long, ts=ts, tc=tc, cmd=MAV_CMD_REQUEST_MESSAGE, confirmation=0, params=(2, 0, 0, 0, 0, 0, 0)
        )
        self._send(request)  # its COMMAND_ACK is not waited for: the message itself answers
        try:
            return await asyncio.wait_for(fut, timeout_s)
        except TimeoutError:
            return None
        finally:
            if fut in self._system_time_waiters:
                self._system_time_waiters.remove(fut)

    def _resolve_system_time(self, value: tuple[int, float]) -> None:
        waiters, self._system_time_waiters = self._system_time_waiters, []
        for fut in waiters:
            if not fut.done():
                fut.set_result(value)

    def _resolve_param(self, name: str, value: float) -> None:
        fut = self._param_waiters.get(name)
        if fut is not None and not fut.done():
            fut.set_result(value)

    # ------------------------------------------------------------------ receiving (reader thread)
    def _post(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn(*args)`` on the event loop, in the order posted. Calls posted while the loop has
        not yet run the previous ones go in one wake-up (an autopilot sends its streams in bursts:
        one self-pipe write and one loop iteration per burst, not per message)."""
        loop = self._loop
        if loop is None or loop.is_closed():
            return
        self._posted.append((fn, args))
        if self._drain_scheduled:  # the loop has not started the drain yet: it will run this too
            return
        self._drain_scheduled = True
        try:
            loop.call_soon_threadsafe(self._drain_posted)
        except RuntimeError:  # loop closing: nothing will run them
            self._posted.clear()
            self._drain_scheduled = False

    def _drain_posted(self) -> None:
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

    def _push(self, sample: TelemetrySample) -> None:
        self._post(self.telemetry.push, sample)

    def _status(self) -> VehicleStatus:
        healthy = self._prearm_ok if self._prearm_ok is not None else self._gps_fix >= 3
        return VehicleStatus(
            time.monotonic(),
            self._armed,
            self.mode,
            self._landed,
            bool(healthy),
            self._battery_pct if math.isfinite(self._battery_pct) else 100.0,
            self._payload_released,
        )

    def _push_status(self) -> None:
        self._push(self._status())

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
        next_save = time.monotonic() + TIMESTAMP_SAVE_PERIOD_S
        while self._running:
            conn = self._conn
            if conn is None:
                break
            now = time.monotonic()
            if now >= next_save:
                next_save = now + TIMESTAMP_SAVE_PERIOD_S
                self._save_signing_timestamp()
            if now >= next_hb:
                next_hb = now + 1.0
                self._send(
                    lambda mav: mav.heartbeat_send(
                        mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                        mavlink.MAV_AUTOPILOT_INVALID,
                        0,
                        0,
                        mavlink.MAV_STATE_ACTIVE,
                    )
                )
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
            tlog = self.tlog
            if tlog is not None and m.get_type() != "BAD_DATA":
                tlog.write(m.get_msgbuf())
            try:
                self._on_message(m)
            except Exception:
                log.exception("error decoding %s", m.get_type())

    def _log_sent(self, msg: Any) -> None:
        tlog = self.tlog
        if tlog is not None:
            tlog.write(msg.get_msgbuf())

    def _check_streams(self, now: float) -> None:
        if (
            self.link_ok
            and now - self._last_hb < 2.0
            and now - self._last_attitude > 3.0
            and now - self._last_stream_request > 5.0
            and self._last_stream_request > -math.inf
            and self.target_system is not None
        ):
            log.warning("heartbeats but no telemetry: requesting the streams again")
            self._last_stream_request = now
            self._rerequest_streams_fire_and_forget()

    def _on_message(self, m: Any) -> None:
        t = m.get_type()
        if t == "BAD_DATA":
            if getattr(m, "reason", "") == "Invalid signature":
                self.counters.signature_rejects += 1
                if self.counters.signature_rejects in (1, 100) or self.counters.signature_rejects % 1000 == 0:
                    log.warning(
                        "MAVLink signing: %d packets dropped (unsigned, or signed with another key)",
                        self.counters.signature_rejects,
                    )
                return
            self.counters.bad_data += 1
            self.counters.garbage_bytes += len(getattr(m, "data", b""))
            return
        src = m.get_srcSystem()
        now = time.monotonic()
        if t == "HEARTBEAT":
            if m.autopilot == mavlink.MAV_AUTOPILOT_INVALID or m.type == mavlink.MAV_TYPE_GCS:
                return  # a GCS or another companion
            if self.target_system is None:
                self.target_system = src
            if src != self.target_system or m.get_srcComponent() != self.target_component:
                return
            self.counters.heartbeats += 1
            buf = m.get_msgbuf()
            self._vehicle_signs = len(buf) > 2 and buf[0] == 0xFD and bool(buf[2] & 0x01)  # MAVLINK_IFLAG_SIGNED
            if m.get_signed():
                self.counters.signed_heartbeats += 1
                self.counters.signed_from_vehicle += 1
            self._last_hb = now
            self._last_rx = now
            self.copter_mode = m.custom_mode
            self._armed = bool(m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            if self._first_hb is not None and not self._first_hb.done():
                self._post(self._resolve_first_hb)
            self._push_status()
            if now - self._last_attitude > 3.0:
                self._check_streams(now)
            return
        if self.target_system is None or src != self.target_system:
            return
        self.counters.messages += 1
        self.counters.signed_from_vehicle += m.get_signed()
        self._last_rx = now
        if t == "ATTITUDE":
            self._last_attitude = now
            self._push(Attitude(now, m.roll, m.pitch, m.yaw, m.rollspeed, m.pitchspeed, m.yawspeed))
        elif t == "HIGHRES_IMU":
            self._have_highres = True
            self._push(Imu(now, m.xacc, m.yacc, m.zacc, m.xgyro, m.ygyro, m.zgyro))
        elif t == "RAW_IMU" and not self._have_highres:
            a = G / 1000.0
            self._push(Imu(now, m.xacc * a, m.yacc * a, m.zacc * a, m.xgyro / 1e3, m.ygyro / 1e3, m.zgyro / 1e3))
        elif t == "LOCAL_POSITION_NED":
            self._push(PositionNed(now, m.x, m.y, m.z, m.vx, m.vy, m.vz))
        elif t == "GLOBAL_POSITION_INT":
            self._push(GlobalPosition(now, m.lat / 1e7, m.lon / 1e7, m.alt / 1000.0, m.relative_alt / 1000.0))
        elif t == "GPS_RAW_INT":
            self._gps_fix = m.fix_type
            eph = m.eph / 100.0 if m.eph != 65535 else 99.99
            self._push(GpsRaw(now, m.lat / 1e7, m.lon / 1e7, m.alt / 1000.0, m.fix_type, m.satellites_visible, eph))
        elif t == "SYS_STATUS":
            prearm = mavlink.MAV_SYS_STATUS_PREARM_CHECK
            if m.onboard_control_sensors_present & prearm:
                self._prearm_ok = bool(m.onboard_control_sensors_health & prearm)
            if m.battery_remaining >= 0:
                self._battery_pct = float(m.battery_remaining)
            self._push_status()
        elif t == "BATTERY_STATUS":
            if m.battery_remaining >= 0:
                self._battery_pct = float(m.battery_remaining)
        elif t == "EXTENDED_SYS_STATE":
            self._landed = LANDED_STATES.get(m.landed_state, LandedState.UNKNOWN)
            self._push_status()
        elif t == "HOME_POSITION":
            self._push(HomePosition(now, m.latitude / 1e7, m.longitude / 1e7, m.altitude / 1000.0, m.x, m.y, m.z))
        elif t == "STATUSTEXT":
            text = m.text if isinstance(m.text, str) else bytes(m.text).decode(errors="replace")
            text = text.rstrip("\x00")
            self._last_text = text
            self._texts_seen += 1
            log.info("autopilot: %s", text)
            self._push(StatusText(now, m.severity, text))
        elif t == "COMMAND_ACK":
            if m.target_system in (0, self.source_system):
                self._post(self._resolve_ack, m.command, m.result)
        elif t == "SERVO_OUTPUT_RAW":
            if m.port == 0:
                outs = [getattr(m, f"servo{i}_raw", 0) for i in range(1, 17)]
                self.servo_outputs = tuple(outs)
                self._servo_outputs_time = now
        elif t == "PARAM_VALUE":
            pid = m.param_id if isinstance(m.param_id, str) else bytes(m.param_id).decode(errors="replace")
            pid = pid.rstrip("\x00")
            if math.isfinite(m.param_value):
                self.params[pid] = float(m.param_value)
                self._post(self._resolve_param, pid, float(m.param_value))
        elif t == "SYSTEM_TIME":
            self._system_time = (int(m.time_unix_usec), time.time())
            self._post(self._resolve_system_time, self._system_time)
        elif t == "RC_CHANNELS":
            self.rc_channels = tuple(getattr(m, f"chan{i}_raw") for i in range(1, m.chancount + 1))
            self._post(self.telemetry.push_rc, RcInput(now, self.rc_channels))

    def _resolve_first_hb(self) -> None:
        if self._first_hb is not None and not self._first_hb.done():
            self._first_hb.set_result(None)

    def _resolve_ack(self, cmd: int, result: int) -> None:
        fut = self._acks.get(cmd)
        if fut is not None and not fut.done():
            fut.set_result(result)

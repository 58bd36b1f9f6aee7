"""The embedded :class:`SimVehicle` served over real MAVLink 2 on UDP, in real time: the core
shared by both dialects (socket, parsing, streams, message builders, commands, parameters, RC
input). The dialects are subclasses in :mod:`companion_sitl.mavlink_px4` and
:mod:`companion_sitl.mavlink_ardupilot`; ``MavlinkSimVehicle(cfg, "px4" | "ardupilot", ...)``
builds the one named.

A background thread steps the vehicle on ``time.monotonic`` and speaks one of two dialects:

- ``"px4"``: HEARTBEAT as MAV_AUTOPILOT_PX4 with PX4 custom modes (main mode << 16 | sub mode
  << 24), PX4-like default streams (ATTITUDE, ATTITUDE_QUATERNION, HIGHRES_IMU,
  GLOBAL/LOCAL_POSITION, GPS_RAW_INT, SYS_STATUS, EXTENDED_SYS_STATE, BATTERY_STATUS,
  HOME_POSITION), COMMAND_LONG/COMMAND_INT with COMMAND_ACK, OFFBOARD velocity setpoints with
  PX4's rules (SimVehicle: > 2 Hz before the switch, COM_OF_LOSS_T failsafe), a minimal
  parameter server and an empty mission.
- ``"ardupilot"``: HEARTBEAT as MAV_AUTOPILOT_ARDUPILOTMEGA with Copter mode numbers, nothing
  streamed but the heartbeat until asked (REQUEST_DATA_STREAM or SET_MESSAGE_INTERVAL), GUIDED
  velocity with a 3 s timeout, arming refused until the EKF/GPS delay has passed,
  RC_CHANNELS_OVERRIDE reflected in RC_CHANNELS (channel 5 is the flight-mode switch).
  The pilot's transmitter is :meth:`MavlinkSimVehicle.pilot_set_rc`; an override replaces its
  channel until released (0 on channels 1-8, UINT16_MAX-1 on 9-18) or until it lapses after
  ``rc_override_timeout_s`` (ArduPilot's RC_OVERRIDE_TIME). A vehicle with ``set_rc_input``
  (companion_sitl.dart_link.StickSimVehicle) is handed the copter mode and channels 1-4 (RCMAP
  roll, pitch, throttle, yaw) every tick, so STABILIZE / ALT_HOLD fly on the sticks.

The vehicle sends to a configured remote address (as PX4 SITL sends to 14540) and to every
peer it has heard from. Malformed bytes on the socket are counted and ignored. Ground truth goes
out as HIL_STATE_QUATERNION when requested.

MAVLink 2 signing (ArduPilot dialect), as ArduPilot's GCS_Signing.cpp: SETUP_SIGNING stores the
key (refused while armed, with "ERROR: Won't setup signing when armed"), the vehicle's timestamp
starts 60 s past the pushed one (raised to the clock, as ArduPilot does on a GPS fix), and from then
on every packet it sends is signed and unsigned or wrongly signed packets are dropped, except
RADIO_STATUS and RADIO, or everything on a ``trusted_link`` (ArduPilot's channel 0: USB, SITL TCP
5760). The all-zero key with timestamp 0 turns signing off. ``signing_key`` starts with a key.
"""

from __future__ import annotations

import abc
import logging
import math
import os
import select
import socket
import struct
import threading
import time
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, ClassVar, Literal

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.autopilot.signing import (
    AP_KEY_LOAD_OFFSET,
    KEY_LEN,
    accept_everything,
    accept_unsigned_ardupilot,
    clock_timestamp,
)
from companion.autopilot.types import FlightMode, LandedState
from companion.config import SimConfig
from companion.geometry.earth import GeoPoint, LocalTangentPlane
from companion.geometry.rotations import quat_to_euler
from companion.guidance.setpoint import VelocitySetpoint
from companion_sitl.vehicle import G, SimCommandError, SimVehicle

log = logging.getLogger(__name__)

Dialect = Literal["px4", "ardupilot"]

# type_mask bits of SET_POSITION_TARGET_LOCAL_NED
MASK_POS = 0b111
MASK_VEL = 0b111000
MASK_ACC = 0b111000000
MASK_YAW = 1 << 10
MASK_YAW_RATE = 1 << 11

_IMU = mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
SENSORS_BASE = _IMU | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
SENSORS_BASE |= mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE | mavlink.MAV_SYS_STATUS_AHRS
SENSORS_GPS = mavlink.MAV_SYS_STATUS_SENSOR_GPS
SENSORS_PREARM = mavlink.MAV_SYS_STATUS_PREARM_CHECK

PX4_DEFAULT_STREAMS_HZ: dict[int, float] = {
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 50.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 50.0,
    mavlink.MAVLINK_MSG_ID_HIGHRES_IMU: 50.0,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 40.0,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 30.0,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 8.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 5.0,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 5.0,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
}

# ArduPilot REQUEST_DATA_STREAM groups (GCS_MAVLink stream ids)
AP_STREAM_GROUPS: dict[int, tuple[int, ...]] = {
    mavlink.MAV_DATA_STREAM_RAW_SENSORS: (mavlink.MAVLINK_MSG_ID_RAW_IMU, mavlink.MAVLINK_MSG_ID_HIGHRES_IMU),
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: (
        mavlink.MAVLINK_MSG_ID_SYS_STATUS,
        mavlink.MAVLINK_MSG_ID_GPS_RAW_INT,
        mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
    ),
    mavlink.MAV_DATA_STREAM_RC_CHANNELS: (mavlink.MAVLINK_MSG_ID_RC_CHANNELS,),
    mavlink.MAV_DATA_STREAM_POSITION: (
        mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
        mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    ),
    mavlink.MAV_DATA_STREAM_EXTRA1: (mavlink.MAVLINK_MSG_ID_ATTITUDE,),
    mavlink.MAV_DATA_STREAM_EXTRA3: (mavlink.MAVLINK_MSG_ID_BATTERY_STATUS,),
}


def _i(x: float) -> int:
    """A command parameter as an int (MAVSDK sends NaN for unused parameters)."""
    return int(x) if math.isfinite(x) else 0


def euler_to_quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


@dataclass
class LinkStats:
    """What the vehicle's MAVLink endpoint saw (read from any thread; counters only grow)."""

    datagrams_in: int = 0
    messages_in: int = 0
    bad_data: int = 0  # malformed packets (bad prefix, CRC, length)
    garbage_bytes: int = 0
    messages_out: int = 0
    send_errors: int = 0
    setpoints: int = 0
    setpoints_rejected: int = 0
    landing_targets: int = 0
    signature_rejects: int = 0  # dropped by the signing check (unsigned, or another key)
    signed_in: int = 0  # accepted with a verified signature
    commands: Counter[int] = field(default_factory=Counter)
    unsupported_commands: Counter[int] = field(default_factory=Counter)
    by_type_in: Counter[str] = field(default_factory=Counter)


class _Writer:
    """File-like sink for pymavlink's encoder: collects the bytes of one message."""

    def __init__(self) -> None:
        self.data = b""

    def write(self, b: bytes) -> None:
        self.data += b


class MavlinkSimVehicle(abc.ABC):
    """A :class:`SimVehicle` behind a real MAVLink 2 UDP endpoint, stepped in real time.

    ``bind`` is the vehicle's own address (port 0 picks a free one; see :attr:`address`).
    ``remote`` is where it sends before anyone has spoken to it (a companion listening with
    ``udpin``). Use as a context manager or call :meth:`start` / :meth:`stop`.

    ``MavlinkSimVehicle(cfg, dialect)`` returns the dialect's subclass
    (:class:`~companion_sitl.mavlink_px4.Px4SimVehicle`,
    :class:`~companion_sitl.mavlink_ardupilot.ArduPilotSimVehicle`), which fills in the hooks below.
    """

    dialect: Dialect
    DEFAULT_STREAMS_HZ: ClassVar[dict[int, float]] = {}  # streamed from boot unless stream_rates_hz
    OFFBOARD_LOSS_MODE: ClassVar[FlightMode] = FlightMode.HOLD  # where the offboard-loss failsafe goes
    HOME_ALWAYS: ClassVar[bool] = False  # send HOME_POSITION on change even when not streamed
    LOCAL_Z_OFFSET_M: ClassVar[float] = 0.0  # added to LOCAL_POSITION_NED z
    SOFTWARE_VERSION: ClassVar[int] = 0  # AUTOPILOT_VERSION flight_sw_version
    SIGNING: ClassVar[bool] = False  # handles SETUP_SIGNING and signs (the ArduPilot dialect)
    # parameters the firmware types as integers (the rest are REAL32), and how it sends them:
    # byte-wise in the float field (PX4) or cast to a float (ArduPilot)
    INT_PARAMS: ClassVar[frozenset[str]] = frozenset()
    PARAM_BYTEWISE: ClassVar[bool] = False
    #: RC_OVERRIDE_TIME when none is given (< 0: overrides never lapse)
    RC_OVERRIDE_TIMEOUT_S: ClassVar[float] = -1.0

    def __new__(cls, cfg: SimConfig, dialect: Dialect = "px4", **kwargs: Any) -> MavlinkSimVehicle:
        if cls is MavlinkSimVehicle:
            from companion_sitl.mavlink_ardupilot import ArduPilotSimVehicle
            from companion_sitl.mavlink_px4 import Px4SimVehicle

            by_dialect: dict[str, type[MavlinkSimVehicle]] = {"px4": Px4SimVehicle, "ardupilot": ArduPilotSimVehicle}
            if dialect not in by_dialect:
                raise ValueError(f"dialect {dialect!r}: must be 'px4' or 'ardupilot'")
            cls = by_dialect[dialect]
        return super().__new__(cls)

    def __init__(
        self,
        cfg: SimConfig,
        dialect: Dialect | None = None,
        *,
        bind: tuple[str, int] = ("127.0.0.1", 0),
        remote: tuple[str, int] | None = None,
        vehicle: SimVehicle | None = None,
        system_id: int = 1,
        heartbeat_hz: float = 1.0,
        stream_rates_hz: dict[int, float] | None = None,
        ekf_delay_s: float | None = None,
        guided_timeout_s: float = 3.0,
        release_servo: int = 9,
        release_pwm: int = 1900,
        rc_override_timeout_s: float | None = None,
        params: dict[str, float] | None = None,
        signing_key: bytes | None = None,
        signing_timestamp: int | None = None,
        trusted_link: bool = False,
        clock_offset_s: float = 0.0,
    ):
        if dialect is not None and dialect != self.dialect:
            raise ValueError(f"dialect {dialect!r}: this is the {self.dialect!r} sim vehicle")
        if vehicle is None:
            cfg = self._vehicle_config(cfg, guided_timeout_s, ekf_delay_s)
            vehicle = SimVehicle(cfg)
        self.cfg = cfg
        self.vehicle = vehicle
        vehicle.offboard_loss_mode = self.OFFBOARD_LOSS_MODE
        self.system_id = system_id
        self.component_id = mavlink.MAV_COMP_ID_AUTOPILOT1
        self.stats = LinkStats()
        self.remote = remote
        self.peers: list[tuple[str, int]] = []
        self.release_servo = release_servo
        self.release_pwm = release_pwm
        self.lock = threading.RLock()  # held while the vehicle is stepped or commanded
        self._bind = bind
        self._sock: socket.socket | None = None
        self._thread: threading.Thread | None = None
        self._running = False
        self._link_up = True
        self._t0 = 0.0
        self._enc = mavlink.MAVLink(_Writer(), srcSystem=system_id, srcComponent=self.component_id)
        self._rx = mavlink.MAVLink(None, srcSystem=system_id, srcComponent=self.component_id)
        self._rx.robust_parsing = True
        self._enc.signing = self._rx.signing  # one signing state: the timestamp grows both ways
        self.trusted_link = trusted_link
        if signing_key is not None:
            if not self.SIGNING:
                raise ValueError(f"signing_key: the {self.dialect!r} sim vehicle does not sign (ardupilot does)")
            self._set_signing(signing_key, clock_timestamp() if signing_timestamp is None else signing_timestamp)
        self._hb_period = 1.0 / heartbeat_hz
        self._hb_next = 0.0
        # message id -> [interval_s, next_due]
        self._streams: dict[int, list[float]] = {}
        for mid, hz in (stream_rates_hz or self.DEFAULT_STREAMS_HZ).items():
            self._streams[mid] = [1.0 / hz, 0.0]
        self._texts_sent = 0
        self._home_sent: tuple[float, float, float] | None = None
        self._rc = [1500, 1500, 1000, 1500, 1100, 1100, 1100, 1100] + [0] * 10
        self._rc_override_at = -math.inf
        # RC input: the pilot's transmitter, the overrides in force (per channel, with
        # their time) and, in ``_rc``, what the autopilot flies on and reports in RC_CHANNELS
        self._radio = list(self._rc)
        self._ovr: list[int | None] = [None] * 18
        self._ovr_at = [-math.inf] * 18
        # RC_OVERRIDE_TIME; < 0: never lapses
        self.rc_override_timeout_s = (
            self.RC_OVERRIDE_TIMEOUT_S if rc_override_timeout_s is None else rc_override_timeout_s
        )
        self.clock_offset_s = clock_offset_s  # added to the UTC this vehicle reports (SYSTEM_TIME)
        self._params: dict[str, float] = self._default_params(cfg, system_id, guided_timeout_s)
        self._params.update(params or {})  # the vehicle's own configuration (e.g. GRIP_ENABLE = 1)
        if self.BOOT_MODE is not None and not self.vehicle.armed:
            self.vehicle.mode = self.BOOT_MODE
        self._ltp = LocalTangentPlane(GeoPoint(cfg.home.lat_deg, cfg.home.lon_deg, cfg.home.alt_amsl_m))
        self.on_message: Callable[[Any], None] | None = None  # test hook: every decoded message

    # ------------------------------------------------------------------ signing
    @property
    def signing_key(self) -> bytes | None:
        """The key the vehicle signs with (None: not signing)."""
        key = self._rx.signing.secret_key
        return bytes(key) if key is not None else None

    def _set_signing(self, key: bytes, initial_timestamp: int) -> None:
        """ArduPilot's load_signing_key: the all-zero key with timestamp 0 turns signing off."""
        if len(key) != KEY_LEN:
            raise ValueError(f"signing key: {KEY_LEN} bytes expected, got {len(key)}")
        sig = self._rx.signing
        if initial_timestamp == 0 and not any(key):
            sig.secret_key = None
            sig.sign_outgoing = False
            sig.allow_unsigned_callback = None
            log.info("sim vehicle: signing off")
            return
        sig.secret_key = bytes(key)
        sig.link_id = 0  # ArduPilot: its channel number
        sig.sign_outgoing = True
        sig.allow_unsigned_callback = accept_everything if self.trusted_link else accept_unsigned_ardupilot
        # 60 s past the stored timestamp, then up to the GPS clock (update_signing_timestamp)
        # (a second SETUP_SIGNING with the same timestamp turns it back, as on ArduPilot)
        sig.timestamp = max(initial_timestamp + AP_KEY_LOAD_OFFSET, clock_timestamp())
        log.info("sim vehicle: signing on")

    def _setup_signing(self, m: Any) -> None:
        if not self.SIGNING or m.target_system not in (0, self.system_id):
            return
        if self.vehicle.armed:
            self._statustext("ERROR: Won't setup signing when armed", mavlink.MAV_SEVERITY_WARNING)
            return
        self._set_signing(bytes(m.secret_key), int(m.initial_timestamp))

    # ------------------------------------------------------------------ dialect hooks
    def _vehicle_config(self, cfg: SimConfig, guided_timeout_s: float, ekf_delay_s: float | None) -> SimConfig:
        """The configuration of the vehicle the dialect builds when none is handed in."""
        return cfg

    @abc.abstractmethod
    def _default_params(self, cfg: SimConfig, system_id: int, guided_timeout_s: float) -> dict[str, float]: ...

    @abc.abstractmethod
    def _pilot_mode(self, mode: FlightMode) -> None: ...

    def _rc_switch(self, now: float) -> None:
        """The autopilot reads the pilot's RC (mode switch, sticks) after the RC input changed."""
        return None  # optional hook: this dialect ignores it

    @abc.abstractmethod
    def _mode_flags(self) -> int: ...

    @abc.abstractmethod
    def _heartbeat_autopilot(self) -> tuple[int, int]:
        """(MAV_AUTOPILOT, custom_mode) of the HEARTBEAT."""
        ...

    def _arm_refused(self) -> int | None:
        """A MAV_RESULT if the dialect refuses to arm now, else None."""
        return None

    @abc.abstractmethod
    def _takeoff(self, p: tuple[float, ...]) -> int: ...

    def _gripper(self, p: tuple[float, ...]) -> int:
        """MAV_CMD_DO_GRIPPER (param 2: 0 = release)."""
        if _i(p[1]) == mavlink.GRIPPER_ACTION_RELEASE:
            self.vehicle.release_payload()
        return mavlink.MAV_RESULT_ACCEPTED

    def _set_servo(self, p: tuple[float, ...]) -> int:
        """MAV_CMD_DO_SET_SERVO (param 1 output, param 2 PWM)."""
        if _i(p[0]) == self.release_servo and _i(p[1]) >= self.release_pwm - 100:
            self.vehicle.release_payload()
        return mavlink.MAV_RESULT_ACCEPTED

    def _set_actuator(self, p: tuple[float, ...]) -> int | None:
        """MAV_CMD_DO_SET_ACTUATOR; None: not a command of this dialect."""
        return None

    @abc.abstractmethod
    def _land(self) -> int: ...

    @abc.abstractmethod
    def _rtl(self) -> int: ...

    @abc.abstractmethod
    def _set_mode(self, base: float, custom_main: float, custom_sub: float) -> int: ...

    def _landing_target_angles(self, m: Any) -> None:
        """LANDING_TARGET without a valid local position (the angle form)."""
        return None  # optional hook: this dialect ignores it

    @abc.abstractmethod
    def _velocity_setpoint(self, sp: VelocitySetpoint) -> None: ...

    # ------------------------------------------------------------------ lifecycle
    @property
    def address(self) -> tuple[str, int]:
        if self._sock is None:
            raise RuntimeError("vehicle not started")
        host, port = self._sock.getsockname()[:2]
        return host, port

    @property
    def running(self) -> bool:
        """Started and not stopped: the vehicle's clock runs."""
        return self._thread is not None

    @property
    def now(self) -> float:
        """Vehicle time: seconds since :meth:`start` (the vehicle's boot)."""
        return time.monotonic() - self._t0

    BOOT_MODE: ClassVar[FlightMode | None] = None  # the autopilot's mode at boot (None: the vehicle's)

    def start(self) -> MavlinkSimVehicle:
        if self._thread is not None:
            return self
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(self._bind)
        sock.setblocking(False)
        self._sock = sock
        self._t0 = time.monotonic() - self.vehicle.time_s
        self._running = True
        self._thread = threading.Thread(target=self._run, name=f"mavlink-sim-{self.dialect}", daemon=True)
        self._thread.start()
        log.info("MAVLink %s sim vehicle on udp %s:%d -> %s", self.dialect, *self.address, self.remote)
        return self

    def stop(self) -> None:
        self._running = False
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> MavlinkSimVehicle:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def set_link(self, up: bool) -> None:
        """Test hook: cut (both directions) or restore the radio link."""
        self._link_up = up

    # ------------------------------------------------------------------ pilot hooks
    def pilot_set_mode(self, mode: FlightMode) -> None:
        """The pilot flips the mode switch on the vehicle side (thread-safe)."""
        with self.lock:
            self.vehicle.step_to(self.now)
            self._pilot_mode(mode)

    @property
    def rc_channels(self) -> list[int]:
        return list(self._rc)

    @property
    def rc_overrides(self) -> list[int | None]:
        """The companion's overrides in force per channel (None: the radio's value is used)."""
        with self.lock:
            return list(self._ovr)

    def pilot_set_rc(self, channels: dict[int, int]) -> None:
        """The pilot's transmitter (ArduPilot dialect): 1-based channel -> microseconds, thread-safe.
        Overridden channels keep the override until it is released or lapses."""
        for ch, us in channels.items():
            if not 1 <= ch <= 18:
                raise ValueError(f"RC channel {ch}: must be 1..18")
            if not 0 <= us <= 65535:
                raise ValueError(f"RC channel {ch} = {us}: must be 0..65535 us")
        with self.lock:
            running = self.running  # before start(), vehicle time has not begun
            now = self.now if running else self.vehicle.time_s
            if running:
                self.vehicle.step_to(now)
            for ch, us in channels.items():
                self._radio[ch - 1] = int(us)
            self._rc_effective(now)
            self._rc_switch(now)

    # ------------------------------------------------------------------ main loop
    def _run(self) -> None:
        v = self.vehicle
        dt = 1.0 / self.cfg.vehicle.physics_rate_hz
        assert self._sock is not None
        sock = self._sock
        next_tick = self.now
        while self._running:
            timeout = next_tick - self.now
            if timeout > 0:
                try:
                    ready, _, _ = select.select([sock], [], [], timeout)
                except (OSError, ValueError):
                    break
                if ready:
                    self._drain(sock)
                    continue
            now = self.now
            with self.lock:
                v.step_to(now)
                self._rc_switch(now)
                self._send_due(now)
            next_tick = max(next_tick + dt, now - dt)

    def _drain(self, sock: socket.socket) -> None:
        for _ in range(64):
            try:
                data, addr = sock.recvfrom(65535)
            except (BlockingIOError, InterruptedError):
                return
            except OSError as err:  # e.g. ICMP port unreachable from a peer that went away
                log.debug("recv error: %s", err)
                return
            if not self._link_up:
                continue
            self.stats.datagrams_in += 1
            if addr not in self.peers:
                self.peers.append(addr)
                if len(self.peers) > 8:
                    del self.peers[0]
            self._parse(data)

    def _parse(self, data: bytes) -> None:
        rx = self._rx
        try:
            msgs = rx.parse_buffer(data) or []
        except Exception as err:
            self.stats.bad_data += 1
            self.stats.garbage_bytes += len(data)
            log.debug("unparseable datagram (%d bytes): %s", len(data), err)
            msgs = []
        if rx.buf_len() > 0:  # a datagram holds whole packets: leftovers are garbage
            self.stats.garbage_bytes += rx.buf_len()
            self.stats.bad_data += 1
            rx.buf = bytearray()
            rx.buf_index = 0
            rx.expected_length = mavlink.HEADER_LEN_V1 + 2
        for m in msgs:
            if m.get_type() == "BAD_DATA":
                if getattr(m, "reason", "") == "Invalid signature":
                    self.stats.signature_rejects += 1
                    continue
                self.stats.bad_data += 1
                self.stats.garbage_bytes += len(m.data)
                continue
            if m.get_srcSystem() == self.system_id and m.get_srcComponent() == self.component_id:
                continue
            self.stats.messages_in += 1
            self.stats.signed_in += m.get_signed()
            self.stats.by_type_in[m.get_type()] += 1
            if self.on_message is not None:
                self.on_message(m)
            try:
                with self.lock:
                    self.vehicle.step_to(self.now)
                    self._handle(m)
            except Exception:
                log.exception("error handling %s", m.get_type())

    # ------------------------------------------------------------------ sending
    def _send(self, msg: Any) -> None:
        if not self._link_up or self._sock is None:
            return
        w = self._enc.file
        w.data = b""
        self._enc.send(msg)
        buf = w.data
        targets = list(self.peers)
        if self.remote is not None and self.remote not in targets:
            targets.append(self.remote)
        for addr in targets:
            try:
                self._sock.sendto(buf, addr)
            except OSError:
                self.stats.send_errors += 1
        self.stats.messages_out += 1

    def _send_due(self, now: float) -> None:
        if now >= self._hb_next:
            self._hb_next = now + self._hb_period
            self._send(self._heartbeat())
        for mid, st in self._streams.items():
            if now >= st[1]:
                st[1] = max(st[1] + st[0], now)
                msg = self._build(mid)
                if msg is not None:
                    self._send(msg)
        v = self.vehicle
        while self._texts_sent < len(v.status_texts):
            _ts, text = v.status_texts[self._texts_sent]
            self._texts_sent += 1
            self._statustext(text, mavlink.MAV_SEVERITY_INFO)
        home = v.home()
        if home is not None:
            key = (home.lat_deg, home.lon_deg, home.alt_amsl_m)
            wanted = self.HOME_ALWAYS or mavlink.MAVLINK_MSG_ID_HOME_POSITION in self._streams
            if key != self._home_sent and wanted:
                self._home_sent = key
                self._send(self._build(mavlink.MAVLINK_MSG_ID_HOME_POSITION))

    def _statustext(self, text: str, severity: int) -> None:
        self._send(self._enc.statustext_encode(severity, text[:50].encode()))

    def _ack(self, command: int, result: int, m: Any) -> None:
        self._send(self._enc.command_ack_encode(command, result, 0, 0, m.get_srcSystem(), m.get_srcComponent()))

    # ------------------------------------------------------------------ message builders
    def _base_mode(self) -> int:
        b = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.vehicle.armed:
            b |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        return b | self._mode_flags()

    def _heartbeat(self) -> Any:
        v = self.vehicle
        ap, custom = self._heartbeat_autopilot()
        state = mavlink.MAV_STATE_ACTIVE if v.armed else mavlink.MAV_STATE_STANDBY
        return self._enc.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, ap, self._base_mode(), custom, state, 3)

    def _local(self) -> tuple[float, float, float, float, float, float]:
        p = self.vehicle.position_ned()
        dz = self.LOCAL_Z_OFFSET_M
        return p.north_m, p.east_m, p.down_m + dz, p.north_m_s, p.east_m_s, p.down_m_s

    def _landed_state(self) -> int:
        v = self.vehicle
        if v.landed is LandedState.ON_GROUND:
            return mavlink.MAV_LANDED_STATE_ON_GROUND
        if v.mode is FlightMode.LAND:
            return mavlink.MAV_LANDED_STATE_LANDING
        if v.mode is FlightMode.TAKEOFF:
            return mavlink.MAV_LANDED_STATE_TAKEOFF
        return mavlink.MAV_LANDED_STATE_IN_AIR

    def _build(self, mid: int) -> Any:
        v, e = self.vehicle, self._enc
        t_ms = int(v.time_s * 1000) & 0xFFFFFFFF
        t_us = int(v.time_s * 1e6)
        if mid == mavlink.MAVLINK_MSG_ID_ATTITUDE:
            a = v.attitude()
            return e.attitude_encode(
                t_ms, a.roll_rad, a.pitch_rad, a.yaw_rad, a.rollspeed_rad_s, a.pitchspeed_rad_s, a.yawspeed_rad_s
            )
        if mid == mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION:
            a = v.attitude()
            q = euler_to_quaternion(a.roll_rad, a.pitch_rad, a.yaw_rad)
            return e.attitude_quaternion_encode(t_ms, *q, a.rollspeed_rad_s, a.pitchspeed_rad_s, a.yawspeed_rad_s)
        if mid == mavlink.MAVLINK_MSG_ID_HIGHRES_IMU:
            i = v.imu()
            alt = -v.pd + self.cfg.home.alt_amsl_m
            p_hpa = 1013.25 * (1.0 - 2.25577e-5 * alt) ** 5.25588
            return e.highres_imu_encode(
                t_us,
                i.accel_x_m_s2,
                i.accel_y_m_s2,
                i.accel_z_m_s2,
                i.gyro_x_rad_s,
                i.gyro_y_rad_s,
                i.gyro_z_rad_s,
                0.2,
                0.0,
                0.4,
                p_hpa,
                0.0,
                alt,
                25.0,
                0x1FFF,
            )
        if mid == mavlink.MAVLINK_MSG_ID_RAW_IMU:
            i = v.imu()
            mg = 1000.0 / G
            return e.raw_imu_encode(
                t_us,
                *(round(x * mg) for x in (i.accel_x_m_s2, i.accel_y_m_s2, i.accel_z_m_s2)),
                *(round(x * 1000.0) for x in (i.gyro_x_rad_s, i.gyro_y_rad_s, i.gyro_z_rad_s)),
                200,
                0,
                400,
            )
        if mid == mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT:
            if not v.healthy:
                return None
            g = v.global_position()
            hdg = round(math.degrees(v.estimated_yaw()) * 100) % 36000  # the estimate, as ATTITUDE
            return e.global_position_int_encode(
                t_ms,
                round(g.lat_deg * 1e7),
                round(g.lon_deg * 1e7),
                round(g.alt_amsl_m * 1000),
                round(g.alt_rel_m * 1000),
                round(v.vn * 100),
                round(v.ve * 100),
                round(v.vd * 100),
                hdg,
            )
        if mid == mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED:
            if not v.healthy:
                return None
            return e.local_position_ned_encode(t_ms, *self._local())
        if mid == mavlink.MAVLINK_MSG_ID_GPS_RAW_INT:
            gr = v.gps_raw()
            speed = math.hypot(v.vn, v.ve)
            cog = round(math.degrees(math.atan2(v.ve, v.vn)) * 100) % 36000 if speed > 0.2 else 0xFFFF
            return e.gps_raw_int_encode(
                t_us,
                gr.fix_type,
                round(gr.lat_deg * 1e7),
                round(gr.lon_deg * 1e7),
                round(gr.alt_amsl_m * 1000),
                int(gr.eph_m * 100),
                120,
                int(speed * 100),
                cog,
                gr.satellites,
            )
        if mid == mavlink.MAVLINK_MSG_ID_SYS_STATUS:
            present = SENSORS_BASE | SENSORS_GPS | SENSORS_PREARM
            health = SENSORS_BASE | (SENSORS_GPS | SENSORS_PREARM if v.healthy else 0)
            volts = int(12600 - 2000 * (1.0 - v.battery_pct / 100.0))
            return e.sys_status_encode(
                present, present, health, 250, volts, 1000 if v.armed else 50, int(v.battery_pct), 0, 0, 0, 0, 0, 0
            )
        if mid == mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE:
            return e.extended_sys_state_encode(mavlink.MAV_VTOL_STATE_UNDEFINED, self._landed_state())
        if mid == mavlink.MAVLINK_MSG_ID_BATTERY_STATUS:
            volts = int(12600 - 2000 * (1.0 - v.battery_pct / 100.0))
            cells = [volts // 3] * 3 + [65535] * 7
            return e.battery_status_encode(
                0,
                mavlink.MAV_BATTERY_FUNCTION_ALL,
                mavlink.MAV_BATTERY_TYPE_LIPO,
                32767,
                cells,
                1000 if v.armed else 50,
                -1,
                -1,
                int(v.battery_pct),
            )
        if mid == mavlink.MAVLINK_MSG_ID_SYSTEM_TIME:  # the host's UTC, as a SITL reports it
            return e.system_time_encode(int((time.time() + self.clock_offset_s) * 1e6), t_ms)
        if mid == mavlink.MAVLINK_MSG_ID_HOME_POSITION:
            h = v.home()
            if h is None:
                return None
            return e.home_position_encode(
                round(h.lat_deg * 1e7),
                round(h.lon_deg * 1e7),
                round(h.alt_amsl_m * 1000),
                0.0,
                0.0,
                0.0,
                (1.0, 0.0, 0.0, 0.0),
                0.0,
                0.0,
                0.0,
                t_us,
            )
        if mid == mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION:
            g = self._ltp.to_geo(v.pn, v.pe, v.pd)
            a = v.attitude()
            mg = 1000.0 / G
            acc = v.imu()
            return e.hil_state_quaternion_encode(
                t_us,
                euler_to_quaternion(v.roll, v.pitch, v.yaw),
                a.rollspeed_rad_s,
                a.pitchspeed_rad_s,
                a.yawspeed_rad_s,
                # degE7 truncated toward zero, as PX4 and ArduPilot do (C's int32 conversion)
                int(g.lat_deg * 1e7),
                int(g.lon_deg * 1e7),
                round(g.alt_amsl_m * 1000),
                int(v.vn * 100),
                int(v.ve * 100),
                int(v.vd * 100),
                0,
                0,
                *(round(x * mg) for x in (acc.accel_x_m_s2, acc.accel_y_m_s2, acc.accel_z_m_s2)),
            )
        if mid == mavlink.MAVLINK_MSG_ID_RC_CHANNELS:
            n = max(8, max((i + 1 for i, us in enumerate(self._rc) if us), default=8))
            return e.rc_channels_encode(t_ms, n, *self._rc, 255)
        if mid == mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION:
            caps = (
                mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
                | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
                | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
                | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
                | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
            )
            if self.PARAM_BYTEWISE:
                caps |= mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
            sw = self.SOFTWARE_VERSION
            uid = 0x5349_4D00 + self.system_id
            return e.autopilot_version_encode(caps, sw, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, uid)
        return None

    # ------------------------------------------------------------------ receiving
    def _handle(self, m: Any) -> None:
        t = m.get_type()
        if t == "HEARTBEAT":
            return
        if t == "SETUP_SIGNING":
            self._setup_signing(m)
            return
        if t in ("COMMAND_LONG", "COMMAND_INT"):
            if m.target_system not in (0, self.system_id) or m.target_component not in (0, self.component_id):
                return
            if t == "COMMAND_LONG":
                p = (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7)
            else:
                p = (m.param1, m.param2, m.param3, m.param4, float(m.x), float(m.y), m.z)
            p = tuple(x if math.isfinite(x) else math.nan for x in p)  # type: ignore[assignment]
            self.stats.commands[m.command] += 1
            result = self._command(m.command, p, m)
            if result is not None:
                self._ack(m.command, result, m)
            return
        if t == "SET_POSITION_TARGET_LOCAL_NED":
            if m.target_system in (0, self.system_id):
                self._setpoint(m)
            return
        if t == "SET_MODE":
            if m.target_system in (0, self.system_id):
                res = self._set_mode(float(m.base_mode), float(m.custom_mode), 0.0)
                self._ack(mavlink.MAVLINK_MSG_ID_SET_MODE, res, m)
            return
        if t == "REQUEST_DATA_STREAM":
            if m.target_system in (0, self.system_id):
                self._request_data_stream(m.req_stream_id, m.req_message_rate, bool(m.start_stop))
            return
        if t == "RC_CHANNELS_OVERRIDE":
            if m.target_system in (0, self.system_id):
                self._rc_override(m)
            return
        if t == "LANDING_TARGET":
            self._landing_target(m)
            return
        if t == "SET_ATTITUDE_TARGET":
            if m.target_system in (0, self.system_id):
                self._attitude_target(m)
            return
        if t == "PARAM_REQUEST_LIST":
            names = list(self._params)
            for i, name in enumerate(names):
                self._param_value(name, i)
            return
        if t == "PARAM_REQUEST_READ":
            names = list(self._params)
            pid = m.param_id if isinstance(m.param_id, str) else m.param_id.decode(errors="replace")
            pid = pid.rstrip("\x00")
            if m.param_index >= 0 and m.param_index < len(names):
                self._param_value(names[m.param_index], m.param_index)
            elif pid in self._params:
                self._param_value(pid, names.index(pid))
            return
        if t == "PARAM_SET":
            pid = m.param_id if isinstance(m.param_id, str) else m.param_id.decode(errors="replace")
            pid = pid.rstrip("\x00")
            value = self._param_decode(pid, m.param_value)
            if math.isfinite(value):
                self._params[pid] = value
            self._param_value(pid, list(self._params).index(pid) if pid in self._params else 65535)
            return
        if t == "MISSION_REQUEST_LIST":
            self._send(self._enc.mission_count_encode(m.get_srcSystem(), m.get_srcComponent(), 0, m.mission_type))
            return
        if t == "TIMESYNC" and m.tc1 == 0:
            self._send(self._enc.timesync_encode(int(self.now * 1e9), m.ts1))
            return

    def _param_value(self, name: str, index: int) -> None:
        val = self._params.get(name, math.nan)
        ptype = mavlink.MAV_PARAM_TYPE_REAL32
        if name in self.INT_PARAMS and math.isfinite(val):
            ptype = mavlink.MAV_PARAM_TYPE_INT32
            if self.PARAM_BYTEWISE:  # the int32's bytes in the float field
                val = struct.unpack("<f", struct.pack("<i", int(val)))[0]
        self._send(self._enc.param_value_encode(name.encode()[:16], val, ptype, len(self._params), index))

    def _param_decode(self, name: str, value: float) -> float:
        """A PARAM_SET value as the firmware reads it (byte-wise int32 for PX4's integers)."""
        if name in self.INT_PARAMS and self.PARAM_BYTEWISE:
            return float(struct.unpack("<i", struct.pack("<f", value))[0])
        return float(value)

    def _reply(self, text: str, ok: bool) -> int:
        self._statustext(text, mavlink.MAV_SEVERITY_INFO if ok else mavlink.MAV_SEVERITY_CRITICAL)
        return mavlink.MAV_RESULT_ACCEPTED if ok else mavlink.MAV_RESULT_DENIED

    def _command(self, cmd: int, p: tuple[float, ...], m: Any) -> int | None:
        v = self.vehicle
        A, D, U = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_DENIED, mavlink.MAV_RESULT_UNSUPPORTED
        try:
            if cmd == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
                if p[0] >= 0.5:
                    refused = self._arm_refused()
                    if refused is not None:
                        return refused
                    v.arm()
                else:
                    if _i(p[1]) == 21196 and v.armed:  # forced disarm
                        v.armed = False
                    else:
                        v.disarm()
                return A
            if cmd == mavlink.MAV_CMD_NAV_TAKEOFF:
                return self._takeoff(p)
            if cmd == mavlink.MAV_CMD_NAV_LAND:
                return self._land()
            if cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
                return self._rtl()
            if cmd == mavlink.MAV_CMD_DO_SET_MODE:
                return self._set_mode(*(float(_i(x)) for x in p[:3]))
            if cmd == mavlink.MAV_CMD_DO_GRIPPER:
                return self._gripper(p)
            if cmd == mavlink.MAV_CMD_DO_SET_SERVO:
                result = self._set_servo(p)
                if result == U:
                    self.stats.unsupported_commands[cmd] += 1
                return result
            if cmd == mavlink.MAV_CMD_DO_SET_ACTUATOR:
                actuator = self._set_actuator(p)
                if actuator is not None:
                    return actuator
            if cmd == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
                return self._set_interval(_i(p[0]), p[1] if math.isfinite(p[1]) else 0.0)
            if cmd == mavlink.MAV_CMD_REQUEST_MESSAGE:
                msg = self._build(_i(p[0]))
                if msg is None:
                    return U
                self._ack(cmd, A, m)
                self._send(msg)
                return None
            if cmd == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
                self._ack(cmd, A, m)
                self._send(self._build(mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION))
                return None
        except SimCommandError as err:
            self._statustext(str(err), mavlink.MAV_SEVERITY_CRITICAL)
            return D
        self.stats.unsupported_commands[cmd] += 1
        return U

    def _set_interval(self, mid: int, interval_us: float) -> int:
        if mavlink.mavlink_map.get(mid) is None:
            return mavlink.MAV_RESULT_UNSUPPORTED
        if interval_us < 0:
            self._streams.pop(mid, None)
            return mavlink.MAV_RESULT_ACCEPTED
        if interval_us == 0:
            hz = PX4_DEFAULT_STREAMS_HZ.get(mid, 1.0)
            interval = 1.0 / hz
        else:
            interval = max(interval_us * 1e-6, 0.002)
        if (
            mid != mavlink.MAVLINK_MSG_ID_HEARTBEAT
            and self._build(mid) is None
            and mid
            not in (
                mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
                mavlink.MAVLINK_MSG_ID_HOME_POSITION,
            )
        ):
            return mavlink.MAV_RESULT_UNSUPPORTED
        if mid == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            self._hb_period = interval
        else:
            self._streams[mid] = [interval, self.now]
        return mavlink.MAV_RESULT_ACCEPTED

    def _request_data_stream(self, stream_id: int, rate_hz: int, start: bool) -> None:
        groups = list(AP_STREAM_GROUPS) if stream_id == mavlink.MAV_DATA_STREAM_ALL else [stream_id]
        for g in groups:
            for mid in AP_STREAM_GROUPS.get(g, ()):
                if start and rate_hz > 0:
                    self._streams[mid] = [1.0 / rate_hz, self.now]
                else:
                    self._streams.pop(mid, None)

    def _landing_target(self, m: Any) -> None:
        """LANDING_TARGET as each autopilot reads it: PX4 the position form in MAV_FRAME_LOCAL_NED;
        ArduPilot (AC_PrecLand_Companion) angle_x / angle_y / distance as the body-frame line of
        sight (-tan(angle_y), tan(angle_x), 1), rotated by the attitude and added to its position."""
        v = self.vehicle
        self.stats.landing_targets += 1
        if m.position_valid and m.frame == mavlink.MAV_FRAME_LOCAL_NED:
            v.set_landing_target(float(m.x), float(m.y))
            return
        self._landing_target_angles(m)  # PX4's landing_target_estimator takes the position form only

    def _rc_override(self, m: Any) -> None:
        """RC_CHANNELS_OVERRIDE: channels 1-8: 0 releases, UINT16_MAX ignores; channels 9-18: 0
        and UINT16_MAX ignore, UINT16_MAX-1 releases; any other value overrides the channel."""
        now = self.now
        for i in range(18):
            val = int(getattr(m, f"chan{i + 1}_raw", 0))
            if val == 65535 or (i >= 8 and val == 0):
                continue
            if (i < 8 and val == 0) or (i >= 8 and val == 65534):
                self._ovr[i] = None
                continue
            self._ovr[i] = val
            self._ovr_at[i] = now
        self._rc_override_at = now
        self._rc_effective(now)
        self._rc_switch(now)

    def _attitude_target(self, m: Any) -> None:
        """SET_ATTITUDE_TARGET (offboard attitude) for a vehicle that flies it (``set_attitude_target``:
        companion_sitl.dart_link.StickSimVehicle): roll and pitch from the quaternion, the body yaw
        rate, the thrust; anything else (attitude ignored, no such vehicle) is rejected."""
        feed = getattr(self.vehicle, "set_attitude_target", None)
        if feed is None or m.type_mask & 0b1000_0000 or m.type_mask & 0b0100_0000:
            self.stats.setpoints_rejected += 1
            return
        roll, pitch, _yaw = quat_to_euler(m.q)
        yaw_rate = 0.0 if m.type_mask & 0b100 else float(m.body_yaw_rate)
        feed(roll, pitch, yaw_rate, float(m.thrust))
        self.stats.setpoints += 1

    def _rc_effective(self, now: float) -> None:
        """What the autopilot flies on: each override in force, else the radio; stale overrides
        lapse after RC_OVERRIDE_TIME (ArduPilot: the radio takes the channel back)."""
        timeout = self.rc_override_timeout_s
        for i in range(18):
            o = self._ovr[i]
            if o is not None and 0.0 <= timeout < now - self._ovr_at[i]:
                self._ovr[i] = o = None
            self._rc[i] = self._radio[i] if o is None else o

    def _setpoint(self, m: Any) -> None:
        v = self.vehicle
        mask = m.type_mask
        if m.coordinate_frame != mavlink.MAV_FRAME_LOCAL_NED or (mask & MASK_VEL) == MASK_VEL:
            self.stats.setpoints_rejected += 1
            return
        if (mask & MASK_POS) != MASK_POS:
            self.stats.setpoints_rejected += 1  # position control is not simulated
            return
        yaw = v.estimated_yaw() if mask & MASK_YAW else m.yaw  # YAW_IGNORE: hold the heading
        self._velocity_setpoint(VelocitySetpoint(m.vx, m.vy, m.vz, yaw))
        self.stats.setpoints += 1


def free_udp_port() -> int:
    """A currently free UDP port on 127.0.0.1."""
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])

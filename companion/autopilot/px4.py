"""PX4 backend through MAVSDK 4.x (the native ``mavsdk`` binding; no mavsdk_server).

``Mavsdk(Configuration(companion computer))``, ``add_any_connection(url)``,
``first_autopilot(timeout_s)``, then plugins built explicitly from the system: Action, Telemetry,
Offboard and MavlinkDirect. Telemetry arrives through MAVSDK's async streams, one task
per stream (cancelled, and so unsubscribed, in :meth:`close`), stamped on the shell's clock.

Setpoints. MAVSDK's Offboard plugin re-sends the last setpoint at 20 Hz on its own thread until
``offboard.stop()``: a stale setpoint would be resent forever if the control task died (MAVSDK-
Python issue 374), which defeats the shell's stale-setpoint watchdog and PX4's offboard-loss
failsafe. So by default (``setpoint_transport="direct"``) each setpoint is one
SET_POSITION_TARGET_LOCAL_NED sent through MavlinkDirect (synchronous and non-blocking), and
OFFBOARD is entered with MAV_CMD_DO_SET_MODE (PX4 refuses unless setpoints streamed first).
``setpoint_transport="offboard"`` uses the plugin's synchronous ``set_velocity_ned`` and
``start()`` instead, with a guard that calls ``offboard.stop()`` (PX4 HOLD) when the shell stops
refreshing the setpoint while the vehicle is in OFFBOARD.

Link watchdog: MAVSDK's connection state (3 s heartbeat timeout) and the arrival of telemetry
(``link_timeout_s``).

Commands, as PX4 v1.16 SIH answers them (measured): every call is bounded by
``command_timeout_s`` and ends in :class:`CommandRejected` with PX4's MAV_RESULT. Arming is
refused (TEMPORARILY_REJECTED) in POSCTL without RC and in AUTO.LAND / AUTO.TAKEOFF, and (DENIED)
in OFFBOARD once our setpoints stopped, which is the mode a companion-flown landing leaves the
vehicle in; :meth:`arm` therefore switches to HOLD (AUTO.LOITER, where PX4 arms) first. The parcel
is released with MAV_CMD_DO_GRIPPER (ACCEPTED at once) or MAV_CMD_DO_SET_ACTUATOR (an output whose
function is "Peripheral via Actuator Set N"); PX4 answers MAV_CMD_DO_SET_SERVO with UNSUPPORTED.
Both go out as COMMAND_LONG through MavlinkDirect: MAVSDK's Gripper plugin answered UNKNOWN and
then left a native call blocked, and ``Mavsdk.destroy()`` behind it, so :meth:`close` also
destroys MAVSDK on a daemon thread with a time limit rather than hang the application.

MAVLink log (``tlog``, an :data:`~companion.autopilot.interface.OpenPacketSink`): MAVSDK does
not hand out raw packets on a UDP/TCP/serial link, but its core reports every message it
receives and every message it sends (its own heartbeats, Action and parameter traffic, our
MavlinkDirect setpoints and commands) decoded to JSON
(``Mavsdk::subscribe_incoming/outgoing_messages_json``). Those are re-encoded as MAVLink 2 with
pymavlink on the log's writer thread: message types, source ids and field values are the
originals; sequence numbers, MAVLink 1 framing and signatures are not, and whatever MAVSDK
discards before decoding (bad CRC, unknown ids) is not in the file.
"""

from __future__ import annotations

import asyncio
import contextlib
import ctypes
import json
import logging
import math
import os
import threading
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from typing import Any, Literal

from companion.autopilot.interface import (
    LINK_DOWN,
    NO_ANSWER,
    AttitudeTarget,
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
from companion.autopilot.mavlink_messages import VELOCITY_YAW_MASK, MavlinkPacker
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
    VehicleStatus,
)
from companion.geometry import euler_to_quat
from companion.guidance.setpoint import VelocitySetpoint

log = logging.getLogger(__name__)

STREAM_RESUBSCRIBE_S = 1.0  # a MAVSDK stream that ended or raised is subscribed again after this
ATTITUDE_TARGET_RATES_IGNORED = 0b0000_0011  # SET_ATTITUDE_TARGET: use q, yaw rate, thrust
MAV_FRAME_LOCAL_NED = 1
MAV_FRAME_BODY_FRD = 12
LANDING_TARGET_TYPE_VISION_FIDUCIAL = 2
MAV_CMD_DO_SET_MODE = 176
MAV_CMD_REQUEST_MESSAGE = 512
MAV_CMD_DO_SET_SERVO = 183
MAV_CMD_DO_GRIPPER = 211
GRIPPER_ACTION_RELEASE = 0
PX4_MAIN_AUTO = 4
PX4_AUTO_LOITER = 3
MAV_MODE_FLAG_CUSTOM_MODE_ENABLED = 1
MAV_MODE_FLAG_SAFETY_ARMED = 128
PX4_MAIN_OFFBOARD = 6
MAV_RESULT_NAMES = {
    0: "ACCEPTED",
    1: "TEMPORARILY_REJECTED",
    2: "DENIED",
    3: "UNSUPPORTED",
    4: "FAILED",
    5: "IN_PROGRESS",
    6: "CANCELLED",
}
# MAVSDK's Action/Offboard result names -> the MAV_RESULT behind them (CommandRejected.result)
_MAVSDK_RESULTS = {
    "COMMAND_DENIED": "DENIED",
    "COMMAND_DENIED_LANDED_STATE_UNKNOWN": "DENIED",
    "COMMAND_DENIED_NOT_LANDED": "DENIED",
    "UNSUPPORTED": "UNSUPPORTED",
    "FAILED": "FAILED",
    "BUSY": "TEMPORARILY_REJECTED",
    "TIMEOUT": NO_ANSWER,
    "NO_SYSTEM": LINK_DOWN,
    "CONNECTION_ERROR": LINK_DOWN,
}

_FLIGHT_MODES = {
    "UNKNOWN": FlightMode.UNKNOWN,
    "READY": FlightMode.HOLD,
    "TAKEOFF": FlightMode.TAKEOFF,
    "HOLD": FlightMode.HOLD,
    "MISSION": FlightMode.MISSION,
    "RETURN_TO_LAUNCH": FlightMode.RTL,
    "LAND": FlightMode.LAND,
    "OFFBOARD": FlightMode.OFFBOARD,
    "FOLLOW_ME": FlightMode.MISSION,
    "MANUAL": FlightMode.MANUAL,
    "ALTCTL": FlightMode.MANUAL,
    "POSCTL": FlightMode.POSITION,
    "ACRO": FlightMode.MANUAL,
    "STABILIZED": FlightMode.MANUAL,
    "RATTITUDE": FlightMode.MANUAL,
}
_LANDED = {
    "UNKNOWN": LandedState.UNKNOWN,
    "ON_GROUND": LandedState.ON_GROUND,
    "IN_AIR": LandedState.IN_AIR,
    "TAKING_OFF": LandedState.TAKING_OFF,
    "LANDING": LandedState.LANDING,
}
_SEVERITY = {"EMERGENCY": 0, "ALERT": 1, "CRITICAL": 2, "ERROR": 3, "WARNING": 4, "NOTICE": 5, "INFO": 6, "DEBUG": 7}


_PX4_AUTO_SUB = {
    1: FlightMode.HOLD,  # AUTO.READY
    2: FlightMode.TAKEOFF,
    3: FlightMode.HOLD,  # AUTO.LOITER
    4: FlightMode.MISSION,
    5: FlightMode.RTL,
    6: FlightMode.LAND,
    8: FlightMode.MISSION,  # follow target
    9: FlightMode.LAND,  # precision land
}
_PX4_MAIN = {
    1: FlightMode.MANUAL,
    2: FlightMode.MANUAL,  # ALTCTL
    3: FlightMode.POSITION,  # POSCTL
    5: FlightMode.MANUAL,  # ACRO
    6: FlightMode.OFFBOARD,
    7: FlightMode.MANUAL,  # STABILIZED
    8: FlightMode.MANUAL,  # RATTITUDE
}


def px4_flight_mode(custom_mode: int) -> FlightMode:
    """PX4 HEARTBEAT custom_mode (main mode << 16 | sub mode << 24) -> :class:`FlightMode`."""
    main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
    if main == 4:  # AUTO
        return _PX4_AUTO_SUB.get(sub, FlightMode.UNKNOWN)
    return _PX4_MAIN.get(main, FlightMode.UNKNOWN)


def flight_mode_from_mavsdk(mode: Any) -> FlightMode:
    return _FLIGHT_MODES.get(getattr(mode, "name", str(mode)), FlightMode.UNKNOWN)


def intercept_messages_json(mavsdk: Any, direction: str, fn: Callable[[Any], None]) -> Any:
    """Call ``fn`` with every MAVLink message MAVSDK receives (``direction="incoming"``) or sends
    (``"outgoing"``), decoded: a ``mavsdk.types.MavsdkMessage`` with ``message_name``,
    ``system_id``, ``component_id`` and ``fields_json``. Runs on MAVSDK's thread (or the sender's).

    The C library exports ``mavsdk_subscribe_{incoming,outgoing}_messages_json`` but the mavsdk 4
    Python binding does not wrap them, so they are called through ctypes. The callback always
    returns 1 (MAVSDK drops a message whose interceptor returns 0). Returns an unsubscribe
    function, or None if this MAVSDK build lacks the interface.
    """
    try:
        from mavsdk.cmavsdk_loader import _cmavsdk_lib as lib
        from mavsdk.types import InterceptJsonCallback
    except ImportError:
        return None
    sub = getattr(lib, f"mavsdk_subscribe_{direction}_messages_json", None)
    unsub = getattr(lib, f"mavsdk_unsubscribe_{direction}_messages_json", None)
    core = getattr(getattr(mavsdk, "_mavsdk", None), "_handle", None)
    if sub is None or unsub is None or not core:
        return None
    sub.argtypes = [ctypes.c_void_p, InterceptJsonCallback, ctypes.c_void_p]
    sub.restype = ctypes.c_void_p
    unsub.argtypes = [ctypes.c_void_p, ctypes.c_void_p]
    unsub.restype = None

    def trampoline(msg: Any, _user_data: Any) -> int:
        with contextlib.suppress(Exception):
            fn(msg)
        return 1

    cb = InterceptJsonCallback(trampoline)
    handle = sub(core, cb, None)
    if not handle:
        return None

    def unsubscribe(keep_alive: Any = cb) -> None:  # the C callback must outlive the subscription
        unsub(core, handle)

    return unsubscribe


_mavsdk_log = logging.getLogger(__name__ + ".mavsdk")
_MAVSDK_LOG_LEVELS = (logging.DEBUG, logging.INFO, logging.WARNING, logging.ERROR)  # mavsdk LogLevel 0..3
_mavsdk_log_routed = False
#: while a connect is waiting for the autopilot: MAVSDK's warnings and errors, kept for the error
#: message (and logged at debug) instead of printed one per retry
_mavsdk_connect_problems: list[str] | None = None


def route_mavsdk_log() -> None:
    """Send MAVSDK's own log lines (its C++ core prints them to stderr) to Python logging, logger
    ``companion.autopilot.px4.mavsdk``, so ``-v`` shows them and a failed start-up prints only
    its one error line. Once per process."""
    global _mavsdk_log_routed
    if _mavsdk_log_routed:
        return
    from mavsdk.logging import log_subscribe

    def on_log(level: Any, message: str, file: str | None, line: int) -> bool:
        lvl = _MAVSDK_LOG_LEVELS[min(max(int(level), 0), 3)]
        problems = _mavsdk_connect_problems
        if problems is not None and lvl >= logging.WARNING:
            problems.append(message)
            lvl = logging.DEBUG
        _mavsdk_log.log(lvl, "%s (%s:%d)", message, file or "?", line)
        return True  # handled: MAVSDK does not print it

    log_subscribe(on_log)
    _mavsdk_log_routed = True


def check_connection_url(url: str) -> str:
    """Validate a MAVSDK connection URL; a serial device must exist. Returns the URL."""
    u = url.strip()
    scheme, sep, rest = u.partition("://")
    if not sep:
        raise ConnectionUrlError(
            f"connection {url!r}: expected a MAVSDK URL (udpin://HOST:PORT, udpout://, tcpout://, serial:///dev/X:BAUD)"
        )
    if scheme == "serial":
        dev = rest.rsplit(":", 1)[0] if rest.rsplit(":", 1)[-1].isdigit() else rest
        if not os.path.exists(dev):
            raise LinkDeviceMissing(f"serial device {dev} does not exist (connection {url!r})")
    elif scheme not in ("udp", "udpin", "udpout", "tcp", "tcpin", "tcpout", "raw"):
        raise ConnectionUrlError(f"connection {url!r}: unknown scheme {scheme!r}")
    return u


class Px4Autopilot(Autopilot):
    def __init__(
        self,
        connection: str = "udpin://0.0.0.0:14540",
        *,
        link_timeout_s: float = 1.0,
        setpoint_transport: Literal["direct", "offboard"] = "direct",
        setpoint_stale_s: float = 0.5,
        release: Literal["gripper", "servo", "actuator"] = "gripper",
        gripper_instance: int = 1,
        release_servo: int = 9,
        release_pwm: int = 1900,
        release_actuator: int = 1,
        release_actuator_value: float = 1.0,
        command_timeout_s: float = 5.0,
        destroy_timeout_s: float = 3.0,
        tlog: OpenPacketSink | None = None,
    ):
        self.connection = connection
        self.link_timeout_s = link_timeout_s
        self.setpoint_transport = setpoint_transport
        self.setpoint_stale_s = setpoint_stale_s
        self.release = release
        self.gripper_instance = gripper_instance
        self.release_servo = release_servo
        self.release_pwm = release_pwm
        self.release_actuator = release_actuator
        self.release_actuator_value = release_actuator_value
        self.command_timeout_s = command_timeout_s
        self.destroy_timeout_s = destroy_timeout_s
        self.streams_restarted = 0  # telemetry streams that ended or raised and were subscribed again
        self.calls_unanswered = 0  # native calls abandoned at command_timeout_s (still blocked in MAVSDK)
        self.telemetry = TelemetryCache()
        self.setpoints_sent = 0
        self.setpoints_dropped = 0
        self.system_id = 1
        self.open_tlog = tlog
        self.tlog: PacketSink | None = None
        self._tlog_opened = False  # a reconnect appends to the same file
        self._tlog_unhook: list[Callable[[], None]] = []
        self._mavsdk: Any = None
        self._system: Any = None
        self._action: Any = None
        self._tel: Any = None
        self._offboard: Any = None
        self._direct: Any = None
        self._direct_sync: Any = None
        self._param: Any = None
        self._offboard_sync: Any = None
        self._tasks: list[asyncio.Task[None]] = []
        self._leaked: list[Any] = []
        self._connected = False
        self._last_rx = -math.inf
        self._last_hb = -math.inf
        self._latch = LinkLatch()
        self._last_sp_call = -math.inf
        self._plugin_streaming = False
        self._t_boot = time.monotonic()
        # composed status
        self._armed = False
        self._mode = FlightMode.UNKNOWN
        self._landed = LandedState.UNKNOWN
        self._healthy = False
        self._battery_pct = 100.0
        self._payload_released = False
        self._rates = (0.0, 0.0, 0.0)
        self._gps_fix = 0
        self._gps_sats = 0
        self._last_text = ""

    @classmethod
    def from_config(cls, config: Any, **kwargs: Any) -> Px4Autopilot:
        kwargs.setdefault("setpoint_stale_s", config.runtime.setpoint_stale_s)
        pl = config.payload
        kwargs.setdefault("release", pl.release)
        kwargs.setdefault("gripper_instance", pl.gripper_instance)
        kwargs.setdefault("release_servo", pl.servo_channel)
        kwargs.setdefault("release_pwm", pl.servo_pwm_us)
        kwargs.setdefault("release_actuator", pl.actuator_index)
        kwargs.setdefault("release_actuator_value", pl.actuator_value)
        return cls(config.connection, link_timeout_s=config.runtime.link_timeout_s, **kwargs)

    # ------------------------------------------------------------------ link
    async def connect(self, timeout_s: float = 10.0) -> None:
        if self._system is not None:
            return
        url = check_connection_url(self.connection)
        from mavsdk.asyncio import ComponentType, Configuration, Mavsdk
        from mavsdk.asyncio.plugins.action import ActionAsync
        from mavsdk.asyncio.plugins.mavlink_direct import MavlinkDirectAsync
        from mavsdk.asyncio.plugins.offboard import OffboardAsync
        from mavsdk.asyncio.plugins.telemetry import TelemetryAsync

        route_mavsdk_log()
        self._mavsdk = Mavsdk(Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER))
        if self.open_tlog is not None:
            try:
                self._open_tlog(self.open_tlog)
            except OSError as err:
                self._destroy()
                raise AutopilotError(str(err)) from None
        global _mavsdk_connect_problems
        problems: list[str] = []
        _mavsdk_connect_problems = problems
        try:  # until MAVSDK is up or destroyed: its retries' complaints go into the error, not stderr
            try:
                await self._mavsdk.add_any_connection(url)
            except Exception as err:
                self._destroy()
                raise AutopilotUnreachable(f"cannot open {url!r}: {err}") from None
            system = await self._mavsdk.first_autopilot(timeout_s=timeout_s)
            if system is None:
                self._destroy()
                seen = [p for p in dict.fromkeys(problems) if "sending message failed" not in p.lower()]
                why = f" (MAVSDK: {'; '.join(seen[-2:])})" if seen else ""
                raise AutopilotUnreachable(f"no PX4 autopilot answered on {url!r} within {timeout_s:.1f} s{why}")
        finally:
            _mavsdk_connect_problems = None
        self._system = system
        self.system_id = await system.get_system_id()
        self._action = ActionAsync(system)
        self._tel = TelemetryAsync(system)
        self._offboard = OffboardAsync(system)
        self._offboard_sync = self._offboard._plugin
        self._direct = MavlinkDirectAsync(system)
        self._direct_sync = self._direct._plugin
        self._param = None  # built on the first read_params
        self._connected = True
        self._last_rx = time.monotonic()
        self._start_streams()
        log.info("PX4 system %d on %s", self.system_id, url)

    def _start_streams(self) -> None:
        tel, loop = self._tel, asyncio.get_running_loop()

        def now() -> float:
            return loop.time()

        def on_pv(pv: Any) -> None:
            p, v = pv.position, pv.velocity
            self._push(PositionNed(now(), p.north_m, p.east_m, p.down_m, v.north_m_s, v.east_m_s, v.down_m_s))

        def on_pos(p: Any) -> None:
            self._push(
                GlobalPosition(now(), p.latitude_deg, p.longitude_deg, p.absolute_altitude_m, p.relative_altitude_m)
            )

        def on_att(e: Any) -> None:
            r = math.radians
            self._push(Attitude(now(), r(e.roll_deg), r(e.pitch_deg), r(e.yaw_deg), *self._rates))

        def on_rates(w: Any) -> None:
            self._rates = (w.roll_rad_s, w.pitch_rad_s, w.yaw_rad_s)

        def on_imu(i: Any) -> None:
            a, g = i.acceleration_frd, i.angular_velocity_frd
            self._push(
                Imu(now(), a.forward_m_s2, a.right_m_s2, a.down_m_s2, g.forward_rad_s, g.right_rad_s, g.down_rad_s)
            )

        def on_gps_info(gi: Any) -> None:
            self._gps_fix = int(getattr(gi.fix_type, "value", gi.fix_type))
            self._gps_sats = int(gi.num_satellites)

        def on_raw_gps(g: Any) -> None:
            eph = g.horizontal_uncertainty_m if math.isfinite(g.horizontal_uncertainty_m) else g.hdop
            eph = eph if math.isfinite(eph) else 99.99
            self._push(
                GpsRaw(
                    now(), g.latitude_deg, g.longitude_deg, g.absolute_altitude_m, self._gps_fix, self._gps_sats, eph
                )
            )

        def on_mode(m: Any) -> None:
            self._mode = flight_mode_from_mavsdk(m)
            self._push_status()

        def on_armed(a: bool) -> None:
            self._armed = bool(a)
            self._push_status()

        def on_landed(s: Any) -> None:
            self._landed = _LANDED.get(getattr(s, "name", ""), LandedState.UNKNOWN)
            self._push_status()

        def on_battery(b: Any) -> None:
            pct = b.remaining_percent
            if math.isfinite(pct):
                self._battery_pct = pct * 100.0 if pct <= 1.0 else pct

        def on_health(h: Any) -> None:
            self._healthy = bool(h.is_armable and h.is_global_position_ok and h.is_home_position_ok)
            self._push_status()

        def on_text(st: Any) -> None:
            text = str(st.text)
            self._last_text = text
            log.info("autopilot: %s", text)
            self._push(StatusText(now(), _SEVERITY.get(getattr(st.type, "name", ""), 6), text))

        def on_home(h: Any) -> None:
            pass  # MAVSDK's home stream keeps HOME_POSITION coming; on_home_position reads it whole

        def on_home_position(m: Any) -> None:  # with x/y/z: home in PX4's local frame
            if m.system_id != self.system_id:
                return
            try:
                f = json.loads(m.fields_json)
                home = HomePosition(
                    now(),
                    int(f["latitude"]) / 1e7,
                    int(f["longitude"]) / 1e7,
                    int(f["altitude"]) / 1000.0,
                    float(f.get("x", 0.0)),
                    float(f.get("y", 0.0)),
                    float(f.get("z", 0.0)),
                )
            except (ValueError, TypeError, KeyError) as err:
                log.warning("HOME_POSITION not understood (%s): %s", err, m.fields_json)
                return
            self._push(home)

        def on_heartbeat(m: Any) -> None:
            if m.system_id != self.system_id or m.component_id != 1:
                return
            try:
                hb = json.loads(m.fields_json)
            except ValueError:
                return
            self._last_hb = time.monotonic()
            self._armed = bool(int(hb.get("base_mode", 0)) & MAV_MODE_FLAG_SAFETY_ARMED)
            self._mode = px4_flight_mode(int(hb.get("custom_mode", 0)))
            self._push_status()

        streams: list[tuple[Callable[[], AsyncIterator[Any]], Callable[[Any], None]]] = [
            (tel.subscribe_position_velocity_ned, on_pv),
            (tel.subscribe_position, on_pos),
            (tel.subscribe_attitude_euler, on_att),
            (tel.subscribe_attitude_angular_velocity_body, on_rates),
            (tel.subscribe_imu, on_imu),
            (tel.subscribe_gps_info, on_gps_info),
            (tel.subscribe_raw_gps, on_raw_gps),
            (tel.subscribe_flight_mode, on_mode),
            (tel.subscribe_armed, on_armed),
            (tel.subscribe_landed_state, on_landed),
            (tel.subscribe_battery, on_battery),
            (tel.subscribe_health, on_health),
            (tel.subscribe_status_text, on_text),
            (tel.subscribe_home, on_home),
        ]
        for sub, fn in streams:
            self._tasks.append(loop.create_task(self._consume(sub, fn), name=f"px4-{fn.__name__}"))
        self._tasks.append(
            loop.create_task(self._consume(lambda: self._direct.subscribe_message("HEARTBEAT"), on_heartbeat))
        )
        self._tasks.append(
            loop.create_task(self._consume(lambda: self._direct.subscribe_message("HOME_POSITION"), on_home_position))
        )

        def on_rc_channels(m: Any) -> None:  # the receiver's raw channels (Dart: pilot sticks, switch)
            if m.system_id != self.system_id:
                return
            try:
                f = json.loads(m.fields_json)
                n = max(0, min(18, int(f.get("chancount", 18))))
                chans = tuple(int(f.get(f"chan{i}_raw", 0)) for i in range(1, n + 1))
            except (ValueError, TypeError):
                return
            self.telemetry.push_rc(RcInput(now(), chans))

        self._tasks.append(
            loop.create_task(self._consume(lambda: self._direct.subscribe_message("RC_CHANNELS"), on_rc_channels))
        )
        self._tasks.append(loop.create_task(self._watch_connection(), name="px4-connection"))
        if self.setpoint_transport == "offboard":
            self._tasks.append(loop.create_task(self._stale_guard(), name="px4-stale-guard"))

    async def _consume(self, subscribe: Callable[[], AsyncIterator[Any]], fn: Callable[[Any], None]) -> None:
        """One MAVSDK stream into ``fn``, for as long as the task runs. A stream that ends or
        raises is said once and subscribed again after ``STREAM_RESUBSCRIBE_S`` (counted in
        ``streams_restarted``): a stream lost silently would freeze that part of the telemetry
        (a landed state that never changes again leaves a landing that never ends)."""
        name = fn.__name__
        while True:
            gen = subscribe()
            why = "ended"
            try:
                async for item in gen:
                    self._last_rx = time.monotonic()
                    try:
                        fn(item)
                    except Exception:
                        log.exception("error decoding %s", name)
            except Exception as err:  # (a cancellation is not one: it ends the task)
                why = f"failed ({type(err).__name__}: {err})"
            finally:
                with contextlib.suppress(Exception):
                    await gen.aclose()  # type: ignore[attr-defined]
            self.streams_restarted += 1
            log.warning("MAVSDK stream %s %s: subscribing again in %.1f s", name, why, STREAM_RESUBSCRIBE_S)
            await asyncio.sleep(STREAM_RESUBSCRIBE_S)

    async def _watch_connection(self) -> None:
        gen = self._system.is_connected_state()
        try:
            async for connected in gen:
                if connected != self._connected:
                    log.warning("PX4 link %s", "restored" if connected else "lost (no heartbeat for 3 s)")
                self._connected = bool(connected)
        finally:
            with contextlib.suppress(Exception):
                await gen.aclose()

    async def _stale_guard(self) -> None:
        """Offboard-plugin transport: stop MAVSDK's 20 Hz re-send once the shell stops refreshing."""
        while True:
            await asyncio.sleep(0.1)
            if self._plugin_streaming and time.monotonic() - self._last_sp_call > self.setpoint_stale_s:
                self._plugin_streaming = False
                if self._mode is FlightMode.OFFBOARD:
                    log.error("setpoints stale: stopping MAVSDK's offboard re-send (PX4 switches to HOLD)")
                    with contextlib.suppress(Exception):
                        await self._offboard.stop()

    def _push(self, sample: Any) -> None:
        self.telemetry.push(sample)

    def _push_status(self) -> None:
        self._push(
            VehicleStatus(
                time.monotonic(),
                self._armed,
                self._mode,
                self._landed,
                self._healthy,
                self._battery_pct,
                self._payload_released,
            )
        )

    def _open_tlog(self, open_sink: OpenPacketSink) -> None:
        tlog = self.tlog = open_sink(self._tlog_opened)
        self._tlog_opened = True
        packer = MavlinkPacker()  # used on the writer thread only

        def log_message(msg: Any) -> None:
            name, fields = msg.message_name.decode(), msg.fields_json.decode()
            sysid, compid = msg.system_id, msg.component_id
            tlog.write(lambda: packer.pack_json(name, fields, sysid, compid))

        for direction in ("incoming", "outgoing"):
            unhook = intercept_messages_json(self._mavsdk, direction, log_message)
            if unhook is None:
                where = getattr(tlog, "path", "the MAVLink log")
                log.warning("this MAVSDK build does not report %s messages: %s lacks them", direction, where)
            else:
                self._tlog_unhook.append(unhook)

    def _destroy(self) -> None:
        unhooks, self._tlog_unhook = self._tlog_unhook, []
        mavsdk, self._mavsdk = self._mavsdk, None
        if mavsdk is not None:
            for unhook in unhooks:
                with contextlib.suppress(Exception):
                    unhook()

            def destroy() -> None:
                with contextlib.suppress(Exception):
                    mavsdk.destroy()

            # Mavsdk.destroy() waits for native calls in flight; one the autopilot never answers
            # would block it (and the application) for good: give it destroy_timeout_s.
            t = threading.Thread(target=destroy, name="mavsdk-destroy", daemon=True)
            t.start()
            t.join(self.destroy_timeout_s)
            if t.is_alive():
                log.warning(
                    "MAVSDK did not shut down within %.1f s (%d unanswered call(s) still blocked in it); "
                    "left to the process exit",
                    self.destroy_timeout_s,
                    self.calls_unanswered,
                )
                self._leaked.append((mavsdk, unhooks))  # its C callbacks must outlive it
                return
        del unhooks  # the C callbacks may go once MAVSDK is gone
        tlog, self.tlog = self.tlog, None
        if tlog is not None:
            tlog.close()

    async def close(self) -> None:
        tasks, self._tasks = self._tasks, []
        for t in tasks:
            t.cancel()
        for t in tasks:
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await t
        self._system = None
        self._connected = False
        self._destroy()

    @property
    def heartbeat_age_s(self) -> float | None:
        return time.monotonic() - self._last_hb if math.isfinite(self._last_hb) else None

    @property
    def link_ok(self) -> bool:
        """Telemetry within ``link_timeout_s`` and MAVSDK connected; after a loss, only once a
        fresh HEARTBEAT (and so a fresh mode) has arrived."""
        if self._system is None:
            return False
        now = time.monotonic()
        fresh = self._connected and now - self._last_rx <= self.link_timeout_s
        return self._latch.check(now, fresh, self._last_hb)

    # ------------------------------------------------------------------ parameters and clock
    async def read_params(
        self, names: dict[str, Literal["int", "float"]], timeout_s: float = 5.0
    ) -> dict[str, float | Any]:
        """Parameters by name through MAVSDK's Param plugin (PX4 sends int32 parameters byte-wise;
        the plugin decodes them by their type). ``names`` maps each name to its PX4 type; a
        WRONG_TYPE answer is retried as the other type. Each value is a float, or a
        :class:`companion.autopilot.preflight.report.ParamUnavailable` with MAVSDK's reason."""
        from mavsdk.asyncio.plugins.param import ParamAsync
        from mavsdk.plugins.param import ParamError, ParamResult

        from companion.autopilot.preflight.report import ParamUnavailable

        if self._system is None:
            return {n: ParamUnavailable("not connected") for n in names}
        if self._param is None:
            self._param = ParamAsync(self._system)
        param = self._param
        out: dict[str, float | Any] = {}
        for name, kind in names.items():
            getters = [param.get_param_int, param.get_param_float]
            if kind == "float":
                getters.reverse()
            for i, get in enumerate(getters):
                try:
                    out[name] = float(await asyncio.wait_for(get(name), timeout_s))
                except TimeoutError:
                    self.calls_unanswered += 1
                    out[name] = ParamUnavailable(f"no answer within {timeout_s:g} s")
                except ParamError as err:
                    if err.result == ParamResult.WRONG_TYPE and i == 0:
                        continue
                    out[name] = ParamUnavailable(f"MAVSDK {err.result.name}")
                break
        return out

    async def system_time(self, timeout_s: float = 2.0) -> tuple[int, float] | None:
        """A fresh SYSTEM_TIME as ``(time_unix_usec, our wall clock at its arrival)``, requested
        with MAV_CMD_REQUEST_MESSAGE through MavlinkDirect; None without one within ``timeout_s``."""
        if self._system is None:
            return None
        loop = asyncio.get_running_loop()
        fut: asyncio.Future[tuple[int, float]] = loop.create_future()

        def on_time(m: Any) -> None:
            if m.system_id != self.system_id or fut.done():
                return
            try:
                usec = int(json.loads(m.fields_json)["time_unix_usec"])
            except (ValueError, TypeError, KeyError) as err:
                log.warning("SYSTEM_TIME not understood (%s): %s", err, m.fields_json)
                return
            fut.set_result((usec, time.time()))

        task = loop.create_task(self._consume(lambda: self._direct.subscribe_message("SYSTEM_TIME"), on_time))
        try:
            await asyncio.sleep(0.05)  # subscribed before the request goes out
            try:
                await self._direct_command("request SYSTEM_TIME", MAV_CMD_REQUEST_MESSAGE, 2)
            except CommandRejected as err:
                log.info("SYSTEM_TIME request: %s (waiting for the stream)", err)
            return await asyncio.wait_for(fut, timeout_s)
        except TimeoutError:
            return None
        finally:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError, Exception):
                await task

    # ------------------------------------------------------------------ commands
    async def _call(self, name: str, fn: Callable[[], Awaitable[Any]]) -> Any:
        """One MAVSDK call, bounded by ``command_timeout_s``; failures as :class:`CommandRejected`."""
        if self._system is None:
            raise CommandRejected(name, LINK_DOWN, "not connected")
        if not self.link_ok:
            raise CommandRejected(name, LINK_DOWN, "link is down")
        text_before = self._last_text
        try:
            return await asyncio.wait_for(fn(), self.command_timeout_s)
        except TimeoutError:
            # the native call goes on blocking a MAVSDK thread; we stop waiting for it
            self.calls_unanswered += 1
            raise CommandRejected(name, NO_ANSWER, f"no answer within {self.command_timeout_s:.1f} s") from None
        except Exception as err:  # MAVSDK's ActionError, OffboardError, ... (all MavsdkError)
            await asyncio.sleep(0.05)  # the STATUSTEXT with PX4's reason follows the ack
            reason = self._last_text if self._last_text != text_before else ""
            code = str(err).split(";", 1)[0].strip()
            result = _MAVSDK_RESULTS.get(code, code or type(err).__name__)
            raise CommandRejected(name, result, reason or str(err)) from None

    async def _direct_command(self, name: str, command: int, *params: float) -> None:
        """COMMAND_LONG through MavlinkDirect; returns on ACCEPTED, else :class:`CommandRejected`."""
        from mavsdk.asyncio.plugins.mavlink_direct import MavlinkMessage

        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        fields: dict[str, float] = {
            "target_system": self.system_id,
            "target_component": 1,
            "command": command,
            "confirmation": 0,
        }
        fields.update({f"param{i + 1}": v for i, v in enumerate(p)})
        msg = MavlinkMessage("COMMAND_LONG", 0, 0, self.system_id, 1, json.dumps(fields))
        text_before = self._last_text
        ack = await self._call(name, lambda: self._direct.send_command(msg))
        result = json.loads(ack.fields_json).get("result", -1) if ack.fields_json else -1
        if result != 0:
            await asyncio.sleep(0.05)  # PX4's STATUSTEXT with the reason follows the ack
            reason = self._last_text if self._last_text != text_before else ""
            raise CommandRejected(name, MAV_RESULT_NAMES.get(result, str(result)), reason)

    async def arm(self) -> None:
        if not self._armed and self._mode is not FlightMode.HOLD:
            # PX4 refuses to arm in the mode a landing leaves (OFFBOARD without setpoints,
            # AUTO.LAND) and in POSCTL without RC: arm in HOLD, then take off from there
            await self._direct_command(
                "arm (switch to HOLD first)",
                MAV_CMD_DO_SET_MODE,
                MAV_MODE_FLAG_CUSTOM_MODE_ENABLED,
                PX4_MAIN_AUTO,
                PX4_AUTO_LOITER,
            )
            self._mode = FlightMode.HOLD
        await self._call("arm", self._action.arm)

    async def disarm(self) -> None:
        await self._call("disarm", self._action.disarm)

    async def takeoff(self, alt_rel_m: float) -> None:
        await self._call("takeoff", lambda: self._action.set_takeoff_altitude(float(alt_rel_m)))
        await self._call("takeoff", self._action.takeoff)

    def set_velocity_ned(self, setpoint: VelocitySetpoint) -> None:
        if self._system is None or not self.link_ok:
            self.setpoints_dropped += 1
            return
        sp = setpoint
        try:
            if self.setpoint_transport == "offboard":
                from mavsdk.plugins.offboard import VelocityNedYaw

                self._offboard_sync.set_velocity_ned(
                    VelocityNedYaw(sp.north_m_s, sp.east_m_s, sp.down_m_s, math.degrees(sp.yaw_rad))
                )
                self._plugin_streaming = True
            else:
                from mavsdk.plugins.mavlink_direct import MavlinkMessage

                t_ms = int((time.monotonic() - self._t_boot) * 1000) & 0xFFFFFFFF
                fields = (
                    f'{{"time_boot_ms":{t_ms},"target_system":{self.system_id},"target_component":1,'
                    f'"coordinate_frame":{MAV_FRAME_LOCAL_NED},"type_mask":{VELOCITY_YAW_MASK},'
                    f'"x":0,"y":0,"z":0,"vx":{sp.north_m_s!r},"vy":{sp.east_m_s!r},"vz":{sp.down_m_s!r},'
                    f'"afx":0,"afy":0,"afz":0,"yaw":{sp.yaw_rad!r},"yaw_rate":0}}'
                )
                self._direct_sync.send_message(
                    MavlinkMessage("SET_POSITION_TARGET_LOCAL_NED", 0, 0, self.system_id, 1, fields)
                )
        except Exception as err:
            self.setpoints_dropped += 1
            log.debug("setpoint not sent: %s", err)
            return
        self._last_sp_call = time.monotonic()
        self.setpoints_sent += 1

    def set_attitude_target(self, target: AttitudeTarget) -> None:
        """One SET_ATTITUDE_TARGET through MavlinkDirect (offboard attitude): roll, pitch and
        heading as a quaternion, the yaw rate as feed-forward, thrust 0..1; body roll and pitch
        rates ignored. Non-blocking; dropped (and counted) without a link or with a non-finite value."""
        a = target
        vals = (a.roll_rad, a.pitch_rad, a.yaw_rad, a.yaw_rate_rad_s, a.thrust)
        if self._system is None or not self.link_ok or not all(math.isfinite(v) for v in vals):
            self.setpoints_dropped += 1
            return
        from mavsdk.plugins.mavlink_direct import MavlinkMessage

        q = [float(v) for v in euler_to_quat(a.roll_rad, a.pitch_rad, a.yaw_rad)]
        fields = {
            "time_boot_ms": int((time.monotonic() - self._t_boot) * 1000) & 0xFFFFFFFF,
            "target_system": self.system_id,
            "target_component": 1,
            "type_mask": ATTITUDE_TARGET_RATES_IGNORED,
            "q": q,
            "body_roll_rate": 0.0,
            "body_pitch_rate": 0.0,
            "body_yaw_rate": float(a.yaw_rate_rad_s),
            "thrust": min(1.0, max(0.0, float(a.thrust))),
        }
        try:
            self._direct_sync.send_message(
                MavlinkMessage("SET_ATTITUDE_TARGET", 0, 0, self.system_id, 1, json.dumps(fields))
            )
        except Exception as err:
            self.setpoints_dropped += 1
            log.debug("attitude setpoint not sent: %s", err)
            return
        self._last_sp_call = time.monotonic()
        self.setpoints_sent += 1

    async def start_offboard(self) -> None:
        if self.setpoint_transport == "offboard":
            await self._call("start_offboard", self._offboard.start)
            return
        base = MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | (MAV_MODE_FLAG_SAFETY_ARMED if self._armed else 0)
        await self._direct_command("start_offboard", MAV_CMD_DO_SET_MODE, base, PX4_MAIN_OFFBOARD, 0)

    async def hold(self) -> None:
        if self.setpoint_transport == "offboard" and self._plugin_streaming:
            self._plugin_streaming = False
            await self._call("hold", self._offboard.stop)  # stops the re-send and switches to HOLD
            return
        await self._call("hold", self._action.hold)

    async def land(self) -> None:
        await self._call("land", self._action.land)

    async def precision_land(self) -> None:
        """AUTO.PRECLAND (main mode AUTO = 4, sub mode PRECLAND = 9): PX4's precision landing,
        which needs LANDING_TARGET (landing.landing_target_output = "local_ned")."""
        await self._direct_command(
            "precision_land", MAV_CMD_DO_SET_MODE, MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | MAV_MODE_FLAG_SAFETY_ARMED, 4, 9
        )

    def send_landing_target(self, target: LandingTarget) -> None:
        """LANDING_TARGET through MAVSDK's MavlinkDirect. PX4 reads the position form
        (position_valid, MAV_FRAME_LOCAL_NED); time_usec is the exposure on the monotonic clock,
        which PX4 maps into its own through MAVSDK's TIMESYNC."""
        if self._system is None or not self.link_ok:
            return
        from mavsdk.plugins.mavlink_direct import MavlinkMessage

        t = target
        frame = MAV_FRAME_LOCAL_NED if t.position_valid else MAV_FRAME_BODY_FRD
        fields = json.dumps(
            {
                "time_usec": max(0, int(t.time_s * 1e6)),
                "target_num": 0,
                "frame": frame,
                "angle_x": t.angle_x_rad,
                "angle_y": t.angle_y_rad,
                "distance": t.distance_m,
                "size_x": t.size_x_rad,
                "size_y": t.size_y_rad,
                "x": t.north_m,
                "y": t.east_m,
                "z": t.down_m,
                "q": [1.0, 0.0, 0.0, 0.0],
                "type": LANDING_TARGET_TYPE_VISION_FIDUCIAL,
                "position_valid": int(t.position_valid),
            }
        )
        try:
            self._direct_sync.send_message(MavlinkMessage("LANDING_TARGET", 0, 0, self.system_id, 1, fields))
        except Exception as err:
            raise AutopilotError(f"LANDING_TARGET not sent: {err}") from err

    async def release_payload(self) -> None:
        """Release the parcel (``release``: gripper, servo or actuator; see the module doc). PX4
        gives no feedback beyond the COMMAND_ACK, so ACCEPTED counts as released."""
        if self.release == "gripper":
            await self._direct_command(
                "release (gripper)", MAV_CMD_DO_GRIPPER, self.gripper_instance, GRIPPER_ACTION_RELEASE
            )
        elif self.release == "actuator":
            # DO_SET_ACTUATOR with NaN for the other sets (left unchanged): MavlinkDirect's JSON
            # cannot carry a NaN, MAVSDK's Action.set_actuator sends exactly this command
            await self._call(
                "release (actuator)",
                lambda: self._action.set_actuator(self.release_actuator, self.release_actuator_value),
            )
        else:
            await self._direct_command("release (servo)", MAV_CMD_DO_SET_SERVO, self.release_servo, self.release_pwm)
        self._payload_released = True
        self._push_status()

"""The MAVLink sim vehicle's base class (:class:`MavlinkSimVehicle`): its configuration and the
dispatch of what it receives; the dialects subclass it (:mod:`companion_sitl.mavlink.px4`,
:mod:`companion_sitl.mavlink.ardupilot`) and :mod:`companion_sitl.mavlink.factory` picks one."""

from __future__ import annotations

import abc
import math
import os
import threading
from typing import Any, ClassVar, Literal

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.autopilot.signing import clock_timestamp
from companion.autopilot.types import FlightMode
from companion.geometry.earth import GeoPoint, LocalTangentPlane
from companion_sitl.mavlink.commands import CommandHandler
from companion_sitl.mavlink.fence import FenceServer
from companion_sitl.mavlink.link import LinkStats, PacketWriter
from companion_sitl.mavlink.mission import MissionServer
from companion_sitl.params import SimConfig
from companion_sitl.vehicle import SimVehicle

Dialect = Literal["px4", "ardupilot"]


class MavlinkSimVehicle(MissionServer, FenceServer, CommandHandler):
    """A :class:`SimVehicle` behind a real MAVLink 2 UDP endpoint, stepped in real time.

    ``bind`` is the vehicle's own address (port 0 picks a free one; see :attr:`address`).
    ``remote`` is where it sends before anyone has spoken to it (a companion listening with
    ``udpin``). ``unsupported_messages``: message ids SET_MESSAGE_INTERVAL answers UNSUPPORTED
    for (an autopilot without them, e.g. no HIGHRES_IMU). Use as a context manager or call
    :meth:`start` / :meth:`stop`.

    The dialect's subclass (:class:`~companion_sitl.mavlink.px4.Px4SimVehicle`,
    :class:`~companion_sitl.mavlink.ardupilot.ArduPilotSimVehicle`) fills in the hooks;
    :func:`~companion_sitl.mavlink.factory.mavlink_sim_vehicle` builds the one named.
    """

    dialect: Dialect
    OFFBOARD_LOSS_MODE: ClassVar[FlightMode] = FlightMode.HOLD  # where the offboard-loss failsafe goes
    BOOT_MODE: ClassVar[FlightMode | None] = None  # the autopilot's mode at boot (None: the vehicle's)

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
        route_peers: bool = False,
        unsupported_messages: frozenset[int] = frozenset(),
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
        # pass what one peer sends, unless addressed to the vehicle itself, to the others (the
        # firmware's routing between its links: a GCS peer sees the companion's component)
        self.route_peers = route_peers
        self.unsupported_messages = frozenset(unsupported_messages)
        self._rx_addr: tuple[str, int] | None = None
        self.release_servo = release_servo
        self.release_pwm = release_pwm
        self.lock = threading.RLock()  # held while the vehicle is stepped or commanded
        self._bind = bind
        self._sock = None
        self._thread = None
        self._running = False
        self._link_up = True
        self._t0 = 0.0
        self._enc = mavlink.MAVLink(PacketWriter(), srcSystem=system_id, srcComponent=self.component_id)
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
        self._streams = {}
        for mid, hz in (stream_rates_hz or self.DEFAULT_STREAMS_HZ).items():
            self._streams[mid] = [1.0 / hz, 0.0]
        self._texts_sent = 0
        self._home_sent = None
        self._rc = [1500, 1500, 1000, 1500, 1100, 1100, 1100, 1100] + [0] * 10
        self._rc_override_at = -math.inf
        # RC input: the pilot's transmitter, the overrides in force (per channel, with
        # their time) and, in ``_rc``, what the autopilot flies on and reports in RC_CHANNELS
        self._radio = list(self._rc)
        self._ovr = [None] * 18
        self._ovr_at = [-math.inf] * 18
        # RC_OVERRIDE_TIME; < 0: never lapses
        self.rc_override_timeout_s = (
            self.RC_OVERRIDE_TIMEOUT_S if rc_override_timeout_s is None else rc_override_timeout_s
        )
        self.clock_offset_s = clock_offset_s  # added to the UTC this vehicle reports (SYSTEM_TIME)
        self._params = self._default_params(cfg, system_id, guided_timeout_s)
        self._params.update(params or {})  # the vehicle's own configuration (e.g. GRIP_ENABLE = 1)
        if self.BOOT_MODE is not None and not self.vehicle.armed:
            self.vehicle.mode = self.BOOT_MODE
        self._ltp = LocalTangentPlane(GeoPoint(cfg.home.lat_deg, cfg.home.lon_deg, cfg.home.alt_amsl_m))
        self.on_message = None  # test hook: every decoded message

    # ------------------------------------------------------------------ dialect hooks
    def _vehicle_config(self, cfg: SimConfig, guided_timeout_s: float, ekf_delay_s: float | None) -> SimConfig:
        """The configuration of the vehicle the dialect builds when none is handed in."""
        return cfg

    @abc.abstractmethod
    def _default_params(self, cfg: SimConfig, system_id: int, guided_timeout_s: float) -> dict[str, float]: ...

    @abc.abstractmethod
    def _pilot_mode(self, mode: FlightMode) -> None: ...

    def _heartbeat_in(self, m: Any) -> None:
        """A peer's HEARTBEAT (a GCS, a companion): what the dialect's failsafes watch."""
        return None  # optional hook: this dialect watches no peer's heartbeat

    # ------------------------------------------------------------------ pilot hooks
    def pilot_set_mode(self, mode: FlightMode) -> None:
        """The pilot flips the mode switch on the vehicle side (thread-safe)."""
        with self.lock:
            self.vehicle.step_to(self.now)
            self._pilot_mode(mode)

    # ------------------------------------------------------------------ receiving
    def _handle(self, m: Any) -> None:
        t = m.get_type()
        if t == "HEARTBEAT":
            self._heartbeat_in(m)
            return
        if (
            t.startswith("MISSION_")
            and m.target_system in (0, self.system_id)
            and (self._fence_message(m) or self._mission_message(m))
        ):
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
            self._param_request_list()
            return
        if t == "PARAM_REQUEST_READ":
            self._param_request_read(m)
            return
        if t == "PARAM_SET":
            self._param_set(m)
            return
        if t == "MISSION_REQUEST_LIST":
            self._send(self._enc.mission_count_encode(m.get_srcSystem(), m.get_srcComponent(), 0, m.mission_type))
            return
        if t == "TIMESYNC" and m.tc1 == 0:
            self._send(self._enc.timesync_encode(int(self.now * 1e9), m.ts1))
            return

"""The MAVSDK session with PX4: ``Mavsdk(Configuration(companion computer))``,
``add_any_connection(url)``, ``first_autopilot(timeout_s)``, then plugins built explicitly from
the system: Action, Telemetry, Offboard and MavlinkDirect.

Link watchdog: MAVSDK's connection state (3 s heartbeat timeout) and the arrival of telemetry
(``link_timeout_s``). A native call the autopilot never answers would block ``Mavsdk.destroy()``
and the application behind it, so :meth:`Px4Link.close` destroys MAVSDK on a daemon thread with a
time limit.

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

import abc
import asyncio
import contextlib
import logging
import math
import threading
import time
from collections.abc import Callable
from typing import Any, Literal

from companion.autopilot.interface import (
    AutopilotError,
    AutopilotUnreachable,
    LinkLatch,
    LinkTraffic,
    OpenPacketSink,
    PacketSink,
    TelemetryCache,
)
from companion.autopilot.liveness import LoopLiveness
from companion.autopilot.px4.mavsdk_core import (
    InterceptCounters,
    check_connection_url,
    collect_connect_problems,
    intercept_messages_json,
    message_logger,
    route_mavsdk_log,
)
from companion.autopilot.timesync import ClockOffsetEstimator
from companion.autopilot.types import (
    FlightMode,
    LandedState,
)

log = logging.getLogger(__name__)

# what MAVSDK may send only while the control loop is alive (companion.autopilot.liveness)
LOOP_GATED_MESSAGES = frozenset({b"HEARTBEAT", b"SET_POSITION_TARGET_LOCAL_NED", b"SET_ATTITUDE_TARGET"})


class Px4Link(abc.ABC):
    """MAVSDK, the plugins and the link state of :class:`Px4Autopilot`; the telemetry streams and
    the requests are in its subclasses (:mod:`.telemetry`, :mod:`.requests`)."""

    # the state every part shares, set by Px4Autopilot.__init__
    connection: str
    link_timeout_s: float
    setpoint_transport: Literal["direct", "offboard"]
    setpoint_stale_s: float
    command_timeout_s: float
    destroy_timeout_s: float
    streams_restarted: int
    decode_errors: int
    calls_unanswered: int
    telemetry: TelemetryCache
    system_id: int
    component_system_id: int
    component_id: int
    open_tlog: OpenPacketSink | None
    tlog: PacketSink | None
    _tlog_opened: bool
    _tlog_unhook: list[Callable[[], None]]
    intercept_counters: InterceptCounters
    _mavsdk: Any
    _system: Any
    _action: Any
    _tel: Any
    _offboard: Any
    _direct: Any
    _direct_sync: Any
    _param: Any
    _offboard_sync: Any
    _tasks: list[asyncio.Task[None]]
    timesync: ClockOffsetEstimator | None
    timesync_period_s: float
    _timesync_logged: int
    _leaked: list[Any]
    _connected: bool
    _last_rx: float
    _last_hb: float
    _latch: LinkLatch
    _last_sp_call: float
    _plugin_streaming: bool
    _armed: bool
    _mode: FlightMode
    _landed: LandedState
    _healthy: bool
    _battery_pct: float
    _payload_released: bool
    _rates: tuple[float, float, float]
    _gps_fix: int
    _gps_sats: int
    _last_text: str
    _texts_seen: int  # a repeated text is a new one too
    _health: Any
    liveness: LoopLiveness
    foreign_heartbeats: int

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
        mavsdk_config = Configuration.create_with_component_type(ComponentType.COMPANION_COMPUTER)
        mavsdk_config.system_id = self.component_system_id
        mavsdk_config.component_id = self.component_id
        self._mavsdk = Mavsdk(mavsdk_config)
        self._gate_outgoing()
        if self.open_tlog is not None:
            try:
                self._open_tlog(self.open_tlog)
            except OSError as err:
                self._destroy()
                raise AutopilotError(str(err)) from None
        with collect_connect_problems() as problems:
            # until MAVSDK is up or destroyed: its retries' complaints go into the error, not stderr
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

    def _gate_outgoing(self) -> None:
        """MAVSDK sends the component's heartbeat and (offboard plugin) re-sends the setpoint from
        its own threads: both leave only while the control loop is alive (:attr:`liveness`)."""
        gate = self.liveness

        def keep(msg: Any) -> bool:  # MAVSDK's thread, or the sender's
            return msg.message_name not in LOOP_GATED_MESSAGES or gate.may_send()

        unhook = intercept_messages_json(self._mavsdk, "outgoing", keep, self.intercept_counters)
        if unhook is None:
            log.warning("this MAVSDK build cannot hold back its heartbeat: a hung control loop still looks alive")
        else:
            self._tlog_unhook.append(unhook)

    def _open_tlog(self, open_sink: OpenPacketSink) -> None:
        tlog = self.tlog = open_sink(self._tlog_opened)
        self._tlog_opened = True
        log_message = message_logger(tlog)
        for direction in ("incoming", "outgoing"):
            unhook = intercept_messages_json(self._mavsdk, direction, log_message, self.intercept_counters)
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
        self.close_component()
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

    def link_traffic(self) -> LinkTraffic:
        """The serial line's baud as the URL gives it (none given: unknown, no budget); MAVSDK
        counts no bytes we can read."""
        scheme, _, rest = self.connection.strip().partition("://")
        if scheme != "serial":
            return LinkTraffic(None)
        tail = rest.rsplit(":", 1)[-1]
        return LinkTraffic(int(tail) if tail.isdigit() and ":" in rest else None)

    @property
    def link_ok(self) -> bool:
        """Telemetry within ``link_timeout_s`` and MAVSDK connected; after a loss, only once a
        fresh HEARTBEAT (and so a fresh mode) has arrived."""
        if self._system is None:
            return False
        now = time.monotonic()
        fresh = self._connected and now - self._last_rx <= self.link_timeout_s
        return self._latch.check(now, fresh, self._last_hb)

    def close_component(self) -> None:
        """Stop handing over the companion component's commands (:mod:`.component`)."""
        return None  # no component open: nothing to stop

    @abc.abstractmethod
    def _start_streams(self) -> None:
        """Subscribe to the telemetry streams (:class:`~.telemetry.Px4Telemetry`)."""

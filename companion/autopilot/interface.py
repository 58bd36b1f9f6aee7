"""The ``Autopilot`` interface: what the mission shell needs from a flight controller.

Implemented by the embedded simulator (``companion_sitl``), the PX4/MAVSDK backend and the
ArduPilot/pymavlink backend, so the application cannot tell them apart.
"""

from __future__ import annotations

import abc
import enum
import logging
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Protocol

from companion.autopilot.component import ComponentCommand
from companion.autopilot.external_nav import ExternalNavPose
from companion.autopilot.fence import AutopilotFence
from companion.autopilot.liveness import INERT_LIVENESS, LoopLiveness
from companion.autopilot.mission_plan import PlanItem
from companion.autopilot.timesync import ClockOffset
from companion.autopilot.types import (
    Attitude,
    GlobalPosition,
    GpsRaw,
    HomePosition,
    Imu,
    LandingTarget,
    PositionNed,
    RangefinderReading,
    StatusText,
    TelemetrySample,
    VehicleStatus,
    Wind,
)
from companion.autopilot.winch import WinchCommand, WinchStatus
from companion.guidance.setpoint import VelocitySetpoint

log = logging.getLogger(__name__)


PacketSource = bytes | bytearray | Callable[[], bytes | bytearray | None]


class PacketSink(Protocol):
    """Where a backend hands every MAVLink packet of its link, sent and received (the flight's
    ``.tlog``, :class:`companion.flightlog.tlog_writer.TlogWriter`). ``write`` is called from the link's
    threads and must not block (a callable packet is encoded by the sink, off the link's path);
    ``close`` flushes and closes."""

    def write(self, packet: PacketSource, t_unix_s: float | None = None) -> bool: ...

    def close(self) -> None: ...


OpenPacketSink = Callable[[bool], PacketSink]
"""Opens the packet sink when the link connects; the argument is True on a reconnect (append)."""


class AutopilotError(RuntimeError):
    """A command was refused, timed out, or the link is unusable."""


class ConnectionUrlError(AutopilotError):
    """The connection setting is malformed (unknown scheme, no port): a configuration error."""


def check_port(url: str, port: str) -> int:
    """The port of a network connection URL as a number in 1-65535, or a :class:`ConnectionUrlError`."""
    if not port.isdigit() or not 1 <= int(port) <= 65535:
        raise ConnectionUrlError(f"connection {url!r}: port {port!r} is not a number in 1-65535")
    return int(port)


class LinkDeviceMissing(AutopilotError):
    """The serial device the connection names does not exist (unplugged, wrong path)."""


class AutopilotUnreachable(AutopilotError):
    """The link could not be opened (refused, address unusable) or no autopilot answered on it
    within the connect timeout."""


class CommandResult(enum.Enum):
    """How a command ended without ACCEPTED: a MAV_RESULT (MAVLink common.xml, by its name
    without the prefix), or one of the two outcomes that carry no COMMAND_ACK."""

    TEMPORARILY_REJECTED = "TEMPORARILY_REJECTED"
    DENIED = "DENIED"
    UNSUPPORTED = "UNSUPPORTED"
    FAILED = "FAILED"
    IN_PROGRESS = "IN_PROGRESS"
    CANCELLED = "CANCELLED"
    COMMAND_LONG_ONLY = "COMMAND_LONG_ONLY"
    COMMAND_INT_ONLY = "COMMAND_INT_ONLY"
    COMMAND_UNSUPPORTED_MAV_FRAME = "COMMAND_UNSUPPORTED_MAV_FRAME"
    NO_ANSWER = "NO_ANSWER"  # no COMMAND_ACK at all (PX4 ignores commands no module handles)
    LOST = "LOST"  # no COMMAND_ACK while the link lost or garbled messages: worth sending again
    LINK_DOWN = "LINK_DOWN"
    OTHER = "OTHER"  # an answer of no kind above (a MAV_RESULT number beyond common.xml, ...)


NO_ANSWER = CommandResult.NO_ANSWER.value
LINK_DOWN = CommandResult.LINK_DOWN.value
# Results that will not change by sending the same command again: the autopilot lacks the
# feature (UNSUPPORTED), its configuration or state forbids it (DENIED), the action itself failed
# (FAILED: e.g. ArduCopter's DO_GRIPPER with GRIP_ENABLE = 0), or nothing handles it (NO_ANSWER:
# silence on a clean link; silence on a link seen losing messages is LOST, and retried).
PERMANENT_RESULTS = frozenset(
    {CommandResult.UNSUPPORTED, CommandResult.DENIED, CommandResult.FAILED, CommandResult.NO_ANSWER}
)


class CommandRejected(AutopilotError):
    """A command ended without ACCEPTED. ``kind`` is how (:class:`CommandResult`: decide on it);
    ``result`` its name as the backend gave it (``"DENIED"``, ``"NO_ANSWER"``, or an unknown
    answer's own words, for messages); ``reason`` the autopilot's STATUSTEXT that came with it."""

    def __init__(self, command: str, result: CommandResult | str, reason: str = ""):
        self.command = command
        if isinstance(result, CommandResult):
            self.kind, self.result = result, result.value
        else:  # a name, from the wire: parsed once, here
            self.kind, self.result = CommandResult.__members__.get(result, CommandResult.OTHER), result
        self.reason = reason
        super().__init__(f"{command}: {self.result}" + (f" ({reason})" if reason else ""))

    @property
    def permanent(self) -> bool:
        """Sending the same command again will get the same answer (see :data:`PERMANENT_RESULTS`)."""
        return self.kind in PERMANENT_RESULTS


@dataclass(frozen=True, slots=True)
class RcInput:
    """RC channels as the autopilot reports them (MAVLink RC_CHANNELS), microseconds, index 0 =
    channel 1; 0 = no value. ``time_s``: receipt on the shell's monotonic clock. ArduPilot
    reports a channel *after* RC_CHANNELS_OVERRIDE is applied, PX4 the receiver's raw value."""

    time_s: float
    channels_us: tuple[int, ...]

    def validate(self) -> RcInput:
        if not math.isfinite(self.time_s):
            raise ValueError(f"RcInput.time_s is not finite ({self.time_s})")
        if len(self.channels_us) > 18 or any(not 0 <= int(v) <= 65535 for v in self.channels_us):
            raise ValueError(f"RcInput.channels_us out of range: {self.channels_us}")
        return self


@dataclass(frozen=True, slots=True)
class AttitudeTarget:
    """An attitude setpoint (SET_ATTITUDE_TARGET): roll/pitch (FRD, +pitch nose up) and heading
    in NED, the yaw rate as feed-forward, collective thrust 0..1."""

    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    yaw_rate_rad_s: float
    thrust: float


class LinkLatch:
    """Link-state latch shared by the MAVLink backends.

    Each backend decides whether its link is *fresh* (its own rule: heartbeats, telemetry). Once
    the link has been lost it counts as up again only after a heartbeat newer than the loss, so
    the mode the mission sees on reconnect is current (a stale mode would look like a pilot
    takeover).
    """

    def __init__(self) -> None:
        self._lost_at: float | None = None

    def check(self, now_s: float, fresh: bool, last_heartbeat_s: float) -> bool:
        if not fresh:
            if self._lost_at is None:
                self._lost_at = now_s
            return False
        if self._lost_at is not None:
            if last_heartbeat_s <= self._lost_at:
                return False
            self._lost_at = None
        return True


class TelemetryCache:
    """The newest valid sample of each kind, plus counters of what was rejected.

    Backends call :meth:`push`; a sample with a non-finite field is rejected and counted, never
    stored, so one bad message cannot poison the estimate. Listeners are called synchronously
    with every accepted sample (used by flight logs and telemetry publishers; keep them cheap).
    """

    def __init__(self) -> None:
        self.position_ned: PositionNed | None = None
        self.global_position: GlobalPosition | None = None
        self.attitude: Attitude | None = None
        self.imu: Imu | None = None
        self.gps: GpsRaw | None = None
        self.status: VehicleStatus | None = None
        self.home: HomePosition | None = None
        self.last_status_text: StatusText | None = None
        self.received: dict[str, int] = {}
        self.rejected: dict[str, int] = {}
        self.last_rejection: str = ""
        self.rc_input: RcInput | None = None
        self.wind: Wind | None = None  # the autopilot's wind estimate, when asked for (push_wind)
        self.winch: WinchStatus | None = None  # the winch's newest report (push_winch), where one is fitted
        # the newest downward DISTANCE_SENSOR (push_rangefinder), when asked for ([mission.rangefinder])
        self.rangefinder: RangefinderReading | None = None
        self._listeners: list[Callable[[TelemetrySample], None]] = []
        self._rc_listeners: list[Callable[[RcInput], None]] = []

    def add_listener(self, fn: Callable[[TelemetrySample], None]) -> None:
        self._listeners.append(fn)

    @property
    def listeners(self) -> tuple[Callable[[TelemetrySample], None], ...]:
        """The sample listeners, in the order a valid sample is handed to them (a copy)."""
        return tuple(self._listeners)

    def remove_listener(self, fn: Callable[[TelemetrySample], None]) -> None:
        if fn in self._listeners:
            self._listeners.remove(fn)

    def add_rc_listener(self, fn: Callable[[RcInput], None]) -> None:
        self._rc_listeners.append(fn)

    def remove_rc_listener(self, fn: Callable[[RcInput], None]) -> None:
        if fn in self._rc_listeners:
            self._rc_listeners.remove(fn)

    def push_rc(self, rc: RcInput) -> bool:
        """Store the newest RC channels (rejected and counted when malformed); RC listeners are
        called synchronously (the Dart mixer reacts to the pilot's switch at once)."""
        try:
            rc.validate()
        except (ValueError, TypeError) as err:
            self.rejected["RcInput"] = self.rejected.get("RcInput", 0) + 1
            self.last_rejection = str(err)
            return False
        self.received["RcInput"] = self.received.get("RcInput", 0) + 1
        self.rc_input = rc
        for fn in self._rc_listeners:
            fn(rc)
        return True

    def push_wind(self, wind: Wind) -> bool:
        """Store the autopilot's newest wind estimate (rejected and counted when not finite). Kept
        apart from :meth:`push`: no listener (log, telemetry) sees it."""
        try:
            wind.validate()
        except ValueError as err:
            self.rejected["Wind"] = self.rejected.get("Wind", 0) + 1
            self.last_rejection = str(err)
            return False
        self.wind = wind
        return True

    def push_winch(self, status: WinchStatus) -> bool:
        """Store the winch's newest report (rejected and counted when not finite); no listener sees it."""
        try:
            status.validate()
        except ValueError as err:
            self.rejected["WinchStatus"] = self.rejected.get("WinchStatus", 0) + 1
            self.last_rejection = str(err)
            return False
        self.received["WinchStatus"] = self.received.get("WinchStatus", 0) + 1
        self.winch = status
        return True

    def push_rangefinder(self, reading: RangefinderReading) -> bool:
        """Store the newest downward rangefinder reading (rejected and counted when not finite or
        not looking down: a forward sensor's range is no height); no listener sees it."""
        try:
            reading.validate()
            if not reading.downward:
                raise ValueError(f"RangefinderReading.orientation {reading.orientation} is not downward (25)")
        except ValueError as err:
            self.rejected["RangefinderReading"] = self.rejected.get("RangefinderReading", 0) + 1
            self.last_rejection = str(err)
            return False
        self.received["RangefinderReading"] = self.received.get("RangefinderReading", 0) + 1
        self.rangefinder = reading
        return True

    def push(self, sample: TelemetrySample) -> bool:
        kind = type(sample).__name__
        try:
            if not isinstance(sample, StatusText):
                sample.validate()
        except ValueError as err:
            self.rejected[kind] = self.rejected.get(kind, 0) + 1
            self.last_rejection = str(err)
            if self.rejected[kind] in (1, 10, 100, 1000):
                log.warning("rejected telemetry (%d %s so far): %s", self.rejected[kind], kind, err)
            return False
        self.received[kind] = self.received.get(kind, 0) + 1
        match sample:
            case PositionNed():
                self.position_ned = sample
            case GlobalPosition():
                self.global_position = sample
            case Attitude():
                self.attitude = sample
            case Imu():
                self.imu = sample
            case GpsRaw():
                self.gps = sample
            case VehicleStatus():
                self.status = sample
            case HomePosition():
                self.home = sample
            case StatusText():
                self.last_status_text = sample
        for fn in self._listeners:
            fn(sample)
        return True


@dataclass(frozen=True, slots=True)
class LinkTraffic:
    """The link's line and the bytes over it so far: ``baud`` of a serial line (None on UDP or
    TCP, which have no budget worth stating); the byte counts None where the backend cannot
    count them (MAVSDK keeps its link to itself)."""

    baud: int | None
    rx_bytes: int | None = None
    tx_bytes: int | None = None


class Autopilot(abc.ABC):
    """Async interface to one vehicle's flight controller.

    All methods raise :class:`AutopilotError` on refusal, timeout or a dead link. Telemetry
    arrives in :attr:`telemetry` as the backend receives it.
    """

    telemetry: TelemetryCache
    #: the control loop's liveness (:mod:`companion.autopilot.liveness`): the shell renews it each
    #: guidance tick; a backend sends heartbeats and setpoints only while it is alive. Backends that
    #: send from threads of their own have a gate of their own; the default is inert (always open).
    liveness: LoopLiveness = INERT_LIVENESS

    @abc.abstractmethod
    async def connect(self, timeout_s: float = 10.0) -> None:
        """Open the link and wait for the first heartbeat."""

    @abc.abstractmethod
    async def close(self) -> None:
        """Stop streams and release the link; safe to call twice."""

    @property
    @abc.abstractmethod
    def link_ok(self) -> bool:
        """A heartbeat arrived within the link timeout."""

    @property
    def clock_offset(self) -> ClockOffset | None:
        """The autopilot's boot clock against the companion's monotonic clock (offset, jitter,
        round trips; :mod:`companion.autopilot.timesync`, docs/clock.md), None when this backend
        does not estimate it (``runtime.autopilot_timesync_hz = 0``, or too few exchanges answered
        yet). PX4: our own exchanges through MavlinkDirect (MAVSDK's timesync is internal to it)."""
        return None

    @property
    def heartbeat_age_s(self) -> float | None:
        """Seconds since the autopilot's last HEARTBEAT; None before the first one, or for a
        backend without heartbeats (the embedded simulator)."""
        return None

    def link_traffic(self) -> LinkTraffic:
        """The line the link runs on and the bytes it carried (for the pre-flight link budget)."""
        return LinkTraffic(None)

    @abc.abstractmethod
    async def arm(self) -> None: ...

    @abc.abstractmethod
    async def disarm(self) -> None: ...

    @abc.abstractmethod
    async def takeoff(self, alt_rel_m: float) -> None:
        """Switch to the autopilot's takeoff mode climbing to ``alt_rel_m`` above home."""

    @abc.abstractmethod
    def set_velocity_ned(self, setpoint: VelocitySetpoint) -> None:
        """Send one velocity setpoint now; non-blocking (called at the setpoint-stream rate)."""

    @abc.abstractmethod
    async def start_offboard(self) -> None:
        """Enter companion control (PX4 OFFBOARD / ArduPilot GUIDED).

        PX4 refuses unless setpoints have been streaming; callers stream first.
        """

    @abc.abstractmethod
    async def hold(self) -> None:
        """Switch to the autopilot's position hold."""

    @abc.abstractmethod
    async def land(self) -> None:
        """Switch to the autopilot's LAND mode (it disarms after touchdown)."""

    @abc.abstractmethod
    async def release_payload(self) -> None:
        """Open the gripper / move the release servo."""

    async def winch(self, command: WinchCommand) -> None:
        """One MAV_CMD_DO_WINCH (companion.autopilot.winch); its line length arrives in
        ``telemetry.winch``. Backends without a winch raise :class:`AutopilotError`."""
        raise AutopilotError(f"{type(self).__name__} cannot operate a winch")

    # Optional capabilities of the Dart cyber-pilot (hybrid mixer). A backend without them
    # raises AutopilotError; RC channels, where reported, arrive in ``telemetry.rc_input``.
    def send_rc_override(self, channels: Sequence[int]) -> None:
        """One RC_CHANNELS_OVERRIDE now (index 0 = channel 1; 0 releases channels 1-8 and
        UINT16_MAX-1 channels 9-18, UINT16_MAX leaves a channel alone); non-blocking."""
        raise AutopilotError(f"{type(self).__name__} cannot override RC channels")

    def set_attitude_target(self, target: AttitudeTarget) -> None:
        """One attitude setpoint now (offboard attitude control); non-blocking."""
        raise AutopilotError(f"{type(self).__name__} cannot take attitude setpoints")

    # Optional interop: the autopilot's own precision landing fed with our pad observations.
    def send_landing_target(self, target: LandingTarget) -> None:
        """One LANDING_TARGET now (see companion.autopilot.landing_target); non-blocking."""
        raise AutopilotError(f"{type(self).__name__} cannot send LANDING_TARGET")

    async def precision_land(self) -> None:
        """Hand the descent to the autopilot's own precision landing (PX4 AUTO.PRECLAND,
        ArduPilot LAND with PLND enabled). Backends without one fall back to plain LAND."""
        await self.land()

    # Optional: external navigation (companion.autopilot.external_nav, docs/external-nav.md).
    def send_external_nav(self, pose: ExternalNavPose) -> None:
        """One external-navigation pose now (ArduPilot: VISION_POSITION_ESTIMATE); non-blocking."""
        raise AutopilotError(f"{type(self).__name__} cannot take an external-navigation pose")

    async def use_external_nav(self, source_set: int) -> None:
        """Switch the autopilot's position source to the external pose (ArduPilot: EKF source set
        ``source_set``); raises :class:`AutopilotError` when refused or not possible."""
        raise AutopilotError(f"{type(self).__name__} cannot switch its position source to external navigation")

    def external_nav_source_name(self, source_set: int) -> str:
        """What navigates on the external pose once GNSS is lost, for the operator's events."""
        return f"EKF source set {source_set}"

    async def use_gnss(self) -> None:
        """Switch the autopilot's position source back to GNSS (ArduPilot: EKF source set 1)."""
        raise AutopilotError(f"{type(self).__name__} cannot switch its position source back to GNSS")

    # The autopilot's own fence (companion.autopilot.fence; MAVLink fence protocol).
    async def upload_fence(self, fence: AutopilotFence) -> None:
        """Replace the autopilot's fence with ``fence`` (raises :class:`AutopilotError`)."""
        raise AutopilotError(f"{type(self).__name__} cannot upload a fence")

    async def download_fence(self) -> AutopilotFence:
        """The fence the autopilot holds (raises :class:`AutopilotError`)."""
        raise AutopilotError(f"{type(self).__name__} cannot download a fence")

    # The operator's mission (companion.autopilot.mission_plan; MAVLink mission protocol).
    async def download_mission(self) -> tuple[PlanItem, ...]:
        """The mission the autopilot holds (mission_type 0), numbered as a GCS shows it; ArduPilot's
        home item is left out (raises :class:`AutopilotError`)."""
        raise AutopilotError(f"{type(self).__name__} cannot download a mission")

    # Optional: the companion as a MAVLink component of its own (companion.autopilot.component,
    # docs/gcs.md). A backend without it raises AutopilotError from open_component.
    def open_component(
        self, component_id: int, system_id: int, on_command: Callable[[ComponentCommand], None]
    ) -> tuple[int, int]:
        """Start speaking as the companion's component once connected: its heartbeat, and every
        COMMAND_LONG addressed to it handed to ``on_command`` on the event loop. ``system_id`` 0:
        the vehicle's. Returns the (system id, component id) it speaks with."""
        raise AutopilotError(f"{type(self).__name__} cannot speak as a MAVLink component of its own")

    def send_from_component(self, name: str, fields: dict[str, Any]) -> bool:
        """Send one message (MAVLink name, fields by name; arrays as lists, strings as str) from
        the companion's component; non-blocking; False when it could not go out."""
        return False

    def close_component(self) -> None:
        """Stop the component's heartbeat and command hand-over (safe without open_component)."""
        return None

    # Optional: delivery after delivery (docs/flying.md). The embedded simulator needs neither.
    async def make_ready(self) -> str | None:
        """Disarmed on the ground in a mode the autopilot refuses to arm in (PX4 leaves OFFBOARD
        after a companion-flown landing): switch to one it arms in, so the next mission (or the
        pilot) can start. Returns what was done, None when nothing was needed."""
        return None

    def not_ready_reason(self) -> str:
        """Why the autopilot does not report itself ready to arm, in its own words where it gave
        them (its health flags, its mode, its last STATUSTEXT); "" when nothing is known."""
        st = self.telemetry.last_status_text
        return f'last autopilot message: "{st.text}"' if st is not None else ""

"""The ``Autopilot`` interface: what the mission shell needs from a flight controller.

Implemented by the embedded simulator (``companion_sitl``), the PX4/MAVSDK backend and the
ArduPilot/pymavlink backend, so the application cannot tell them apart.
"""

from __future__ import annotations

import abc
import logging
from collections.abc import Callable

from companion.autopilot.types import (
    Attitude,
    GlobalPosition,
    GpsRaw,
    HomePosition,
    Imu,
    PositionNed,
    StatusText,
    TelemetrySample,
    VehicleStatus,
    VelocitySetpoint,
)

log = logging.getLogger(__name__)


class AutopilotError(RuntimeError):
    """A command was refused, timed out, or the link is unusable."""


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
        self._listeners: list[Callable[[TelemetrySample], None]] = []

    def add_listener(self, fn: Callable[[TelemetrySample], None]) -> None:
        self._listeners.append(fn)

    def remove_listener(self, fn: Callable[[TelemetrySample], None]) -> None:
        if fn in self._listeners:
            self._listeners.remove(fn)

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


class Autopilot(abc.ABC):
    """Async interface to one vehicle's flight controller.

    All methods raise :class:`AutopilotError` on refusal, timeout or a dead link. Telemetry
    arrives in :attr:`telemetry` as the backend receives it.
    """

    telemetry: TelemetryCache

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

"""Who watches the delivery shell: one protocol, :class:`ShellObserver`, that the flight log, the
recorder, the telemetry, the operator's GCS, a terminal display and the benches implement, and
the shell calls on its loop thread in the order they were added. Every method is a no-op here:
an observer overrides what it needs. An observer never changes the flight: it sees what the
shell decided after it decided it."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from companion.autopilot.interface import Autopilot
from companion.delivery.gonogo import GoNoGoVerdict
from companion.delivery.mission import DeliveryMission, MissionInputs, MissionOutput, RequestResult
from companion.estimation.types import StateEstimate
from companion.events import MissionEvent
from companion.flightlog.csvlog import CsvLog
from companion.flightlog.streams import ENUM_VALUE
from companion.guidance.setpoint import VelocitySetpoint
from companion.uwb.measurements import UwbFix


class DeliveryShell(Protocol):
    """What an observer sees of the shell (delivery.shell.DeliveryShell)."""

    autopilot: Autopilot
    mission: DeliveryMission
    landing: Any  # shell.LandingKit | None
    fusion: Any  # delivery.fusion.LandingFusion | None
    estimate: StateEstimate | None

    def end_text(self) -> str: ...
    def end_severity(self) -> int: ...


@dataclass(frozen=True, slots=True)
class ShellTick:
    """One guidance tick, as it ended: the mission's inputs and output, the setpoint sent (after
    the clamp; None: none), whether the clamp changed it, and the shell (its mission, fusion and
    estimate)."""

    time_s: float
    inputs: MissionInputs
    output: MissionOutput
    setpoint: VelocitySetpoint | None
    clamped: bool
    shell: DeliveryShell


class ShellObserver:
    def on_start(self, shell: DeliveryShell) -> None:
        """The shell starts (before it connects): the first listener of the autopilot's samples."""

    def on_events(self, time_s: float, events: tuple[MissionEvent, ...]) -> None:
        """The mission's events of a tick, as soon as the mission has stepped."""

    def on_tick(self, tick: ShellTick) -> None:
        """A guidance tick, after its setpoint and request went out."""

    def on_setpoint(self, time_s: float, setpoint: VelocitySetpoint) -> None:
        """A setpoint sent to the autopilot (by a guidance tick or the stream's resend)."""

    def on_marker(self, time_s: float, obs: Any, image: Any) -> None:
        """A camera observation of the pad, before the fusion takes it."""

    def on_marker_fused(self, time_s: float, obs: Any, outcome: Any) -> None:
        """The fusion's verdict on that observation (estimation.UpdateOutcome)."""

    def on_uwb(self, time_s: float, fix: UwbFix) -> None:
        """A UWB fix, before the fusion takes it."""

    def on_result(self, time_s: float, kind: str, result: RequestResult) -> None:
        """What became of a request to the autopilot, before the mission hears it."""

    def on_command(self, time_s: float, kind: str, sender: str, reply: str) -> None:
        """A ground command and the mission's reply."""

    def on_abort(self, time_s: float, reason: str) -> None:
        """An abort the shell was asked for, as the mission takes it."""

    def on_go_no_go(self, time_s: float, verdict: GoNoGoVerdict, detail: str) -> None:
        """A go/no-go verdict reached outside a tick (the fence uploaded, refused)."""

    def on_text(self, text: str, severity: int) -> None:
        """A message for the operator (not ready to arm, the mission's end)."""

    async def close(self, shell: DeliveryShell) -> None:
        """The shell stops: whatever the observer opened is closed (its owner closes what it owns)."""


class RecorderObserver(ShellObserver):
    """The run folder's streams (flightlog.FlightRecorder): every input the core consumed, for replay."""

    def __init__(self, recorder: Any):
        self.recorder = recorder

    def on_start(self, shell: DeliveryShell) -> None:
        kit = shell.landing
        self.recorder.attach(
            shell.autopilot.telemetry,
            landing=kit is not None,
            pad_sensors=kit is not None and (kit.camera is not None or kit.uwb is not None),
        )

    def on_tick(self, tick: ShellTick) -> None:
        sh = tick.shell
        self.recorder.on_tick(tick.inputs, tick.output, tick.setpoint, tick.clamped, sh.mission, sh.fusion)

    def on_setpoint(self, time_s: float, setpoint: VelocitySetpoint) -> None:
        self.recorder.on_setpoint(time_s, setpoint)

    def on_marker(self, time_s: float, obs: Any, image: Any) -> None:
        self.recorder.on_marker(time_s, obs, image)

    def on_uwb(self, time_s: float, fix: UwbFix) -> None:
        self.recorder.on_uwb(time_s, fix)

    def on_result(self, time_s: float, kind: str, result: RequestResult) -> None:
        self.recorder.on_result(time_s, kind, result)

    def on_command(self, time_s: float, kind: str, sender: str, reply: str) -> None:
        self.recorder.on_command(time_s, kind, sender, reply)

    def on_abort(self, time_s: float, reason: str) -> None:
        self.recorder.on_abort(time_s, reason)

    def on_go_no_go(self, time_s: float, verdict: GoNoGoVerdict, detail: str) -> None:
        self.recorder.on_go_no_go(time_s, verdict.value, detail)

    async def close(self, shell: DeliveryShell) -> None:
        self.recorder.detach()  # its owner closes it


class TelemetryObserver(ShellObserver):
    """Zenoh telemetry (delivery.telemetry.ShellTelemetry): the state and the events each tick."""

    def __init__(self, telemetry: Any):
        self.telemetry = telemetry

    def on_tick(self, tick: ShellTick) -> None:
        out = tick.output
        self.telemetry.tick(tick.time_s, tick.shell, out.phase, out.sector, out.lyapunov, out.events)

    async def close(self, shell: DeliveryShell) -> None:
        self.telemetry.close()
        await self.telemetry.publisher.astop()


class GcsObserver(ShellObserver):
    """The companion's MAVLink component (delivery.gcs.GcsComponent): events and texts to the
    operator's GCS; the mission's end said when the shell stops."""

    def __init__(self, gcs: Any):
        self.gcs = gcs

    def on_events(self, time_s: float, events: tuple[MissionEvent, ...]) -> None:
        self.gcs.on_events(events)

    def on_text(self, text: str, severity: int) -> None:
        self.gcs.send_text(text, severity)

    async def close(self, shell: DeliveryShell) -> None:
        if shell.mission.phase.terminal:
            self.gcs.send_text(shell.end_text(), shell.end_severity())
        await self.gcs.close()


class TickCallback(ShellObserver):
    """A function of the shell and the tick's output, called at the end of every tick (the demo's
    and fly's progress display, a test's probe)."""

    def __init__(self, fn: Callable[[Any, MissionOutput], None]):
        self.fn = fn

    def on_tick(self, tick: ShellTick) -> None:
        self.fn(tick.shell, tick.output)


FLIGHT_LOG_COLUMNS = (
    "time_s",
    "phase",
    "sector",
    "lyapunov_m2",
    "est_north_m",
    "est_east_m",
    "est_down_m",
    "est_north_m_s",
    "est_east_m_s",
    "est_down_m_s",
    "est_yaw_rad",
    "sp_north_m_s",
    "sp_east_m_s",
    "sp_down_m_s",
    "sp_yaw_rad",
    "clamped",
    "mission_x_m",
    "mission_y_m",
    "mission_z_m",
    "mode",
    "armed",
)


class FlightLogObserver(ShellObserver):
    """flight.csv (FLIGHT_LOG_COLUMNS): a row a tick, the estimate also in the mission frame."""

    def __init__(self, flight_log: CsvLog):
        self.flight_log = flight_log
        # the mission frame (replaced on a replan, never mutated), its R_ned_mission.T and pad, so
        # each row does MissionFrame.point_from_ned's arithmetic on the same operands without
        # rebuilding the matrix
        self._frame: tuple[Any, Any, Any] | None = None

    def on_tick(self, tick: ShellTick) -> None:
        sh, out = tick.shell, tick.output
        e = sh.estimate
        sp = tick.setpoint
        st = sh.autopilot.telemetry.status
        nan = math.nan
        frame = sh.mission.frame
        if e is None:
            est: tuple[float, ...] = (nan, nan, nan, nan, nan, nan, nan)
            mx = my = mz = nan
        else:
            est = (e.north_m, e.east_m, e.down_m, e.north_m_s, e.east_m_s, e.down_m_s, e.yaw_rad)
            if frame is None:
                mx = my = mz = nan
            else:
                rf = self._frame
                if rf is None or rf[0] is not frame:
                    Rt, pad = frame.R_ned_mission.T, frame.pad_ned
                    rf = self._frame = (frame, tuple(tuple(map(float, r)) for r in Rt), tuple(map(float, pad)))
                # = frame.point_from_ned(position) in floats: numpy's 3x3 product sums each row in this order
                (a0, a1, a2), (b0, b1, b2), (c0, c1, c2) = rf[1]
                pn, pe, pd = rf[2]
                dn, de, dd = e.north_m - pn, e.east_m - pe, e.down_m - pd
                mx, my, mz = a0 * dn + a1 * de + a2 * dd, b0 * dn + b1 * de + b2 * dd, c0 * dn + c1 * de + c2 * dd
        self.flight_log.put(
            (tick.time_s, ENUM_VALUE[out.phase], out.sector, out.lyapunov)
            + est
            + ((sp.north_m_s, sp.east_m_s, sp.down_m_s, sp.yaw_rad) if sp else (nan, nan, nan, nan))
            + (int(tick.clamped), mx, my, mz, ENUM_VALUE[st.mode] if st else "", int(st.armed) if st else 0)
        )

"""The asyncio shell: schedules the synchronous core against an :class:`Autopilot`.

The shell keeps the start-up and shut-down, the guidance loop (>= 20 Hz, on absolute deadlines
of the running loop's clock: real, or virtual under the simulator) and the wiring; its parts,
each a collaborator the shell owns, are modules of their own:

- :mod:`~companion.delivery.preflight_steps`: the steps before the mission (the autopilot's
  mission, its fence, a mode it arms in) and the pre-flight wait's "not ready" reports;
- :mod:`~companion.delivery.landing_sensing`: the landing kit, the fusion's start on the pad (and
  on the alternate), the camera and UWB steps, LANDING_TARGET, the pad lock;
- :mod:`~companion.delivery.setpoint_stream`: the setpoint each tick sends, the stream that
  resends it and is the watchdog;
- :mod:`~companion.delivery.request_runner`: the mission's requests to the autopilot, each a task
  of its own so a slow acknowledgement never stalls guidance.

Whoever watches the shell (flight log, recorder, telemetry, the operator's GCS, a display, a
bench) is a :class:`~companion.delivery.observers.ShellObserver`; a bench's or a test's
instruments are :class:`~companion.delivery.hooks.ShellHooks`.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
from collections.abc import Awaitable, Callable
from typing import Any

from companion.autopilot.interface import Autopilot
from companion.config import CompanionConfig
from companion.delivery.external_nav import ExternalNavFeed
from companion.delivery.hooks import ShellHooks, TimedObserver
from companion.delivery.landing_sensing import LandingKit, LandingSensing
from companion.delivery.mission import (
    CommandReply,
    DeliveryMission,
    FailureKind,
    MissionInputs,
    MissionOutput,
    MissionSummary,
)
from companion.delivery.observers import (
    FlightLogObserver,
    GcsObserver,
    RecorderObserver,
    ShellObserver,
    ShellTick,
    TelemetryObserver,
    TickCallback,
)
from companion.delivery.pad_heading import heading_observation_age_s, landing_heading_rad
from companion.delivery.passthrough import AutopilotPoseEstimator
from companion.delivery.preflight_steps import PreflightSteps
from companion.delivery.request_runner import RequestRunner
from companion.delivery.setpoint_stream import SetpointStream
from companion.delivery.shell_stats import ShellStats
from companion.estimation.types import StateEstimate
from companion.events import CommandKind, EventKind, MissionEvent, Phase
from companion.flightlog.csvlog import CsvLog
from companion.guidance.limits import clamp_velocity
from companion.guidance.velocity_bias import VelocityBiasCorrection
from companion.scheduling import LoopClock, ThreadPolicy, realtime_loop_thread, restore_thread_policy

__all__ = ["AbortedBeforeFlight", "DeliveryShell", "LandingKit", "ShellStats"]

log = logging.getLogger(__name__)

WARNING_EVENTS = (EventKind.ABORT, EventKind.PILOT_TAKEOVER, EventKind.LINK_LOST)  # logged as warnings


class AbortedBeforeFlight(Exception):
    """The operator aborted (SIGINT/SIGTERM) while the shell was still waiting for the autopilot:
    nothing was commanded; ``str(err)`` says so."""


def _delivery_mission(config: CompanionConfig) -> DeliveryMission:
    return DeliveryMission(
        config.mission,
        config.landing.controller,
        config.landing.policy,
        fence=config.fence,
        limits=config.limits,
        go_no_go=config.go_no_go,
        winch=config.winch,
        stall_s=config.runtime.loop_stall_s,
        drop_zone=config.landing.drop_zone,
        moving_pad=config.landing.moving_pad,
    )


def _velocity_bias_correction(config: CompanionConfig) -> VelocityBiasCorrection | None:
    mc = config.mission
    if mc.velocity_bias_tau_s > 0:
        return VelocityBiasCorrection(mc.velocity_bias_tau_s, mc.velocity_bias_max_m_s, mc.velocity_bias_source)
    return None


class DeliveryShell:
    def __init__(
        self,
        config: CompanionConfig,
        autopilot: Autopilot,
        flight_log: CsvLog | None = None,
        on_tick: Callable[[DeliveryShell, MissionOutput], None] | None = None,
        telemetry: bool = False,
        landing: LandingKit | None = None,
        recorder: Any | None = None,
        before_flight: Callable[[], Awaitable[None]] | None = None,
        zenoh_session: Any = None,
        observers: tuple[ShellObserver, ...] = (),
        hooks: ShellHooks | None = None,
    ):
        """``flight_log`` (flight.csv), ``recorder`` (the run folder's streams) and ``on_tick`` (a
        function of the shell and each tick's output) are observers the shell adds itself, first;
        ``observers``: more, called after them (:meth:`add_observer`); ``hooks``: a bench's or a
        test's instruments (:class:`~companion.delivery.hooks.ShellHooks`; None: a flight's)."""
        self.hooks = hooks = hooks or ShellHooks()
        self.config = config
        # an open Zenoh session for the telemetry publisher (`fly --orders`: the order desk's, kept
        # across flights); None: the publisher opens its own from [telemetry]
        self._zenoh_session = zenoh_session
        # awaited once connected, before the setpoint stream and the mission start (nothing armed
        # yet): `companion fly`'s pre-flight check, which raises to stop the start-up
        self.before_flight = before_flight
        self.recorder = recorder  # flightlog.FlightRecorder: per-stream CSV logs of the core's inputs/outputs
        self.autopilot = autopilot
        self.mission = _delivery_mission(config)
        self.estimator = AutopilotPoseEstimator()
        self._velocity_bias = _velocity_bias_correction(config)
        self.flight_log = flight_log
        # the shell's own observers (flight log, recorder, then telemetry and GCS as they start),
        # called before those added from outside, each group in the order added
        self._parts: list[ShellObserver] = []
        self._timed_parts: list[ShellObserver] = []  # the same, timed by hooks.stage_timer when set
        self.observers: list[ShellObserver] = []
        if flight_log is not None:
            self._add_part(FlightLogObserver(flight_log), "logging")
        if recorder is not None:
            self._add_part(RecorderObserver(recorder), "logging")
        if on_tick is not None:
            self.observers.append(TickCallback(on_tick))
        self.observers.extend(observers)
        self.stats = ShellStats()
        self.estimate: StateEstimate | None = None
        self.events: list[MissionEvent] = []
        self._clock = LoopClock()
        # set when a camera observation is fused while the fused estimate steers: guidance ticks
        # at once instead of at its next deadline ([runtime] guidance_on_marker)
        self._marker_fused = asyncio.Event()
        self._abort_reason: str | None = None
        self._abort_kind = FailureKind.ABORTED
        self._connecting: asyncio.Task[None] | None = None
        self._want_telemetry = telemetry
        self._stop_reason: str | None = None  # stop(): the guidance loop ends at its next tick
        self.landing = landing
        # the parts: each reads the configuration and the mission through the shell (both are
        # replaced before flight when the delivery comes from the autopilot's mission)
        watching = self._watching
        self.preflight = PreflightSteps(self, autopilot, self._clock, watching)
        self.sensing = LandingSensing(
            self, landing, autopilot, self._clock, self.stats, hooks, watching, self._marker_fused
        )
        self.sensors = self.sensing.sensors  # the landing sensors' tasks (sensor_tasks.SensorTasks)
        self.stream = SetpointStream(self, autopilot, self._clock, self.stats, hooks, watching)
        self.requests = RequestRunner(self, autopilot, self._clock, self.stats, watching)
        # [external_nav]: the fused pose to the autopilot, its source switched when GNSS is lost
        self.external_nav = ExternalNavFeed(config.external_nav, autopilot) if config.external_nav.enabled else None
        self.telemetry: Any = None  # companion.delivery.telemetry.ShellTelemetry when publishing
        self.ground_commands: list[tuple[str, str]] = []
        self.gcs: Any = None  # delivery.gcs.GcsComponent while speaking to the operator's GCS

    # the parts' state that callers read on the shell
    @property
    def fusion(self) -> Any:
        """The landing fusion (delivery.fusion.LandingFusion) once the pad is known, else None."""
        return self.sensing.fusion

    @fusion.setter
    def fusion(self, fusion: Any) -> None:
        self.sensing.fusion = fusion

    @property
    def marker_tick_pending(self) -> bool:
        """A camera observation fused while the fused estimate steers has asked guidance to tick
        at once, and that tick has not run yet ([runtime] guidance_on_marker)."""
        return self._marker_fused.is_set()

    @property
    def vision_always(self) -> bool:
        """Detect from the fusion's start, whatever the phase (benches, tests)."""
        return self.sensing.vision_always

    @vision_always.setter
    def vision_always(self, on: bool) -> None:
        self.sensing.vision_always = on

    @property
    def landing_targets_sent(self) -> int:
        return self.sensing.landing_targets_sent

    @property
    def made_ready(self) -> list[str]:
        """What the pre-flight steps' make_ready did, before the mission and after it."""
        return self.preflight.made_ready

    def on_ground_command(self, cmd: Any) -> CommandReply:
        """An authenticated ground command (telemetry.auth.GroundCommand), on the loop thread."""
        return self.command(cmd.kind, cmd.sender)

    def command(self, kind: CommandKind, sender: str) -> CommandReply:
        """A hold / return / land / abort from the ground (Zenoh) or the operator's GCS (MAVLink,
        sender "gcs"), on the loop thread: to the mission, recorded; returns the mission's reply.
        The kind's name is written only for the logs and the observers (commands.csv, telemetry)."""
        now = self._clock.now()
        reply = self.mission.command(now, kind, sender)
        for ob in self._watching():
            ob.on_command(now, kind.value, sender, str(reply))
        self.ground_commands.append((kind.value, reply))
        log.warning("ground command %s from %s: %s", kind.value, sender, reply)
        return reply

    def add_observer(self, observer: ShellObserver) -> None:
        """Watch the shell from now on (after those already added): :class:`ShellObserver`."""
        self.observers.append(observer)

    def _add_part(self, observer: ShellObserver, stage: str) -> None:
        self._parts.append(observer)
        timer = self.hooks.stage_timer
        self._timed_parts.append(observer if timer is None else TimedObserver(observer, stage, timer))

    def _watching(self) -> list[ShellObserver]:
        return self._timed_parts + self.observers

    def _closing_order(self) -> list[ShellObserver]:
        """Telemetry first, the recorder next, the GCS last (it says how the mission ended), then
        those added from outside."""
        rank = {TelemetryObserver: 0, FlightLogObserver: 1, RecorderObserver: 1, GcsObserver: 2}
        return sorted(self._parts, key=lambda ob: rank.get(type(ob), 1)) + self.observers

    def abort(self, reason: str, kind: FailureKind = FailureKind.ABORTED) -> None:
        """Ask the mission to abort (hold, then land) at its next tick; while the shell is still
        waiting for the autopilot, stop waiting (nothing has been commanded). ``kind``: what the
        summary's failure is (OPERATOR_ABORT for the operator's signal)."""
        self._abort_reason = reason
        self._abort_kind = kind
        if self._connecting is not None and not self._connecting.done():
            self._connecting.cancel()

    def stop(self, reason: str) -> None:
        """End the guidance loop at its next tick, before it steps the mission again, without
        failing the mission (a bench's measured window is over); the setpoint stream ends with it
        and the shell stops as after a finished mission. Nothing is commanded: the autopilot's
        offboard-loss failsafe acts on a vehicle left in the air."""
        self._stop_reason = reason

    async def run(self, timeout_s: float | None = None) -> MissionSummary:
        saved_policy = self._loop_thread_realtime(asyncio.get_running_loop())
        try:
            return await self._run(timeout_s)
        finally:
            if saved_policy is not None:
                restore_thread_policy(saved_policy)

    async def _run(self, timeout_s: float | None) -> MissionSummary:
        loop = asyncio.get_running_loop()
        self.sensing.apply_opencv_threads()  # process-wide, before the camera starts
        for ob in self._watching():
            ob.on_start(self)  # the recorder: the first listener, so every sample gets a seq
        stream: asyncio.Task[None] | None = None
        try:  # everything started here is stopped in the finally, a failed start-up included
            if self._want_telemetry:
                self._start_telemetry(loop)
            await self._connect(loop)
            if self.config.gcs.enabled:
                self._open_gcs()
            if self.config.mission.destination == "autopilot_mission":
                self.config, said = await self.preflight.autopilot_mission()
                self.mission = _delivery_mission(self.config)
                self.mission.go_no_go(self._clock.now(), said)
            if self.before_flight is not None:
                await self.before_flight()
            await self.preflight.make_ready("before the mission")  # once the pre-flight check has passed
            if self.config.fence.enabled and self.config.fence.upload:
                await self.preflight.upload_fence()
            stream = loop.create_task(self.stream.run(), name="setpoint-stream")
            if timeout_s is None:
                await self._guidance_loop()
            else:
                try:
                    await asyncio.wait_for(self._guidance_loop(), timeout_s)
                except TimeoutError:
                    self.mission.summary.fail(
                        FailureKind.TIMED_OUT,
                        f"mission did not finish within {timeout_s} s ({self.where_it_stands(self._clock.now())})",
                    )
                    log.error(self.mission.summary.failure)
            if self.mission.summary.failure_kind is FailureKind.NOT_READY:
                why = self.autopilot.not_ready_reason()
                if why:
                    self.mission.summary.failure += f" ({why})"
            await self.preflight.make_ready("after the mission")
        finally:
            if stream is not None:
                stream.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await stream
            await self.sensing.stop()
            if self.external_nav is not None:
                await self.external_nav.stop()
            await self.requests.cancel()
            for ob in self._closing_order():
                await ob.close(self)
        return self.mission.summary

    def _start_telemetry(self, loop: asyncio.AbstractEventLoop) -> None:
        """The Zenoh publisher (and its ground commands), watching from now on."""
        from companion.delivery.telemetry import ShellTelemetry, command_handler, make_publisher

        pub = make_publisher(self.config, command_handler(loop, self), session=self._zenoh_session)
        pub.start()
        self.telemetry = ShellTelemetry(pub, self.autopilot.telemetry)
        self._add_part(TelemetryObserver(self.telemetry), "telemetry")

    async def _connect(self, loop: asyncio.AbstractEventLoop) -> None:
        """Wait for the autopilot; an abort meanwhile stops the wait (:class:`AbortedBeforeFlight`)."""
        self._connecting = loop.create_task(
            self.autopilot.connect(timeout_s=self.config.runtime.connect_timeout_s), name="connect"
        )
        try:
            await self._connecting
        except asyncio.CancelledError:
            if self._abort_reason is None:
                raise
            raise AbortedBeforeFlight(f"{self._abort_reason} while waiting for the autopilot") from None
        finally:
            self._connecting = None

    def _open_gcs(self) -> None:
        """The companion's MAVLink component for the operator's GCS, watching once it is open."""
        from companion.delivery.gcs import GcsComponent

        self.gcs = GcsComponent(self.config.gcs, self.autopilot, self.command)
        if self.gcs.open():
            self._add_part(GcsObserver(self.gcs), "gcs")
        else:
            self.gcs = None

    def _loop_thread_realtime(self, loop: asyncio.AbstractEventLoop) -> ThreadPolicy | None:
        """``runtime.realtime_priority`` for the loop's thread (``stats.realtime`` says what was
        done); returns the policy to put back at the end, None when nothing changed."""
        saved, self.stats.realtime = realtime_loop_thread(loop, self.config.runtime.realtime_priority)
        return saved

    def end_text(self) -> str:
        """What the mission's end says to the operator."""
        s = self.mission.summary
        if s.failure:
            return f"mission ended: {s.failure}"
        return "mission done: " + ("delivered" if s.delivered else "not delivered") + (", home" if s.returned else "")

    def end_severity(self) -> int:
        from companion.autopilot.component import SEVERITY_NOTICE, SEVERITY_WARNING

        return SEVERITY_WARNING if self.mission.summary.failure else SEVERITY_NOTICE

    def now(self) -> float:
        """The shell's clock: the loop's time (simulated on the virtual loop), s."""
        return self._clock.now()

    def fused_estimate_steers(self) -> bool:
        """Guidance flies on the fused estimate (DeliveryMission.fused_estimate_steers)."""
        return self.mission.fused_estimate_steers

    def where_it_stands(self, now: float) -> str:
        """The mission's phase, the request it waits on, and what the autopilot last said (mode,
        armed, landed, height, and how old each is): for a mission that ends without finishing,
        so the log says where."""
        tc = self.autopilot.telemetry
        parts = [f"phase {self.mission.phase.value}", self.mission.waiting_for()]
        st = tc.status
        if st is None:
            parts.append("no autopilot status")
        else:
            parts.append(
                f"autopilot {st.mode.value}, {'armed' if st.armed else 'disarmed'}, {st.landed.value} "
                f"(status {now - st.time_s:.1f} s old)"
            )
        p = tc.position_ned
        if p is None:
            parts.append("no local position")
        else:
            parts.append(f"local height {-p.down_m:.2f} m (position {now - p.time_s:.1f} s old)")
        parts.append("link up" if self.autopilot.link_ok else "link down")
        return "; ".join(parts)

    # ------------------------------------------------------------------ the guidance loop
    async def _guidance_loop(self) -> None:
        # each tick renews the loop's liveness: a watchdog thread stops the backend's heartbeats
        # and setpoints when it stalls, so the autopilot fails safe (autopilot.liveness)
        with self.autopilot.liveness.watching(self.config.runtime.loop_stall_s):
            await self._guidance_ticks()

    async def _guidance_ticks(self) -> None:
        """One tick: abort if asked, the pose, the fusion's pad, the estimate, the mission's step,
        its events, the clamped setpoint sent, its request started, then the observers."""
        rate = self.hooks.rate_loop(self._clock, self.config.runtime.guidance_rate_hz)
        tc = self.autopilot.telemetry
        mission = self.mission
        live = self.autopilot.liveness
        sensing, stream = self.sensing, self.stream
        update = self.hooks.timed("guidance", self.estimator.update)
        step = self.hooks.timed("guidance", mission.step)
        while not mission.phase.terminal and self._stop_reason is None:
            now, _ = await rate.tick_or(self._marker_fused)
            if self._stop_reason is not None:
                log.info("guidance stopped: %s; the mission is in phase %s", self._stop_reason, mission.phase.value)
                stream.latest = None  # the stream ends on purpose: not a stalled control task
                break
            live.renew()
            self.stats.guidance_overruns, self.stats.guidance_ticks = rate.overruns, rate.ticks
            if self._abort_reason is not None:
                for ob in self._watching():
                    ob.on_abort(now, self._abort_reason)
                mission.abort(now, self._abort_reason, self._abort_kind)
                self._abort_reason = None
            gps_frame = update(tc.position_ned, tc.attitude)
            if self.landing is not None:
                sensing.follow_pad(now)
            # The fused frame puts the configured pad where the camera/UWB see it; home is a GPS
            # point, so the way back (after the delivery) flies on the GPS-frame estimate.
            fusion = sensing.fusion  # nothing from here to the tick's end awaits: it stays the same
            fused = fusion.estimate() if fusion is not None else None
            self.estimate = mission.guidance_estimate(gps_frame, fused, now)
            heading = fusion.heading if fusion is not None else None
            inp = MissionInputs(
                now,
                self.estimate,
                tc.status,
                tc.home,
                self.autopilot.link_ok,
                sensing.pad_lock(now),
                wind=tc.wind,
                winch=tc.winch,
                rangefinder=tc.rangefinder,
                pad_heading_rad=landing_heading_rad(self.config.mission, mission.pad_index, heading),
                pad_heading_age_s=heading_observation_age_s(heading, now),
                autopilot_yaw_rad=tc.attitude.yaw_rad if tc.attitude is not None else None,
                drop_zone=sensing.drop_zone_verdict(now),
                pad_velocity_ne=fusion.pad_velocity_ne if fusion is not None else None,
                parcel=sensing.parcel,
            )
            out = step(inp)
            events = out.events
            if self.external_nav is not None:
                events = events + self.external_nav.step(now, fusion, mission.phase)
            for ev in events:
                self.events.append(ev)
                level = logging.WARNING if ev.kind in WARNING_EVENTS else logging.INFO
                log.log(level, "t=%.2f %s %s %s", ev.time_s, ev.phase.value, ev.kind.value, ev.detail)
            for ob in self._watching():
                ob.on_events(now, events)
            if out.phase is Phase.PREFLIGHT:
                self.preflight.say_not_ready(now, tc.status)
            clamped = False
            if self._velocity_bias is not None:
                self._velocity_bias.update(tc.position_ned, fusion.locked_position if fusion is not None else None)
            if out.setpoint is not None:
                pos = self.estimate.position_ned if self.estimate else None
                sp_out = self._velocity_bias.correct(out.setpoint) if self._velocity_bias is not None else out.setpoint
                res = clamp_velocity(sp_out, self.config.limits, pos)
                clamped = res.clamped
                if res.clamped:
                    self.stats.setpoints_clamped += 1
                stream.latest = (now, res.setpoint)
                stream.send(now, res.setpoint)
            else:
                stream.latest = None
            if out.request is not None:
                self.requests.submit(out.request)
            tick = ShellTick(now, inp, out, stream.latest[1] if stream.latest is not None else None, clamped, self)
            for ob in self._watching():
                ob.on_tick(tick)

"""The asyncio shell: schedules the synchronous core against an :class:`Autopilot`.

Tasks: the guidance/mission loop (>= 20 Hz) and the setpoint stream (>= 20 Hz), both on
absolute deadlines of the running loop's clock (real, or virtual under the simulator). Autopilot
requests run as their own tasks so a slow acknowledgement never stalls guidance. Each guidance
tick sends the setpoint it computed at once (the estimate it used, a camera frame's included,
reaches the autopilot in the same tick instead of up to one stream period later). The setpoint
stream, half a period out of phase with guidance, only resends the latest setpoint when guidance
has sent none for a stream period (guidance slower than the stream, or a late tick), and it is the
watchdog: if the guidance task stops refreshing the setpoint, streaming stops, so the
autopilot's own offboard-loss failsafe fires (a stale setpoint must never be resent forever, cf.
MAVSDK-Python issue 374).

Landing sensors (once fusion starts): the lock-step and real-time strategies of
:mod:`companion.delivery.sensor_tasks`; the shell's steps detect, fuse and record. Whoever watches
the shell (flight log, recorder, telemetry, the operator's GCS, a display, a bench) is a
:class:`~companion.delivery.observers.ShellObserver`.
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import math
import os
import threading
import time
from collections.abc import Awaitable, Callable
from dataclasses import dataclass
from typing import Any

from companion.autopilot.interface import Autopilot, AutopilotError, CommandRejected
from companion.autopilot.landing_target import LandingTargetBuilder, LandingTargetError
from companion.config import CompanionConfig
from companion.delivery.detection_pacer import DetectionPacer

# the landing fusion's modules load with the shell, not when the fusion starts at take-off: their
# import (scipy.spatial among them) would take the loop's CPU from guidance in flight
from companion.delivery.fusion import FusionSetup
from companion.delivery.gonogo import GoNoGoVerdict
from companion.delivery.hooks import ShellHooks, TimedObserver
from companion.delivery.mission import (
    CommandReply,
    DeliveryMission,
    FailureKind,
    MissionInputs,
    MissionOutput,
    MissionSummary,
    Request,
    RequestKind,
    RequestResult,
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
from companion.delivery.pad_heading import heading_observation_age_s, landing_heading_rad, pad_yaw_and_tolerance_rad
from companion.delivery.padlock import NO_SENSORS, PadLock, measure_pad_lock
from companion.delivery.passthrough import AutopilotPoseEstimator
from companion.delivery.sensor_tasks import SensorTasks
from companion.estimation.ekf import UpdateOutcome
from companion.estimation.types import StateEstimate
from companion.events import CommandKind, EventKind, MissionEvent, Phase
from companion.flightlog.csvlog import CsvLog
from companion.geometry.mounts import pad_pose_ned
from companion.guidance.limits import clamp_velocity
from companion.guidance.setpoint import VelocitySetpoint
from companion.guidance.velocity_bias import VelocityBiasCorrection
from companion.scheduling import (
    LoopClock,
    ThreadPolicy,
    realtime_loop_thread,
    restore_thread_policy,
    set_thread_realtime,
    vision_thread_priority,
)
from companion.uwb.multilateration import UwbFix

log = logging.getLogger(__name__)

REQUEST_TIMEOUT_S = 10.0  # an autopilot call that takes longer has failed (and is retried)


WARNING_EVENTS = (EventKind.ABORT, EventKind.PILOT_TAKEOVER, EventKind.LINK_LOST)  # logged as warnings
NOT_READY_SAY_S = 5.0  # how often a pre-flight wait on an autopilot that is not ready says why


class AbortedBeforeFlight(Exception):
    """The operator aborted (SIGINT/SIGTERM) while the shell was still waiting for the autopilot:
    nothing was commanded; ``str(err)`` says so."""


@dataclass
class LandingKit:
    """What precision landing needs: sensor plugins (api_version 1), the detector and solver, and
    the mounts. The simulator passes simulated plugins; on a vehicle they come from config."""

    camera: Any | None  # plugin: read() -> plugin_api.Frame | None
    uwb: Any | None  # plugin: read() -> list of TwrMeasurement (or readings with to_twr_measurement())
    detector: Any | None  # companion.vision.PadDetector
    multilaterator: Any | None  # companion.uwb.Multilaterator
    T_body_camera: Any  # geometry.Transform
    T_pad_anchors: Any  # geometry.Transform: the UWB anchor frame in the pad frame
    ekf_config: Any = None  # estimation.EkfConfig (None: defaults)
    # off the event loop in flight (and camera and UWB on tasks of their own); inline under virtual
    # time, in one polled loop (deterministic)
    vision_in_thread: bool = True
    poll_rate_hz: float = 60.0  # the UWB's poll, and the camera's when it offers no frame listener
    sensors_started: bool = False  # started before take-off (a real vehicle); else at fusion start
    # hand the detector the autopilot's attitude (through the camera mount) to resolve the IPPE
    # mirror pair of a lone marker (vision.detector.resolve_ambiguity(attitude=True)); off by default
    vision_attitude: bool = False


@dataclass
class ShellStats:
    guidance_ticks: int = 0
    guidance_overruns: int = 0
    setpoint_overruns: int = 0
    setpoints_sent: int = 0
    setpoints_clamped: int = 0
    stream_stops: int = 0
    requests: int = 0
    requests_failed: int = 0
    # how the camera is read: "" (no camera task), "frame listener", "polled"
    camera_read: str = ""
    frames_notified: int = 0  # wake-ups of the camera task by its frame listener
    frames_paced: int = 0  # frames not read: the detector's CPU budget (runtime.vision_cpu_budget) was spent
    realtime: str = ""  # runtime.realtime_priority: "SCHED_RR <priority>", "refused: <why>", "" (not asked)


_thread_priority: dict[int, tuple[int, int]] = {}  # tid -> (nice, realtime priority) applied


def _prioritise_this_thread(nice: int, realtime: int = 0) -> None:
    """The detector thread's priority, set once per setting (Linux: a thread id is a pid to
    setpriority): SCHED_RR one below the loop's ``realtime`` when that is set, otherwise the lower
    ``nice``; where that is not possible the thread keeps its priority, said once."""
    tid = threading.get_native_id()
    if (nice <= 0 and realtime <= 0) or _thread_priority.get(tid) == (nice, realtime):
        return
    _thread_priority[tid] = (nice, realtime)
    if realtime > 0:
        why = set_thread_realtime(vision_thread_priority(realtime))
        if why is not None:
            log.warning("runtime.realtime_priority = %d: the detector thread keeps its policy (%s)", realtime, why)
        return
    try:
        os.setpriority(os.PRIO_PROCESS, tid, nice)
    except (OSError, AttributeError) as err:
        log.warning("runtime.vision_thread_nice = %d: the detector thread keeps its priority (%s)", nice, err)


def _cpu_timed(fn: Callable[..., Any], *args: Any, nice: int = 0, realtime: int = 0) -> tuple[Any, float]:
    """``fn(*args)`` and the CPU seconds its thread spent in it (the thread prioritised first, see
    ``runtime.vision_thread_nice`` and ``runtime.realtime_priority``)."""
    _prioritise_this_thread(nice, realtime)
    t0 = time.thread_time()
    out = fn(*args)
    return out, time.thread_time() - t0


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
        self._setpoint: tuple[float, VelocitySetpoint] | None = None
        self._last_sent_s = -math.inf  # when a setpoint last went to the autopilot
        # set when a camera observation is fused while the fused estimate steers: guidance ticks
        # at once instead of at its next deadline ([runtime] guidance_on_marker)
        self._marker_fused = asyncio.Event()
        budget = config.runtime.vision_cpu_budget
        self._pacer = DetectionPacer(budget) if budget > 0.0 else None
        self._request_task: asyncio.Task[None] | None = None
        self._streaming = False
        self._abort_reason: str | None = None
        self._abort_kind = FailureKind.ABORTED
        self._connecting: asyncio.Task[None] | None = None
        self._want_telemetry = telemetry
        self.landing = landing
        self.fusion: Any = None  # delivery.fusion.LandingFusion once the pad is known
        self._fusion_pad_index = 0  # mission.pad_index the fusion was started for
        self.sensors = SensorTasks(landing, self._clock, self.stats, self._camera_step, self._uwb_step, hooks.rate_loop)
        self._stop_reason: str | None = None  # stop(): the guidance loop ends at its next tick
        self.vision_always = False  # detect from the fusion's start, whatever the phase (see _vision_wanted)
        self.telemetry: Any = None  # companion.delivery.telemetry.ShellTelemetry when publishing
        self.ground_commands: list[tuple[str, str]] = []
        self._landing_target: Any = None  # autopilot.landing_target.LandingTargetBuilder when sending
        # the pad's size for LANDING_TARGET, known before take-off (the layout's module loads OpenCV)
        self._landing_target_size_m: float | None = None
        if config.landing.landing_target_output != "off" and landing is not None:
            from companion.vision.pad import PadLayout

            self._landing_target_size_m = getattr(landing.detector, "layout", PadLayout()).outer_size_m
        self.landing_targets_sent = 0
        self.gcs: Any = None  # delivery.gcs.GcsComponent while speaking to the operator's GCS
        self.made_ready: list[str] = []  # what make_ready did, before the mission and after it
        self._not_ready_said_s = -math.inf

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
        if self.landing is not None and (self.landing.camera is not None or self.landing.detector is not None):
            from companion.vision.opencv_threads import apply_opencv_threads

            apply_opencv_threads(self.config.runtime.opencv_threads)  # process-wide, before the camera starts
        for ob in self._watching():
            ob.on_start(self)  # the recorder: the first listener, so every sample gets a seq
        stream: asyncio.Task[None] | None = None
        try:  # everything started here is stopped in the finally, a failed start-up included
            if self._want_telemetry:
                from companion.delivery.telemetry import ShellTelemetry, command_handler, make_publisher

                pub = make_publisher(self.config, command_handler(loop, self), session=self._zenoh_session)
                pub.start()
                self.telemetry = ShellTelemetry(pub, self.autopilot.telemetry)
                self._add_part(TelemetryObserver(self.telemetry), "telemetry")
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
            if self.config.gcs.enabled:
                from companion.delivery.gcs import GcsComponent

                self.gcs = GcsComponent(self.config.gcs, self.autopilot, self.command)
                if self.gcs.open():
                    self._add_part(GcsObserver(self.gcs), "gcs")
                else:
                    self.gcs = None
            if self.config.mission.destination == "autopilot_mission":
                await self._take_autopilot_mission()
            if self.before_flight is not None:
                await self.before_flight()
            await self._make_ready("before the mission")  # once the pre-flight check has passed
            if self.config.fence.enabled and self.config.fence.upload:
                await self._upload_fence()
            stream = loop.create_task(self._setpoint_stream(), name="setpoint-stream")
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
            await self._make_ready("after the mission")
        finally:
            if stream is not None:
                stream.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await stream
            await self.sensors.stop()
            if self.landing is not None:
                for dev in (self.landing.camera, self.landing.uwb):
                    if dev is not None:
                        try:
                            dev.stop()
                        except Exception as err:  # the rest must still be closed
                            log.error("stopping %s failed: %s", type(dev).__name__, err)
            if self._request_task is not None:
                self._request_task.cancel()
                with contextlib.suppress(asyncio.CancelledError):
                    await self._request_task
            for ob in self._closing_order():
                await ob.close(self)
        return self.mission.summary

    def _loop_thread_realtime(self, loop: asyncio.AbstractEventLoop) -> ThreadPolicy | None:
        """``runtime.realtime_priority`` for the loop's thread (``stats.realtime`` says what was
        done); returns the policy to put back at the end, None when nothing changed."""
        saved, self.stats.realtime = realtime_loop_thread(loop, self.config.runtime.realtime_priority)
        return saved

    async def _take_autopilot_mission(self) -> None:
        """The delivery the operator planned in the GCS (docs/gcs.md): download the autopilot's
        mission, fly to its pad. Nothing is armed yet; a mission the companion cannot fly raises
        :class:`~companion.delivery.autopilot_mission.MissionPlanError` (or MissionDownloadError)."""
        from companion.delivery.autopilot_mission import config_from_autopilot_mission

        self.config, said = await config_from_autopilot_mission(self.config, self.autopilot)
        self.mission = _delivery_mission(self.config)
        self.mission.go_no_go(self._clock.now(), said)

    async def _upload_fence(self) -> None:
        """The autopilot's own fence: upload ``[fence]``, read it back and compare, before anything
        is armed; a failure refuses the delivery (docs/go-no-go.md)."""
        from companion.autopilot.fence import fence_from_config, fence_mismatch

        fence = fence_from_config(self.config.fence)
        try:
            await self.autopilot.upload_fence(fence)
            why = fence_mismatch(fence, await self.autopilot.download_fence())
            if why is not None:
                raise AutopilotError(f"the fence read back differs from the one uploaded: {why}")
        except AutopilotError as err:
            log.error("fence refused: %s", err)
            self._go_no_go(GoNoGoVerdict.REFUSE, f"the autopilot's fence: {err}")
            return
        self._go_no_go(GoNoGoVerdict.GO, f"fence uploaded to the autopilot and read back: {fence.describe()}")

    def _go_no_go(self, verdict: GoNoGoVerdict, detail: str) -> None:
        """A go/no-go verdict reached outside a guidance tick, to the mission (``refuse``: the
        delivery is refused; ``go``: said, nothing changes) and to the recorder, for replay."""
        now = self._clock.now()
        for ob in self._watching():
            ob.on_go_no_go(now, verdict, detail)
        if verdict is GoNoGoVerdict.REFUSE:
            self.mission.refuse(now, detail)
        else:
            self.mission.go_no_go(now, detail)

    def end_text(self) -> str:
        """What the mission's end says to the operator."""
        s = self.mission.summary
        if s.failure:
            return f"mission ended: {s.failure}"
        return "mission done: " + ("delivered" if s.delivered else "not delivered") + (", home" if s.returned else "")

    def end_severity(self) -> int:
        from companion.autopilot.component import SEVERITY_NOTICE, SEVERITY_WARNING

        return SEVERITY_WARNING if self.mission.summary.failure else SEVERITY_NOTICE

    async def _make_ready(self, when: str) -> None:
        """Leave (or find) the autopilot disarmed in a mode it arms in, so mission after mission
        starts (:meth:`Autopilot.make_ready`); a refusal is said, not raised: the mission's own
        pre-flight wait then says why it cannot arm."""
        if type(self.autopilot).make_ready is Autopilot.make_ready:
            return  # nothing to do (the embedded simulator): not a tick of virtual time spent on it
        if not self.autopilot.link_ok and when == "after the mission":
            return
        if when == "before the mission":
            # the mode arrives with the first telemetry after connecting
            for _ in range(20):
                st = self.autopilot.telemetry.status
                if st is not None and st.mode.value != "unknown":
                    break
                await asyncio.sleep(0.1)
        else:
            await asyncio.sleep(0.5)  # the disarm's mode and armed state have arrived
        try:
            done = await asyncio.wait_for(self.autopilot.make_ready(), 10.0)
        except (AutopilotError, TimeoutError) as err:
            log.warning("%s: the autopilot's mode could not be made ready to arm: %s", when, err or "no answer")
            return
        if done:
            self.made_ready.append(f"{when}: {done}")
            log.info("%s: %s", when, done)
            from companion.autopilot.component import SEVERITY_NOTICE

            for ob in self._watching():
                ob.on_text(done, SEVERITY_NOTICE)

    def now(self) -> float:
        """The shell's clock: the loop's time (simulated on the virtual loop), s."""
        return self._clock.now()

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

    # ------------------------------------------------------------------ tasks
    async def _guidance_loop(self) -> None:
        # each tick renews the loop's liveness: a watchdog thread stops the backend's heartbeats
        # and setpoints when it stalls, so the autopilot fails safe (autopilot.liveness)
        with self.autopilot.liveness.watching(self.config.runtime.loop_stall_s):
            await self._guidance_ticks()

    async def _guidance_ticks(self) -> None:
        rate = self.hooks.rate_loop(self._clock, self.config.runtime.guidance_rate_hz)
        tc = self.autopilot.telemetry
        mission = self.mission
        live = self.autopilot.liveness
        update = self.hooks.timed("guidance", self.estimator.update)
        step = self.hooks.timed("guidance", mission.step)
        while not mission.phase.terminal and self._stop_reason is None:
            now, _ = await rate.tick_or(self._marker_fused)
            if self._stop_reason is not None:
                log.info("guidance stopped: %s; the mission is in phase %s", self._stop_reason, mission.phase.value)
                self._setpoint = None  # the stream ends on purpose: not a stalled control task
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
                if self.fusion is None and mission.frame is not None:
                    self._start_fusion(now)
                elif self.fusion is not None and mission.pad_index != self._fusion_pad_index:
                    self._start_fusion(now)  # diverted: the fusion starts again on the alternate pad
            # The fused frame puts the configured pad where the camera/UWB see it; home is a GPS
            # point, so the way back (after the delivery) flies on the GPS-frame estimate.
            fused = self.fusion.estimate() if self.fusion is not None else None
            self.estimate = mission.guidance_estimate(gps_frame, fused, now)
            heading = self.fusion.heading if self.fusion is not None else None
            inp = MissionInputs(
                now,
                self.estimate,
                tc.status,
                tc.home,
                self.autopilot.link_ok,
                self._pad_lock(now),
                wind=tc.wind,
                winch=tc.winch,
                rangefinder=tc.rangefinder,
                pad_heading_rad=landing_heading_rad(self.config.mission, mission.pad_index, heading),
                pad_heading_age_s=heading_observation_age_s(heading, now),
                autopilot_yaw_rad=tc.attitude.yaw_rad if tc.attitude is not None else None,
            )
            out = step(inp)
            for ev in out.events:
                self.events.append(ev)
                level = logging.WARNING if ev.kind in WARNING_EVENTS else logging.INFO
                log.log(level, "t=%.2f %s %s %s", ev.time_s, ev.phase.value, ev.kind.value, ev.detail)
            for ob in self._watching():
                ob.on_events(now, out.events)
            if out.phase is Phase.PREFLIGHT:
                self._say_not_ready(now, tc.status)
            clamped = False
            if self._velocity_bias is not None:
                self._velocity_bias.update(
                    tc.position_ned, self.fusion.locked_position if self.fusion is not None else None
                )
            if out.setpoint is not None:
                pos = self.estimate.position_ned if self.estimate else None
                sp_out = self._velocity_bias.correct(out.setpoint) if self._velocity_bias is not None else out.setpoint
                res = clamp_velocity(sp_out, self.config.limits, pos)
                clamped = res.clamped
                if res.clamped:
                    self.stats.setpoints_clamped += 1
                self._setpoint = (now, res.setpoint)
                self._send_setpoint(now, res.setpoint)
            else:
                self._setpoint = None
            if out.request is not None:
                self._request_task = asyncio.get_running_loop().create_task(self._execute(out.request))
            tick = ShellTick(now, inp, out, self._setpoint[1] if self._setpoint is not None else None, clamped, self)
            for ob in self._watching():
                ob.on_tick(tick)

    def _pad_lock(self, now: float) -> PadLock:
        """The pad's lock for the mission's no-release-off-the-pad policy: none without a camera or
        UWB in the landing kit (GPS-only)."""
        kit = self.landing
        if kit is None or (kit.camera is None and kit.uwb is None):
            return NO_SENSORS
        if self.fusion is None:
            return PadLock(now, math.inf, math.inf)
        return measure_pad_lock(self.fusion, now)

    def _say_not_ready(self, now: float, st: Any) -> None:
        """In pre-flight, while the autopilot does not report itself ready to arm: say why every
        NOT_READY_SAY_S, with the autopilot's own words (log, and the operator's GCS)."""
        if st is None or st.healthy or now - self._not_ready_said_s < NOT_READY_SAY_S:
            return
        if self._not_ready_said_s == -math.inf:
            self._not_ready_said_s = now  # the first reports after connecting may still be settling
            return
        self._not_ready_said_s = now
        why = self.autopilot.not_ready_reason() or "no reason given"
        log.warning("waiting for the autopilot to be ready to arm: %s", why)
        from companion.autopilot.component import SEVERITY_WARNING

        for ob in self._watching():
            ob.on_text(f"not ready to arm: {why}", SEVERITY_WARNING)

    def _start_fusion(self, now: float) -> None:
        kit = self.landing
        assert kit is not None and self.mission.frame is not None
        pad = self.mission.frame.pad_ned
        # the camera and UWB see the pad the mission lands on: after a divert, the alternate (a new
        # EKF: the first pad's GPS-bias estimate says nothing about where the alternate lies)
        restart = self.fusion is not None
        if restart:
            self.autopilot.telemetry.remove_listener(self.fusion.on_sample)
        self._fusion_pad_index = self.mission.pad_index
        yaw, heading_tol = pad_yaw_and_tolerance_rad(self.config.mission, self.mission.pad_index)
        setup = FusionSetup(
            T_world_pad=pad_pose_ned(float(pad[0]), float(pad[1]), float(pad[2]), yaw_rad=yaw),
            heading_tolerance_rad=heading_tol,
            T_body_camera=kit.T_body_camera,
            T_pad_anchors=kit.T_pad_anchors,
            ekf=kit.ekf_config or self.config.landing.ekf,
            velocity_bias_tau_s=self.config.landing.ekf_velocity_bias_tau_s,
            velocity_bias_max_m_s=self.config.mission.velocity_bias_max_m_s,
            velocity_bias_source=self.config.mission.velocity_bias_source,
            level_pad=self.config.landing.ekf_level_pad,
        )
        self.fusion = self.hooks.fusion(setup, now)
        if self._landing_target_size_m is not None:
            self._landing_target = LandingTargetBuilder(
                self.config.landing.landing_target_output,
                kit.T_body_camera,
                setup.T_world_pad,
                self._landing_target_size_m,
            )
        self.autopilot.telemetry.add_listener(self.fusion.on_sample)
        if restart:
            log.info("landing fusion started again on the alternate pad at NED %s", [round(float(v), 2) for v in pad])
            return
        for dev in (kit.camera, kit.uwb):
            if dev is not None and not kit.sensors_started:
                dev.start()
        self.sensors.start()
        log.info("landing fusion started; configured pad at NED %s", [round(float(v), 2) for v in pad])

    def _vision_wanted(self) -> bool:
        """Detection from the approach on (sector 5 of the way out, the pad phases), or always
        with ``vision_always`` (benches and tests that measure the detector from the start)."""
        m = self.mission
        return (
            self.vision_always
            or m.phase in (Phase.LANDING_PAD, Phase.PAD_HOLD, Phase.PAD_SEARCH, Phase.WINCH)
            or (m.phase in (Phase.OUTBOUND, Phase.DIVERT) and m.sector >= 5)
        )

    async def _camera_step(self) -> None:
        """The camera's newest frame, when vision is wanted: detection (on the executor, or inline in
        lock-step), then the observation to the recorder, the fusion and the landing target."""
        kit = self.landing
        assert kit is not None and kit.camera is not None and kit.detector is not None and self.fusion is not None
        if not self._vision_wanted():
            return
        pacer, start_s = self._pacer, self._clock.now()
        if pacer is not None and not pacer.due(start_s):
            self.stats.frames_paced += 1
            return
        frame = kit.camera.read()
        if frame is None:
            return
        # the attitude moves the ROI with the vehicle's tilt always, and resolves the IPPE pair when
        # vision_attitude is set
        down_cam = self._down_in_camera()
        detect = functools.partial(
            _cpu_timed,
            functools.partial(
                kit.detector.detect, down_cam=down_cam if kit.vision_attitude else None, roi_down_cam=down_cam
            ),
            nice=self.config.runtime.vision_thread_nice if kit.vision_in_thread else 0,
            realtime=self.config.runtime.realtime_priority if kit.vision_in_thread else 0,
        )
        if kit.vision_in_thread:
            obs, cpu_s = await asyncio.get_running_loop().run_in_executor(None, detect, frame.image, frame.time_s)
        else:
            obs, cpu_s = detect(frame.image, frame.time_s)
        if pacer is not None:
            pacer.done(start_s, cpu_s)
        if obs is None:
            return
        watching = self._watching()
        for ob in watching:
            ob.on_marker(self._clock.now(), obs, frame.image)
        outcome = self.fusion.on_marker(obs)
        for ob in watching:
            ob.on_marker_fused(self._clock.now(), obs, outcome)
        accepted = outcome is UpdateOutcome.ACCEPTED
        if accepted and self.config.runtime.guidance_on_marker and self.fused_estimate_steers():
            self._marker_fused.set()
        if self._landing_target is not None:
            self._send_landing_target(obs)

    def _uwb_step(self) -> None:
        """The UWB readings since the last call, multilaterated, to the recorder and the fusion."""
        kit = self.landing
        assert kit is not None and kit.uwb is not None and kit.multilaterator is not None and self.fusion is not None
        for m in kit.uwb.read():
            meas = m.to_twr_measurement() if hasattr(m, "to_twr_measurement") else m
            res = kit.multilaterator.solve_twr(meas)
            if isinstance(res, UwbFix):
                for ob in self._watching():
                    ob.on_uwb(self._clock.now(), res)
                self.fusion.on_uwb(res)

    def fused_estimate_steers(self) -> bool:
        """Guidance flies on the fused estimate (DeliveryMission.fused_estimate_steers)."""
        return self.mission.fused_estimate_steers

    def _down_in_camera(self) -> Any:
        """World down in the camera frame from the autopilot's latest attitude (None without one)."""
        from companion.geometry import euler_to_rotmat
        from companion.vision.detector import down_in_camera

        att = self.autopilot.telemetry.attitude
        if att is None or self.landing is None:
            return None
        R_wb = euler_to_rotmat(att.roll_rad, att.pitch_rad, att.yaw_rad)
        return down_in_camera(R_wb, self.landing.T_body_camera.R)

    def _send_landing_target(self, obs: Any) -> None:
        """LANDING_TARGET for the autopilot's own precision landing (ambiguous poses never sent)."""
        if getattr(obs, "ambiguous", False) or self.fusion is None or not self.fusion.pad_locked:
            return
        try:
            target = self._landing_target.build(obs.time_s, obs.T_camera_pad, self.fusion.estimate())
            self.autopilot.send_landing_target(target)
        except (LandingTargetError, AutopilotError) as err:
            log.warning("LANDING_TARGET not sent: %s", err)
            return
        self.landing_targets_sent += 1

    def _send_setpoint(self, now: float, sp: VelocitySetpoint) -> None:
        self.autopilot.set_velocity_ned(sp)
        self.stats.setpoints_sent += 1
        self._last_sent_s = now
        for ob in self._watching():
            ob.on_setpoint(now, sp)
        self._streaming = True

    async def _setpoint_stream(self) -> None:
        rt = self.config.runtime
        period = 1.0 / rt.setpoint_rate_hz
        # half a period after the guidance ticks (same rate by default): a resend is decided on a
        # clock instant guidance never ticks on, so the order of two tasks due at once plays no part
        rate = self.hooks.rate_loop(self._clock, rt.setpoint_rate_hz, start_s=self._clock.now() + period / 2.0)
        while True:
            now = await rate.tick()
            self.stats.setpoint_overruns = rate.overruns
            sp = self._setpoint
            if sp is not None and now - sp[0] <= rt.setpoint_stale_s:
                # guidance sends every setpoint it computes; resend only what a stream period
                # without a send would otherwise leave the autopilot without
                if now - self._last_sent_s >= period * (1.0 - 1e-9):
                    self._send_setpoint(now, sp[1])
            elif self._streaming:
                self._streaming = False
                if sp is not None:  # stale, not merely finished
                    self.stats.stream_stops += 1
                    log.error(
                        "setpoint is %.2f s old: control task stalled, setpoint stream stopped "
                        "so the autopilot's failsafe acts",
                        now - sp[0],
                    )

    async def _execute(self, req: Request) -> None:
        ap = self.autopilot
        self.stats.requests += 1
        calls = {
            RequestKind.ARM: ap.arm,
            RequestKind.DISARM: ap.disarm,
            RequestKind.START_OFFBOARD: ap.start_offboard,
            RequestKind.HOLD: ap.hold,
            RequestKind.LAND: ap.land,
            RequestKind.PRECISION_LAND: ap.precision_land,
            RequestKind.RELEASE: ap.release_payload,
        }
        # Every way out of here answers the request: a request left without a result would keep
        # the mission from ever issuing another (an abort's HOLD and LAND included), silently.
        # a call the autopilot never answers ends here; an arm that waits for the autopilot's
        # checks by design (ArduPilot's arm_timeout_s, retried until then) gets its own time
        limit_s = REQUEST_TIMEOUT_S
        if req.kind is RequestKind.ARM:
            limit_s = max(limit_s, float(getattr(ap, "arm_timeout_s", 0.0)) + REQUEST_TIMEOUT_S)
        try:
            if req.kind is RequestKind.TAKEOFF:
                await asyncio.wait_for(ap.takeoff(req.alt_rel_m), limit_s)
            elif req.kind is RequestKind.WINCH:
                assert req.winch is not None
                await asyncio.wait_for(ap.winch(req.winch), limit_s)
            else:
                await asyncio.wait_for(calls[req.kind](), limit_s)
        except (AutopilotError, TimeoutError) as err:
            permanent = isinstance(err, CommandRejected) and err.permanent
            self._failed(req, str(err) or type(err).__name__, permanent)
            return
        except asyncio.CancelledError:
            task = asyncio.current_task()
            if task is not None and task.cancelling():
                raise  # the shell is stopping
            # a cancellation from inside the backend (a native call's future cancelled under it)
            self._failed(req, "the autopilot call was cancelled inside the backend", False)
            return
        except Exception as err:  # a backend bug: said with its traceback, and the mission told
            log.exception("%s: the backend raised %s", req.kind.value, type(err).__name__)
            self._failed(req, f"backend error: {type(err).__name__}: {err}", False)
            return
        self._result(req, RequestResult(req.id, True))

    def _failed(self, req: Request, msg: str, permanent: bool) -> None:
        self.stats.requests_failed += 1
        log.warning("%s failed%s: %s", req.kind.value, " (not retried)" if permanent else "", msg)
        self._result(req, RequestResult(req.id, False, msg, permanent))

    def _result(self, req: Request, result: RequestResult) -> None:
        for ob in self._watching():
            ob.on_result(self._clock.now(), req.kind.value, result)
        self.mission.on_result(result)

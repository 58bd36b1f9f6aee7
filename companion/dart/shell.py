"""The Dart cyber-pilot on the asyncio shell: a real autopilot, a camera plugin, the Dart tasks.

The functional core is the Dart application's own (companion.dart: the Madgwick-based or
complementary position estimators in :mod:`.estimators`, the four decoupled PIDs in
:mod:`.control`, the mission in :mod:`.mission`, the hybrid RC mixer in :mod:`.mixer`) plus the
shared marker detector; the lock-step simulator (companion_sitl.dart_sim) runs the same core.
Here they are scheduled on the running loop's clock by
absolute-deadline :class:`~companion.scheduling.RateLoop` tasks at the rates of dart sec. 4:

- IMU + estimator (200 Hz): every IMU sample the autopilot streamed (HIGHRES_IMU, collected by a
  telemetry listener, stamped at receipt) goes through ``update_imu`` in time order. The Madgwick
  filter starts from the autopilot's ATTITUDE; at every engagement its heading is re-aligned to
  the autopilot's (``align_yaw_to_autopilot``): the Madgwick yaw is unobservable and drifts.
- vision (aperiodic, ~30 Hz): the newest camera frame (plugin ``read()``, stamped at exposure)
  goes to the detector on a worker thread (OpenCV releases the GIL); the observation, timestamped
  at exposure, is fused on the loop. An ambiguous detection (IPPE mirror pair unresolved) is
  gated by the estimator, never fused.
- control (22 Hz): engagement from the pilot's switch, the mission's setpoint, the PIDs'
  contribution (RC microseconds).
- commands (44 Hz): the contribution leaves the companion.
  ArduPilot (``output="rc_override"``): RC_CHANNELS_OVERRIDE = the pilot's sticks (RC_CHANNELS, on
  ``pilot_channels``) + the contribution on ``stick_channels``, through the hybrid mixer. When the
  switch goes off the overrides are *released* (0: the autopilot flies on the receiver again) in
  the same call, and the RC_CHANNELS listener runs that call the moment the switch reading
  arrives, not at the next command tick. PX4 (``output="attitude"``): SET_ATTITUDE_TARGET with
  the pilot's stick deflection plus the contribution (dart.mixer.attitude_setpoint), OFFBOARD
  requested once setpoints stream; when the switch goes off the stream stops at once (map the
  same switch to PX4's RC_MAP_OFFB_SW so PX4 leaves OFFBOARD by itself) and, if PX4 is still in
  OFFBOARD one control period later, the shell commands HOLD.
- log (20 Hz): a CSV row of the shell's state (flightlog.csvlog).

Safety: engaged only while the link is up, the vehicle armed and in a pilot attitude mode
(ArduCopter STABILIZE or ALT_HOLD; PX4 a manual/position mode or OFFBOARD), the RC reading is
fresh (``rc_timeout_s``) and valid; a contribution older than ``contribution_timeout_s`` (a
stalled control task) is not mixed, the pilot's sticks pass alone. Leaving :meth:`DartShell.run`
releases everything.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from collections import deque
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal

from companion.autopilot.interface import AttitudeTarget, Autopilot, AutopilotError, RcInput
from companion.autopilot.types import Attitude, FlightMode, Imu, TelemetrySample
from companion.dart.control import DartCommand, DartController, DartSetpoint
from companion.dart.estimators import (
    CameraMarkerObservation,
    DartEstimator,
    DartEstimatorConfig,
    MadgwickPositionEstimator,
    camera_mount,
    make_estimator,
    wall_marker,
)
from companion.dart.hooks import DartHooks
from companion.dart.mission import DartMission, DartPhase
from companion.dart.mixer import AttitudeMapConfig, RcMixer, RcMixerConfig, attitude_setpoint
from companion.dart.params import DartFlightParams, DartRuntimeConfig, controller_config
from companion.flightlog.csvlog import CsvLog
from companion.geometry import wrap_angle
from companion.param_kinds import DartEstimatorTable
from companion.scheduling import (
    Clock,
    LoopClock,
    realtime_loop_thread,
    restore_thread_policy,
    set_thread_realtime,
    vision_thread_priority,
)
from companion.vision.camera import CameraModel, load_camera, load_default_camera
from companion.vision.detector import PadDetector
from companion.vision.opencv_threads import apply_opencv_threads
from companion.vision.pad import PadLayout

log = logging.getLogger(__name__)

Output = Literal["rc_override", "attitude"]

#: message id -> rate the Dart runtime asks an ArduPilot for (IMU at the estimator's rate)
DART_STREAM_RATES_HZ: dict[int, float] = {
    105: 200.0,  # HIGHRES_IMU
    30: 100.0,  # ATTITUDE
    65: 50.0,  # RC_CHANNELS: the pilot's sticks and switch
    1: 5.0,  # SYS_STATUS
    245: 5.0,  # EXTENDED_SYS_STATE
    147: 1.0,  # BATTERY_STATUS
}
#: ArduCopter modes in which the sticks are attitude (and climb-rate / thrust) commands
ARDUCOPTER_STICK_MODES = (0, 2)  # STABILIZE, ALT_HOLD
PX4_ENGAGE_MODES = (FlightMode.MANUAL, FlightMode.POSITION, FlightMode.OFFBOARD)
OFFBOARD_AFTER_SETPOINTS = 5  # attitude setpoints streamed (at 44 Hz) before OFFBOARD is requested

LOG_COLUMNS = (
    "time_s",
    "engaged",
    "phase",
    "est_x_m",
    "est_y_m",
    "est_z_m",
    "est_yaw_rad",
    "sp_x_m",
    "sp_y_m",
    "sp_z_m",
    "roll_us",
    "pitch_us",
    "thrust_us",
    "yaw_rate_us",
    "out_roll_us",
    "out_pitch_us",
    "out_throttle_us",
    "out_yaw_us",
    "imu_samples",
    "estimates",
)


@dataclass
class DartShellStats:
    imu_samples: int = 0
    imu_rejected: int = 0
    frames: int = 0
    detections: int = 0
    ambiguous: int = 0
    estimates: int = 0
    vision_errors: int = 0
    control_steps: int = 0
    overrides_sent: int = 0
    releases_sent: int = 0
    attitude_targets_sent: int = 0
    stale_contributions: int = 0
    rc_stale: int = 0
    send_errors: int = 0
    yaw_alignments: int = 0
    realtime: str = ""  # runtime.realtime_priority: "SCHED_RR <priority>", "refused: <why>", "" (not asked)


@dataclass(frozen=True, slots=True)
class DartStep:
    """One control step: the estimate used, the setpoint, the contribution."""

    time_s: float
    engaged: bool
    phase: DartPhase
    est: tuple[float, float, float] | None
    setpoint: tuple[float, float, float] | None
    command: DartCommand


@dataclass
class DartRunSummary:
    duration_s: float
    output: str
    estimator: str
    phase: DartPhase
    transitions: list[tuple[float, DartPhase]]
    stats: DartShellStats
    steps: list[DartStep] = field(default_factory=list)
    releases: list[float] = field(default_factory=list)  # times the overrides were released


def estimator_config(rt: DartRuntimeConfig, table: DartEstimatorTable | None = None) -> DartEstimatorConfig:
    """The estimators' settings ``[estimator]`` (``table``; default its defaults) with the
    geometry from ``[runtime]``: forward camera, lens offset, wall marker."""
    heading = math.radians(rt.marker_heading_deg)
    return DartEstimatorConfig.with_geometry(
        table or DartEstimatorTable(),
        R_body_cam=camera_mount(),
        t_body_cam_m=rt.lens_offset_m,
        R_world_marker=wall_marker(heading),
        reference_yaw_rad=heading,
        gimbal_yaw_rad=heading,
    )


def runtime_camera_model(rt: DartRuntimeConfig) -> CameraModel:
    cam = load_camera(rt.camera_file) if rt.camera_file else load_default_camera()
    return cam.scaled(rt.camera_scale) if rt.camera_scale != 1.0 else cam


def _overridden(obj: Autopilot, name: str) -> bool:
    return getattr(type(obj), name) is not getattr(Autopilot, name)


def _choose_output(autopilot: Autopilot, output: Output | None, rt: DartRuntimeConfig) -> Output:
    """The output asked for, or the one the backend takes (RC overrides first, then attitude
    setpoints); refused when RC overrides would read the pilot's sticks with the overrides on."""
    if output is None:
        if _overridden(autopilot, "send_rc_override"):
            output = "rc_override"
        elif _overridden(autopilot, "set_attitude_target"):
            output = "attitude"
        else:
            raise AutopilotError(
                f"{type(autopilot).__name__} takes neither RC overrides nor attitude setpoints: "
                "the Dart cyber-pilot cannot fly it"
            )
    if output not in ("rc_override", "attitude"):
        raise ValueError(f"output = {output!r}: must be 'rc_override' or 'attitude'")
    if output == "rc_override" and not rt.pilot_mirrored:
        raise ValueError(
            f"[runtime] pilot_channels = {rt.pilot_channels}: equal to stick_channels, but ArduPilot reports "
            "RC_CHANNELS with the overrides applied, so the pilot's sticks must be mirrored on other channels "
            "by the transmitter (e.g. 9-12)"
        )
    return output


def _log_row(shell: DartShell, time_s: float) -> tuple[Any, ...]:
    """The shell's state as one row of LOG_COLUMNS (NaN where there is none yet)."""
    e = shell.estimator.last
    sp = shell._last_sp
    c = shell.command
    nan = math.nan
    return (
        time_s,
        int(shell.engaged),
        shell.mission.phase.value,
        *((e.x_m, e.y_m, e.z_m, e.yaw_rad) if e is not None else (nan,) * 4),
        *((sp.x_m, sp.y_m, sp.z_m) if sp is not None else (nan,) * 3),
        c.roll_us,
        c.pitch_us,
        c.thrust_us,
        c.yaw_rate_us,
        *(nan if v is None else v for v in shell.last_output),
        shell.stats.imu_samples,
        shell.stats.estimates,
    )


class DartShell:
    """Runs the Dart cyber-pilot against ``autopilot`` with frames from ``camera`` (a
    ``companion.cameras`` plugin instance, frames stamped on this loop's clock)."""

    def __init__(
        self,
        autopilot: Autopilot,
        camera: Any,
        params: DartFlightParams | None = None,
        *,
        output: Output | None = None,
        camera_model: CameraModel | None = None,
        layout: PadLayout | None = None,
        log_path: str | Path | None = None,
        clock: Clock | None = None,
        keep_steps: bool = True,
        hooks: DartHooks | None = None,
    ) -> None:
        self.params = p = params or DartFlightParams()
        rt = self.rt = p.runtime
        self.autopilot = autopilot
        self.camera = camera
        self.output: Output = _choose_output(autopilot, output, rt)
        self.clock: Clock = clock or LoopClock()
        self.hooks = h = hooks or DartHooks()
        self.rates = rt.rates
        self.estimator: DartEstimator = make_estimator(rt.estimator_name, estimator_config(rt, p.estimator))
        self.camera_model = camera_model or runtime_camera_model(rt)
        self.layout = layout or PadLayout(
            outer_size_m=rt.outer_size_m, inner_size_m=rt.inner_size_m, pad_size_m=rt.pad_size_m
        )
        self.detector = PadDetector(self.camera_model, self.layout)
        self.mission = DartMission(p.mission)
        self.controller = DartController(controller_config(p.control, rt.control_hz))
        # [runtime] is the mixer's config and the attitude map (its keys declared once, in
        # companion.param_kinds.RcMixerTable and AttitudeMapTable)
        self.mixer_config: RcMixerConfig = rt
        self.mixer = RcMixer(self.mixer_config, on_disengage=self._on_disengage, release_when_disengaged=True)
        self.attitude_map: AttitudeMapConfig = rt
        self.log_path = Path(log_path) if log_path is not None else None
        self.keep_steps = keep_steps
        self.stats = DartShellStats()
        self.steps: list[DartStep] = []
        self.releases: list[float] = []
        self.command = DartCommand(0.0, 0.0, 0.0, 0.0, 0.0, engaged=False)
        self.last_output: tuple[int | None, ...] = (None, None, None, None)
        self.engaged = False  # as last decided by the control task
        self._imu: deque[Imu] = deque(maxlen=256)
        self._last_sp: DartSetpoint | None = None
        self._release_left = 0
        self._madgwick_started = False
        self._offboard_task: asyncio.Task[None] | None = None
        self._offboard_asked_at = -math.inf
        self._streak = 0  # attitude setpoints sent since the engagement
        self._hold_task: asyncio.Task[None] | None = None
        self._disengaged_at: float | None = None
        self._executor: ThreadPoolExecutor | None = None
        self._csv: CsvLog | None = None
        self._t0 = 0.0
        # the stages a bench times (DartHooks), bound once; a flight binds the functions themselves
        self._sample_listener = h.timed("imu", self._on_sample)
        self._command_step = h.timed("commands", self._send_command)
        self._rc_out = h.timed("rc_override", self._send_rc_override)
        self._attitude_out = h.timed("attitude", self._set_attitude_target)

    # ------------------------------------------------------------------ inputs
    def _on_sample(self, sample: TelemetrySample) -> None:
        if isinstance(sample, Imu):
            self._imu.append(sample)

    def _mode_ok(self) -> bool:
        st = self.autopilot.telemetry.status
        if st is None or not st.armed:
            return False
        if self.output == "rc_override":
            copter = getattr(self.autopilot, "copter_mode", None)
            if isinstance(copter, int) and copter >= 0:
                return copter in ARDUCOPTER_STICK_MODES
            return st.mode is FlightMode.MANUAL
        return st.mode in PX4_ENGAGE_MODES

    def pilot_view(self, now: float) -> list[int | None]:
        """The pilot's channels as the mixer reads them: the sticks (read on ``pilot_channels``)
        on the stick channels and the switch, forced off when the vehicle may not be engaged.
        Empty when the RC reading is missing or stale (invalid: disengage, release)."""
        rc: RcInput | None = self.autopilot.telemetry.rc_input
        if rc is None or not now - rc.time_s <= self.rt.rc_timeout_s:
            if rc is not None:
                self.stats.rc_stale += 1
            return []
        ch = rc.channels_us
        view: list[int | None] = [None] * 18

        def at(c: int) -> int | None:
            return ch[c - 1] if c <= len(ch) else None

        for stick, pilot in zip(self.rt.stick_channels, self.rt.pilot_channels, strict=True):
            view[stick - 1] = at(pilot)
        sw = self.rt.switch_channel
        view[sw - 1] = at(sw) if self.autopilot.link_ok and self._mode_ok() else round(self.mixer_config.min_us)
        return view

    def _on_rc(self, rc: RcInput) -> None:
        """The pilot's switch off (or the mode left): release now, not at the next command tick."""
        if self.mixer.engaged and not self.mixer.engaged_from(self.pilot_view(self.clock.now())):
            self._send_command(self.clock.now())

    # ------------------------------------------------------------------ engagement
    def _on_disengage(self) -> None:
        self.controller.disengage()
        self._streak = 0
        self._disengaged_at = self.clock.now()
        self.releases.append(self._disengaged_at)

    def _align_yaw(self, now: float) -> None:
        """Madgwick heading := the autopilot's heading (its compass-aided estimate)."""
        est = self.estimator
        att: Attitude | None = self.autopilot.telemetry.attitude
        if not (self.rt.align_yaw_to_autopilot and isinstance(est, MadgwickPositionEstimator)):
            return
        if att is None or now - att.time_s > 0.5:
            log.warning("dart: no recent ATTITUDE from the autopilot: Madgwick heading not aligned")
            return
        yaw_m = est.madgwick.euler()[2]
        est.yaw_offset_rad = wrap_angle(att.yaw_rad - yaw_m)
        self.stats.yaw_alignments += 1

    # ------------------------------------------------------------------ tasks
    async def _imu_task(self) -> None:
        rate = self.hooks.rate_loop(self.clock, self.rates.imu_hz)
        est = self.estimator
        update_imu = self.hooks.timed("imu", est.update_imu)
        while True:
            await rate.tick()
            while self._imu:
                s = self._imu.popleft()
                if not self._madgwick_started and isinstance(est, MadgwickPositionEstimator):
                    att = self.autopilot.telemetry.attitude
                    if att is not None:  # start from the autopilot's attitude, not from level-north
                        est.madgwick.reset_euler(att.roll_rad, att.pitch_rad, att.yaw_rad)
                        self._madgwick_started = True
                ok = update_imu(
                    s.time_s,
                    (s.gyro_x_rad_s, s.gyro_y_rad_s, s.gyro_z_rad_s),
                    (s.accel_x_m_s2, s.accel_y_m_s2, s.accel_z_m_s2),
                )
                if ok:
                    self.stats.imu_samples += 1
                else:
                    self.stats.imu_rejected += 1

    async def _vision_task(self) -> None:
        loop = asyncio.get_running_loop()
        assert self._executor is not None
        poll_s = 0.25 / self.rates.vision_hz
        detect = self.hooks.timed("detect", self.detector.detect)
        update_vision = self.hooks.timed("vision", self.estimator.update_vision)
        while True:
            frame = self.camera.read()
            if frame is None:
                await asyncio.sleep(poll_s)
                continue
            self.stats.frames += 1
            try:
                det = await loop.run_in_executor(self._executor, detect, frame.image, frame.time_s)
            except ValueError as err:  # an unusable frame is counted, never fatal
                self.stats.vision_errors += 1
                log.warning("dart vision: frame %d rejected: %s", frame.index, err)
                continue
            if det is None:
                continue
            self.stats.detections += 1
            if det.ambiguous:
                self.stats.ambiguous += 1
            if update_vision(CameraMarkerObservation.from_detection(det)) is not None:
                self.stats.estimates += 1

    async def _control_task(self) -> None:
        rate = self.hooks.rate_loop(self.clock, self.rates.control_hz)
        step = self.hooks.timed("control", self.control_step)
        while True:
            t = await rate.tick()
            step(t)

    def control_step(self, t: float) -> DartCommand:
        """Engagement, mission setpoint and the PIDs' contribution at ``t``."""
        engaged = self.mixer.engaged_from(self.pilot_view(t))
        if engaged and not self.engaged:
            self._align_yaw(t)
        self.engaged = engaged
        step = self.mission.update(t, engaged)
        sp = step.setpoint or self._last_sp or self.mission.start_setpoint
        self._last_sp = sp
        est = self.estimator.last
        self.command = self.controller.update(t, est, sp, engaged)
        self.stats.control_steps += 1
        if self.keep_steps:
            self.steps.append(
                DartStep(
                    t,
                    engaged,
                    step.phase,
                    None if est is None else (est.x_m, est.y_m, est.z_m),
                    (sp.x_m, sp.y_m, sp.z_m) if engaged else None,
                    self.command,
                )
            )
        return self.command

    async def _command_task(self) -> None:
        rate = self.hooks.rate_loop(self.clock, self.rates.command_hz)
        while True:
            t = await rate.tick()
            self._command_step(t)

    def _contribution(self, now: float) -> DartCommand | None:
        c = self.command
        if not c.engaged:
            return None
        if not now - c.time_s <= self.rt.contribution_timeout_s:
            self.stats.stale_contributions += 1
            return None
        return c

    def _send_command(self, now: float) -> None:
        view = self.pilot_view(now)
        contrib = self._contribution(now)
        if self.output == "rc_override":
            self._send_rc(view, contrib)
        else:
            self._send_attitude(now, view, contrib)

    def _send_rc(self, view: list[int | None], contrib: DartCommand | None) -> None:
        out = self.mixer.mix(view, contrib)
        if out.engaged:
            self._release_left = self.rt.release_repeat
        elif self._release_left > 0:
            self._release_left -= 1
        else:
            return  # released and repeated: silence (the radio flies)
        try:
            self._rc_out(out.channels)
        except AutopilotError as err:
            self.stats.send_errors += 1
            log.warning("dart: RC override not sent: %s", err)
            return
        self.last_output = out.sticks_us if out.engaged else (None, None, None, None)
        if out.engaged:
            self.stats.overrides_sent += 1
        else:
            self.stats.releases_sent += 1

    def _send_attitude(self, now: float, view: list[int | None], contrib: DartCommand | None) -> None:
        ap = self.autopilot
        out = self.mixer.mix(view, contrib)  # engagement bookkeeping (its channels are not sent)
        if not out.engaged:
            self.last_output = (None, None, None, None)
            st = ap.telemetry.status
            late = self._disengaged_at is not None and now - self._disengaged_at >= 1.0 / self.rates.control_hz
            if late and st is not None and st.mode is FlightMode.OFFBOARD and self._hold_task is None:
                log.warning("dart: still in OFFBOARD after the switch went off: commanding HOLD")
                self._hold_task = asyncio.get_running_loop().create_task(self._request(ap.hold(), "hold"))
            return
        sp = attitude_setpoint(view, contrib, self.mixer_config, self.attitude_map)
        att = ap.telemetry.attitude
        if sp is None or att is None:
            return
        target = AttitudeTarget(sp.roll_rad, sp.pitch_rad, att.yaw_rad, sp.yaw_rate_rad_s, sp.thrust)
        try:
            self._attitude_out(target)
        except AutopilotError as err:
            self.stats.send_errors += 1
            log.warning("dart: attitude setpoint not sent: %s", err)
            return
        self.stats.attitude_targets_sent += 1
        self._streak += 1
        self._disengaged_at = None
        self._hold_task = None
        self.last_output = out.sticks_us
        st = ap.telemetry.status
        if (
            st is not None
            and st.mode is not FlightMode.OFFBOARD
            and self._streak >= OFFBOARD_AFTER_SETPOINTS  # PX4 refuses OFFBOARD without a stream
            and now - self._offboard_asked_at >= 0.5
            and (self._offboard_task is None or self._offboard_task.done())
        ):
            self._offboard_asked_at = now
            self._offboard_task = asyncio.get_running_loop().create_task(self._request(ap.start_offboard(), "offboard"))

    def _send_rc_override(self, channels: Sequence[int]) -> None:
        self.autopilot.send_rc_override(channels)  # looked up each time: a test may spy on it

    def _set_attitude_target(self, target: AttitudeTarget) -> None:
        self.autopilot.set_attitude_target(target)

    async def _request(self, coro: Any, what: str) -> None:
        try:
            await coro
        except AutopilotError as err:
            log.warning("dart: %s refused: %s", what, err)

    async def _log_task(self) -> None:
        rate = self.hooks.rate_loop(self.clock, self.rates.log_hz)
        write = None if self._csv is None else self.hooks.timed("logging", self._csv.write)
        while True:
            t = await rate.tick()
            if write is None:
                continue
            write(_log_row(self, t - self._t0))

    # ------------------------------------------------------------------ run
    async def run(self, duration_s: float | None = None) -> DartRunSummary:
        """Fly until ``duration_s`` has passed (None: until cancelled); always releases on exit."""
        if duration_s is not None and not (math.isfinite(duration_s) and duration_s > 0.0):
            raise ValueError(f"duration_s = {duration_s!r}: must be > 0")
        tel = self.autopilot.telemetry
        self._t0 = self.clock.now()
        apply_opencv_threads(self.rt.opencv_threads)  # process-wide, before the camera starts
        loop = asyncio.get_running_loop()
        prio = self.rt.realtime_priority
        saved_policy, self.stats.realtime = realtime_loop_thread(loop, prio)
        self._executor = ThreadPoolExecutor(
            max_workers=1,
            thread_name_prefix="dart-vision",
            # the vision thread one below the loop's (it inherits the loop's at its start)
            initializer=None if saved_policy is None else lambda: set_thread_realtime(vision_thread_priority(prio)),
        )
        if self.log_path is not None:
            self._csv = CsvLog(self.log_path, LOG_COLUMNS)
        tel.add_listener(self._sample_listener)
        tel.add_rc_listener(self._on_rc)
        self.camera.start()
        tasks = [
            loop.create_task(self._imu_task(), name="dart-imu"),
            loop.create_task(self._vision_task(), name="dart-vision"),
            loop.create_task(self._control_task(), name="dart-control"),
            loop.create_task(self._command_task(), name="dart-command"),
            loop.create_task(self._log_task(), name="dart-log"),
        ]
        log.info("dart: %s estimator, output %s", self.estimator.name, self.output)
        try:
            if duration_s is None:
                await asyncio.gather(*tasks)
            else:
                done, _ = await asyncio.wait(tasks, timeout=duration_s, return_when=asyncio.FIRST_EXCEPTION)
                for t in done:  # a task that died is a bug: surface it
                    t.result()
        finally:
            for t in tasks:
                t.cancel()
            for t in tasks:
                with contextlib.suppress(asyncio.CancelledError):
                    await t
            self._shutdown()
            await self._leave_offboard()
            tel.remove_listener(self._sample_listener)
            tel.remove_rc_listener(self._on_rc)
            self.camera.stop()
            self._executor.shutdown(wait=True)
            if self._csv is not None:
                self._csv.close()
            if saved_policy is not None:
                restore_thread_policy(saved_policy)
        return DartRunSummary(
            duration_s=self.clock.now() - self._t0,
            output=self.output,
            estimator=self.estimator.name,
            phase=self.mission.phase,
            transitions=list(self.mission.transitions),
            stats=self.stats,
            steps=self.steps,
            releases=self.releases,
        )

    async def _leave_offboard(self) -> None:
        """PX4: stopping the stream alone would leave OFFBOARD to its loss failsafe: hold now."""
        for task in (self._offboard_task, self._hold_task):
            if task is not None and not task.done():
                task.cancel()
                with contextlib.suppress(asyncio.CancelledError, AutopilotError):
                    await task
        st = self.autopilot.telemetry.status
        if self.output == "attitude" and st is not None and st.mode is FlightMode.OFFBOARD and self.autopilot.link_ok:
            try:
                await asyncio.wait_for(self.autopilot.hold(), timeout=3.0)
            except (AutopilotError, TimeoutError) as err:
                log.warning("dart: HOLD on exit refused: %s", err)

    def _shutdown(self) -> None:
        """Leaving: the pilot gets everything back."""
        out = self.mixer.mix([], None)  # invalid input: disengages (controller reset), release values
        if self.output == "rc_override" and (out.disengaged_now or self._release_left > 0):
            with contextlib.suppress(AutopilotError):
                self._rc_out(out.channels)
                self.stats.releases_sent += 1


__all__ = [
    "ARDUCOPTER_STICK_MODES",
    "DART_STREAM_RATES_HZ",
    "LOG_COLUMNS",
    "DartRunSummary",
    "DartShell",
    "DartShellStats",
    "DartStep",
    "estimator_config",
    "runtime_camera_model",
]

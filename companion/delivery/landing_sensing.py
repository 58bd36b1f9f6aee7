"""The landing sensing: what the delivery shell does with its landing kit once the mission knows
where the pad is.

- :meth:`LandingSensing.follow_pad` (each guidance tick): the landing fusion
  (:mod:`companion.delivery.fusion`) started on the pad the mission lands on, and again on the
  alternate after a divert; the first start also starts the devices and their tasks
  (:mod:`companion.delivery.sensor_tasks`, which call the two steps below).
- :meth:`LandingSensing.camera_step`: the newest frame, when vision is wanted, detected (on the
  executor, or inline in lock-step), then to the observers, the fusion and LANDING_TARGET.
- :meth:`LandingSensing.uwb_step`: the UWB readings multilaterated, to the observers and the fusion.
- :meth:`LandingSensing.pad_lock`: the pad's lock each tick, for the no-release-off-the-pad policy.
"""

from __future__ import annotations

import asyncio
import functools
import logging
import math
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Protocol

from companion.autopilot.interface import Autopilot, AutopilotError
from companion.autopilot.landing_target import LandingTargetBuilder, LandingTargetError
from companion.config import CompanionConfig
from companion.delivery.capture_latency import CaptureLatency
from companion.delivery.detection_pacer import DetectionPacer
from companion.delivery.detector_thread import cpu_timed

# the landing fusion's modules load with the shell, not when the fusion starts at take-off: their
# import (SciPy's LAPACK among them) would take the loop's CPU from guidance in flight
from companion.delivery.fusion import FusionSetup
from companion.delivery.hooks import ShellHooks
from companion.delivery.mission import DeliveryMission
from companion.delivery.observers import ShellObserver
from companion.delivery.pad_heading import pad_yaw_and_tolerance_rad
from companion.delivery.padlock import NO_SENSORS, PadLock, measure_pad_lock
from companion.delivery.sensor_tasks import SensorTasks
from companion.delivery.shell_stats import ShellStats
from companion.estimation.ekf import UpdateOutcome
from companion.events import Phase
from companion.geometry.mounts import pad_pose_ned
from companion.scheduling import LoopClock
from companion.uwb.measurements import UwbFix

log = logging.getLogger(__name__)


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


class Owner(Protocol):
    """What the landing sensing reads of the shell when it acts: the configuration and the
    mission, both replaced before flight when the delivery comes from the autopilot's mission."""

    config: CompanionConfig
    mission: DeliveryMission


class LandingSensing:
    def __init__(
        self,
        owner: Owner,
        kit: LandingKit | None,
        autopilot: Autopilot,
        clock: LoopClock,
        stats: ShellStats,
        hooks: ShellHooks,
        watching: Callable[[], list[ShellObserver]],
        marker_fused: asyncio.Event,
    ):
        """``watching``: the shell's observers, in order, when called; ``marker_fused``: set when a
        camera observation is fused while the fused estimate steers (guidance then ticks at once,
        ``[runtime] guidance_on_marker``)."""
        self.owner = owner
        self.kit = kit
        self.autopilot = autopilot
        self.clock = clock
        self.stats = stats
        self.hooks = hooks
        self.watching = watching
        self.marker_fused = marker_fused
        config = owner.config
        budget = config.runtime.vision_cpu_budget
        self.pacer = DetectionPacer(budget) if budget > 0.0 else None
        self.fusion: Any = None  # delivery.fusion.LandingFusion once the pad is known
        self.fusion_pad_index = 0  # mission.pad_index the fusion was started for
        self.sensors = SensorTasks(kit, clock, stats, self.camera_step, self.uwb_step, hooks.rate_loop)
        self.vision_always = False  # detect from the fusion's start, whatever the phase (see vision_wanted)
        self._landing_target: Any = None  # autopilot.landing_target.LandingTargetBuilder when sending
        # the pad's size for LANDING_TARGET, known before take-off (the layout's module loads OpenCV)
        self._landing_target_size_m: float | None = None
        if config.landing.landing_target_output != "off" and kit is not None:
            from companion.vision.pad import PadLayout

            self._landing_target_size_m = getattr(kit.detector, "layout", PadLayout()).outer_size_m
        self.landing_targets_sent = 0
        # each frame's exposure time for the fusion (landing.camera_time; configured: Frame.time_s)
        self.frame_time = CaptureLatency(config.landing.camera_time, config.landing.camera_latency_s)
        # [landing.drop_zone]: each detected frame also judged for an object on the pad or motion
        # around it (built before take-off: the check renders the printed pad once)
        self.drop_zone: Any = None  # delivery.drop_zone_watch.DropZoneWatch
        dz = config.landing.drop_zone
        if dz.enabled and kit is not None and kit.camera is not None and kit.detector is not None:
            from companion.delivery.drop_zone_watch import DropZoneWatch

            self.drop_zone = DropZoneWatch(kit.detector.camera, kit.detector.layout, dz)
        # [winch.camera]: while the line is out, each frame is also searched for the parcel's tag
        self.parcel_finder: Any = None  # vision.parcel_tag.ParcelTagFinder
        self.parcel: Any = None  # vision.parcel_tag.ParcelSighting, the newest
        self._parcel_tag: tuple[float, float, float] | None = None  # the last searched frame's find
        wcam = config.winch.camera
        if config.mission.delivery == "winch" and wcam.enabled and kit is not None and kit.detector is not None:
            from companion.vision.parcel_tag import ParcelTagFinder

            # (a tag that is one of the pad's markers is refused where the kit is built: landing_setup)
            self.parcel_finder = ParcelTagFinder(kit.detector.camera, wcam.tag_dict, wcam.tag_id, wcam.tag_size_m)

    def apply_opencv_threads(self) -> None:
        """``[runtime] opencv_threads``, process-wide, before the camera starts (with a camera or
        a detector in the kit)."""
        kit = self.kit
        if kit is not None and (kit.camera is not None or kit.detector is not None):
            from companion.vision.opencv_threads import apply_opencv_threads

            apply_opencv_threads(self.owner.config.runtime.opencv_threads)

    def follow_pad(self, now: float) -> None:
        """A guidance tick's first look at the pad: the fusion starts once the mission has its
        frame, and starts again when the mission diverts to the alternate pad."""
        mission = self.owner.mission
        if self.fusion is None and mission.frame is not None:
            self.start_fusion(now)
        elif self.fusion is not None and mission.pad_index != self.fusion_pad_index:
            self.start_fusion(now)  # diverted: the fusion starts again on the alternate pad

    def start_fusion(self, now: float) -> None:
        kit, config, mission = self.kit, self.owner.config, self.owner.mission
        assert kit is not None and mission.frame is not None
        pad = mission.frame.pad_ned
        # the camera and UWB see the pad the mission lands on: after a divert, the alternate (a new
        # EKF: the first pad's GPS-bias estimate says nothing about where the alternate lies)
        restart = self.fusion is not None
        if restart:
            self.autopilot.telemetry.remove_listener(self.fusion.on_sample)
        self.fusion_pad_index = mission.pad_index
        yaw, heading_tol = pad_yaw_and_tolerance_rad(config.mission, mission.pad_index)
        setup = FusionSetup(
            T_world_pad=pad_pose_ned(float(pad[0]), float(pad[1]), float(pad[2]), yaw_rad=yaw),
            heading_tolerance_rad=heading_tol,
            T_body_camera=kit.T_body_camera,
            T_pad_anchors=kit.T_pad_anchors,
            ekf=kit.ekf_config or config.landing.ekf,
            velocity_bias_tau_s=config.landing.ekf_velocity_bias_tau_s,
            velocity_bias_max_m_s=config.mission.velocity_bias_max_m_s,
            velocity_bias_source=config.mission.velocity_bias_source,
            level_pad=config.landing.ekf_level_pad,
            moving_pad=config.landing.moving_pad if config.landing.moving_pad.enabled else None,
        )
        self.fusion = self.hooks.fusion(setup, now)
        if self.drop_zone is not None:
            self.drop_zone.reset()  # a new pad: the markers seen and the votes were the other's
        if self._landing_target_size_m is not None:
            self._landing_target = LandingTargetBuilder(
                config.landing.landing_target_output,
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

    async def stop(self) -> None:
        """The sensors' tasks, then the devices (a device that fails to stop is said; the rest are
        still stopped). A dead task's error is raised before the devices are stopped."""
        await self.sensors.stop()
        if self.frame_time.mode.value != "configured":
            log.info("camera capture latency at the end of the flight: %s", self.frame_time.summary())
        if self.kit is not None:
            for dev in (self.kit.camera, self.kit.uwb):
                if dev is not None:
                    try:
                        dev.stop()
                    except Exception as err:  # the rest must still be closed
                        log.error("stopping %s failed: %s", type(dev).__name__, err)

    def pad_lock(self, now: float) -> PadLock:
        """The pad's lock for the mission's no-release-off-the-pad policy: none without a camera or
        UWB in the landing kit (GPS-only)."""
        kit = self.kit
        if kit is None or (kit.camera is None and kit.uwb is None):
            return NO_SENSORS
        if self.fusion is None:
            return PadLock(now, math.inf, math.inf)
        return measure_pad_lock(self.fusion, now)

    def vision_wanted(self) -> bool:
        """Detection from the approach on (sector 5 of the way out, the pad phases), or always
        with ``vision_always`` (benches and tests that measure the detector from the start)."""
        m = self.owner.mission
        return (
            self.vision_always
            or m.phase in (Phase.LANDING_PAD, Phase.PAD_HOLD, Phase.PAD_SEARCH, Phase.WINCH, Phase.DROP_ZONE_HOLD)
            or (m.phase in (Phase.OUTBOUND, Phase.DIVERT) and m.sector >= 5)
        )

    async def camera_step(self) -> None:
        """The camera's newest frame, when vision is wanted: detection (on the executor, or inline in
        lock-step), then the observation to the recorder, the fusion and the landing target."""
        kit = self.kit
        assert kit is not None and kit.camera is not None and kit.detector is not None and self.fusion is not None
        if not self.vision_wanted():
            return
        pacer, start_s = self.pacer, self.clock.now()
        if pacer is not None and not pacer.due(start_s):
            self.stats.frames_paced += 1
            return
        frame = kit.camera.read()
        if frame is None:
            return
        # the attitude moves the ROI with the vehicle's tilt always, and resolves the IPPE pair when
        # vision_attitude is set
        down_cam = self.down_in_camera()
        runtime = self.owner.config.runtime
        detect = functools.partial(
            cpu_timed,
            functools.partial(
                kit.detector.detect, down_cam=down_cam if kit.vision_attitude else None, roi_down_cam=down_cam
            ),
            nice=runtime.vision_thread_nice if kit.vision_in_thread else 0,
            realtime=runtime.realtime_priority if kit.vision_in_thread else 0,
        )
        exposure_s = self.frame_time.exposure_time_s(frame, start_s)
        m = self.owner.mission
        if self.drop_zone is not None and not m.summary.delivered and not m.returning:  # judged with the parcel aboard
            detect = functools.partial(self._detect_and_judge, detect, self._predicted_camera_pad())
        looking = self.parcel_finder is not None and self._parcel_wanted()
        if looking:
            detect = functools.partial(self._detect_and_find_parcel, detect)
        if kit.vision_in_thread:
            obs, cpu_s = await asyncio.get_running_loop().run_in_executor(None, detect, frame.image, exposure_s)
        else:
            obs, cpu_s = detect(frame.image, exposure_s)
        if pacer is not None:
            pacer.done(start_s, cpu_s)
        if looking and self._parcel_tag is not None:
            self._place_parcel(exposure_s, self._parcel_tag)
        if obs is None:
            return
        watching = self.watching()
        for ob in watching:
            ob.on_marker(self.clock.now(), obs, frame.image)
        outcome = self.fusion.on_marker(obs)
        for ob in watching:
            ob.on_marker_fused(self.clock.now(), obs, outcome)
        accepted = outcome is UpdateOutcome.ACCEPTED
        if accepted and self.owner.config.runtime.guidance_on_marker and self.owner.mission.fused_estimate_steers:
            self.marker_fused.set()
        if self._landing_target is not None:
            self.send_landing_target(obs)

    def _predicted_camera_pad(self) -> Any:
        from companion.delivery.drop_zone_watch import predicted_camera_pad

        assert self.kit is not None
        return predicted_camera_pad(self.fusion, self.kit.T_body_camera)

    def _detect_and_judge(
        self, detect: Callable[..., tuple[Any, float]], T_predicted: Any, image: Any, exposure_s: float
    ) -> tuple[Any, float]:
        """The detector, then the drop-zone check of the same frame (on the detector's thread in
        flight); the CPU time is both's, for the pacer."""
        obs, cpu_s = detect(image, exposure_s)
        if self.drop_zone is not None:
            _, check_s = cpu_timed(self.drop_zone.judge, image, exposure_s, obs, T_predicted)
            cpu_s += check_s
        return obs, cpu_s

    def _parcel_wanted(self) -> bool:
        """The parcel is looked for while the line may be out and it is not released."""
        m = self.owner.mission
        seq = m.winch
        return m.phase is Phase.WINCH and seq is not None and seq.paid_out and not seq.delivered

    def _detect_and_find_parcel(
        self, detect: Callable[..., tuple[Any, float]], image: Any, exposure_s: float
    ) -> tuple[Any, float]:
        """The detector (and what wraps it), then the parcel's tag in the same frame (on the
        detector's thread in flight); the CPU time is both's, for the pacer."""
        obs, cpu_s = detect(image, exposure_s)
        self._parcel_tag, find_s = cpu_timed(self.parcel_finder.find, image)
        return obs, cpu_s + find_s

    def _place_parcel(self, exposure_s: float, tag: tuple[float, float, float]) -> None:
        """The parcel's bottom above the pad from its tag and the fused pose (winch.camera)."""
        from companion.vision.parcel_tag import ParcelSighting, parcel_bottom_above_pad_m

        m, kit = self.owner.mission, self.kit
        est = self.fusion.estimate() if self.fusion is not None else None
        if est is None or m.frame is None or kit is None:
            return
        height = parcel_bottom_above_pad_m(
            tag,
            est.position_ned,
            (est.roll_rad, est.pitch_rad, est.yaw_rad),
            kit.T_body_camera,
            float(m.frame.pad_ned[2]),
            self.owner.config.winch.camera.parcel_height_m,
        )
        self.parcel = ParcelSighting(exposure_s, tag, height)

    def drop_zone_verdict(self, now: float) -> Any:
        """The drop-zone verdict for the mission (None: no check configured)."""
        return self.drop_zone.verdict(now) if self.drop_zone is not None else None

    def uwb_step(self) -> None:
        """The UWB readings since the last call, multilaterated, to the recorder and the fusion."""
        kit = self.kit
        assert kit is not None and kit.uwb is not None and kit.multilaterator is not None and self.fusion is not None
        for m in kit.uwb.read():
            meas = m.to_twr_measurement() if hasattr(m, "to_twr_measurement") else m
            res = kit.multilaterator.solve_twr(meas)
            if isinstance(res, UwbFix):
                for ob in self.watching():
                    ob.on_uwb(self.clock.now(), res)
                self.fusion.on_uwb(res)

    def down_in_camera(self) -> Any:
        """World down in the camera frame from the autopilot's latest attitude (None without one)."""
        from companion.geometry import euler_to_rotmat
        from companion.vision.detector import down_in_camera

        att = self.autopilot.telemetry.attitude
        if att is None or self.kit is None:
            return None
        R_wb = euler_to_rotmat(att.roll_rad, att.pitch_rad, att.yaw_rad)
        return down_in_camera(R_wb, self.kit.T_body_camera.R)

    def send_landing_target(self, obs: Any) -> None:
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

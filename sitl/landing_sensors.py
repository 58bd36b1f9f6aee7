"""Simulated landing sensors behind the plugin interface (api_version 1): a downward camera that
renders real images of the pad, and a DWM1001-like UWB tag ranging to the anchors around it.

Both are fed by simulator truth. The true pose is snapshotted at each exposure / ranging instant
(a cheap task on the shell's clock), so a frame's pixels show the vehicle where it was at
exposure, and it becomes readable only after the capture latency. The camera skips exposures in
which the pad is outside the field of view (the detector would find nothing; rendering them would
only burn CPU in simulation).

Once started, the camera renders each exposure's scene through the lens on a thread of its own as
soon as the pose is known (OpenCV releases the GIL: the event loop runs on meanwhile); the frame
is finished (gain, exposure noise from the camera's seeded generator) when the shell reads it, in
the order the frames are read, so the frames are the ones rendered on read, bit for bit. At most
``_AHEAD_KEPT`` unread renders are kept (the newest); an older exposure read later is rendered then.
Exposures are rendered ahead only while the camera is read (``read()`` called since the previous
exposure, or a frame listener attached): before the shell wants vision, the exposures in view would
be rendered and never read; the first frame read after such a gap is rendered on read.

The camera offers the frame-listener capability (version 1, :mod:`companion.plugin_api`): with a
listener attached it is called on the event loop when a frame's capture latency has elapsed (the
frame is readable), as a real camera's capture thread calls it when a frame arrives; its optics were
rendered during that latency, so neither the application's latency nor its event loop carries the
simulator's rendering. The lock-step simulation never attaches one (its shell polls).
"""

from __future__ import annotations

import asyncio
import contextlib
import functools
import logging
import math
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from companion.delivery.hooks import RateLoopFactory, StageTimer, untimed
from companion.delivery.shell import LandingKit
from companion.geometry.se3 import Transform
from companion.plugin_api import FRAME_LISTENER_VERSION, Frame, FrameListenerSlot
from companion.scheduling import LoopClock, RateLoop
from companion.uwb.measurements import TwrMeasurement
from companion_sitl.camera import SimulatedCamera, U8Image
from companion_sitl.camera_conditions import CameraConditions, FrameFate, pad_velocity_px_s
from companion_sitl.camera_occluders import OCCLUDER_STREAM, Occluder, draw_occluder
from companion_sitl.camera_parcel import ParcelLook, ParcelPainter
from companion_sitl.pad_motion import PadTrack, pad_track
from companion_sitl.params import SimOccluderConfig, SimulatedConfig
from companion_sitl.uwb import SimulatedUwb
from companion_sitl.vehicle import SimVehicle
from companion_sitl.winch import STOWED_M

if TYPE_CHECKING:
    from companion.vision.pad import PadLayout

log = logging.getLogger(__name__)


_AHEAD_KEPT = 4  # exposures rendered ahead and not read yet that are kept (the newest)


def _truth_pose(v: SimVehicle) -> Transform:
    return Transform.from_euler((v.pn, v.pe, v.pd), v.roll, v.pitch, v.yaw)


@dataclass(frozen=True)
class SimSensorHooks:
    """How a bench instruments the simulated sensors (the defaults: as every simulation runs).

    ``stage_timer`` (``(stage, fn) -> fn``, see :mod:`companion.delivery.hooks`) wraps the
    simulator's own work, once at construction: ``"sim_render"`` (the image finished or rendered
    on read), ``"sim_sensors"`` (the true pose, the pad in the camera frame, the field-of-view
    test), ``"sim_uwb"`` (the ranges). ``rate_loop`` builds the sensors' exposure and ranging
    loops. ``every_exposure``: every exposure with the camera above the pad plane is rendered and
    readable, the pad in view or not (the detector then also searches frames without the pad)."""

    stage_timer: StageTimer | None = None
    rate_loop: RateLoopFactory = RateLoop
    every_exposure: bool = False


class SimCameraSource:
    api_version: ClassVar[int] = 1
    frame_listener_version: ClassVar[int] = FRAME_LISTENER_VERSION

    def __init__(
        self,
        vehicle: SimVehicle,
        camera: SimulatedCamera,
        rate_hz: float = 30.0,
        latency_s: float = 0.05,
        fails_below_m: float = 0.0,
        range_m: float = 0.0,
        hooks: SimSensorHooks | None = None,
        conditions: CameraConditions | None = None,
        unknown_latency_s: float = 0.0,
        driver_stamp: bool = False,
        occluder: Occluder | None = None,
        occluder_from_height_m: float = 0.0,
        pad_track: PadTrack | None = None,
        parcel: ParcelPainter | None = None,
        parcel_at: Callable[[], tuple[float, float, float] | None] | None = None,
    ):
        """``latency_s``: the latency the configuration knows (``landing.camera_latency_s``);
        ``unknown_latency_s``: what the frames take on top of it, which the configuration does not
        know (``[sim.camera] unknown_latency_s``): a frame is readable ``latency_s +
        unknown_latency_s`` after its exposure, and stamped as a driver without a stamp of its own
        stamps it (its arrival minus ``latency_s``); ``driver_stamp``: the frame also carries the
        driver's honest capture stamp (the exposure) and its arrival (docs/clock.md); ``occluder``:
        painted into each frame before the exposure, its clock starting at the first frame read with
        the pad in view and the vehicle below ``occluder_from_height_m`` (0: any height;
        ``[sim.camera.occluder]``, docs/drop-zone.md); ``pad_track``: the pad moves
        (``[sim.pad_motion]``): each exposure sees it where it is at that instant; ``parcel``: the
        parcel painted where ``parcel_at()`` (world NED of its bottom, None: in its bay) has it at
        each exposure (``[sim.winch] draw_parcel``; by default the sim vehicle's parcel)."""
        if not (math.isfinite(unknown_latency_s) and 0.0 <= unknown_latency_s <= 1.0):
            raise ValueError(f"unknown_latency_s = {unknown_latency_s!r}: expected finite, within [0, 1] s")
        self.vehicle = vehicle
        self.pad_track = pad_track
        # a real camera's effects ([sim.camera]): None or inactive, the renderer's frames bit for bit
        self.conditions = conditions if conditions is not None and conditions.active else None
        self._fates: dict[float, tuple[FrameFate, tuple[float, float]]] = {}  # exposure -> fate, image velocity
        self._prev_pad: tuple[float, np.ndarray] | None = None
        self.fails_below_m = fails_below_m  # a failed camera: no frame below this true height (0: never)
        self.range_m = range_m  # no frame above this true height (0: unlimited)
        self.camera = camera
        self.rate_hz = rate_hz
        self.latency_s = latency_s
        self.unknown_latency_s = float(unknown_latency_s)
        self.driver_stamp = driver_stamp
        self.occluder = occluder if occluder is not None and occluder.kind != "none" else None
        self._occluder_t0: float | None = None  # the first frame read with the pad in view
        self._occluder_from_height_m = float(occluder_from_height_m)
        if parcel is not None and parcel_at is None and getattr(vehicle, "parcel", None) is not None:
            parcel_at = functools.partial(sim_parcel_bottom, vehicle)
        self.parcel = parcel if parcel_at is not None else None
        self._parcel_where = parcel_at
        self._parcel_at: dict[float, tuple[float, float, float]] = {}  # exposure -> the parcel's bottom, NED
        # exposure -> readable (x + 0.0 is x: without an unknown latency, the same floats as before)
        self._delivery_s = latency_s + self.unknown_latency_s
        self._clock = LoopClock()
        # (exposure time, T_world_body, T_camera_pad when computed at the exposure, else None)
        self._poses: deque[tuple[float, Transform, Transform | None]] = deque(maxlen=64)
        self._task: asyncio.Task[None] | None = None
        # the optics of the exposures in view, rendered ahead on one thread (the camera's buffers
        # take one render at a time), by exposure time
        self._renderer: ThreadPoolExecutor | None = None
        self._renders: dict[float, Future[U8Image]] = {}
        self._listener = FrameListenerSlot("simulated")
        self._index = 0
        self._last_read_t = -math.inf
        self._polled = False  # read() called since the last exposure
        self.exposures = 0
        self.rendered = 0
        self.out_of_view = 0
        cam = camera.camera
        self._half_fov_x = math.atan2(cam.width_px / 2.0, cam.fx)
        self._half_fov_y = math.atan2(cam.height_px / 2.0, cam.fy)
        self.frames_dropped = 0  # exposures that became readable and were never read (a newer one was)
        h = hooks or SimSensorHooks()
        timed = h.stage_timer or untimed
        self._rate_loop = h.rate_loop
        self.rate_loop: RateLoop | None = None  # the exposures' loop, once started
        self._truth_pose = timed("sim_sensors", _truth_pose)
        self._camera_pad = timed("sim_sensors", camera.T_camera_pad)
        self._in_view = timed("sim_sensors", self._above_pad if h.every_exposure else self._pad_in_view)
        self._expose = timed("sim_render", camera.expose)
        self._capture = timed("sim_render", camera.capture)
        self._render = timed("sim_render", camera.render)

    @property
    def pending_renders(self) -> int:
        """Exposures in view rendered ahead (or being rendered) on the render thread, not yet read."""
        return len(self._renders)

    @property
    def render_thread_running(self) -> bool:
        """The render thread is up: :meth:`start` ran and :meth:`stop` has not."""
        return self._renderer is not None

    def start(self) -> None:
        self._renderer = ThreadPoolExecutor(1, thread_name_prefix="sim-camera-render")
        self._task = asyncio.get_running_loop().create_task(self._run(), name="sim-camera")

    def set_frame_listener(self, callback: Callable[[], None] | None) -> None:
        """``callback()`` on the event loop when each frame becomes readable (None detaches)."""
        self._listener.set(callback)

    async def _run(self) -> None:
        rate = self.rate_loop = self._rate_loop(self._clock, self.rate_hz)
        loop = asyncio.get_running_loop()
        while True:
            t = await rate.tick()
            self.vehicle.step_to(t)
            T = self._truth_pose(self.vehicle)
            self.exposures += 1
            # rendered ahead while someone reads (polled since the last exposure, or a listener is
            # told): an unpolled camera's exposures (vision not wanted yet) would render unread
            polled, self._polled = self._polled, False
            T_cp = None
            if self.pad_track is not None:  # the pad where it is now; T_cp kept with the pose for read()
                self.camera.T_world_pad = self.pad_track.pose(t)
                T_cp = self._camera_pad(T)
            if self._renderer is not None and (polled or self._listener.attached):
                if T_cp is None:
                    T_cp = self._camera_pad(T)  # kept with the pose: read() needs it again
                if self._in_view(T_cp):
                    self._renders[t] = self._renderer.submit(self.camera.render_optics, T_cp, fresh=True)
                    if len(self._renders) > _AHEAD_KEPT:  # not read (vision not wanted): the oldest goes
                        self._renders.pop(next(iter(self._renders))).cancel()
            self._poses.append((t, T, T_cp))
            if self.parcel is not None:
                self._note_parcel(t)
            late = 0.0
            if self.conditions is not None:
                late = self._draw_fate(t, T_cp if T_cp is not None else self._camera_pad(T))
                if late < 0:  # dropped by the driver: never readable
                    continue
            if self._listener.attached:
                loop.call_at(t + self._delivery_s + late, self._frame_ready, t)

    def _draw_fate(self, t: float, T_cp: Transform) -> float:
        """The exposure's fate under the conditions and its image velocity, kept for read(): the
        extra latency, or -1 when the driver drops it."""
        assert self.conditions is not None
        fate = self.conditions.fate()
        cam = self.camera.camera
        prev = self._prev_pad
        v = pad_velocity_px_s(
            cam.fx, cam.fy, cam.cx, cam.cy, None if prev is None else prev[1], T_cp.t, t - prev[0] if prev else 0.0
        )
        self._prev_pad = (t, T_cp.t.copy())
        self._fates[t] = (fate, v)
        while len(self._fates) > 64:
            self._fates.pop(next(iter(self._fates)))
        return -1.0 if fate.dropped else fate.extra_latency_s

    def _late_s(self, t: float) -> float:
        """Extra latency of the exposure at ``t``; inf when the driver dropped it."""
        got = self._fates.get(t)
        if got is None:
            return 0.0
        return math.inf if got[0].dropped else got[0].extra_latency_s

    def _frame_ready(self, exposure_s: float) -> None:
        """The frame exposed at ``exposure_s`` is readable now: tell the listener."""
        if self._task is None:  # stopped meanwhile
            return
        ready_s = exposure_s + self._delivery_s + (self._late_s(exposure_s) if self.conditions is not None else 0.0)
        if self._clock.now() < ready_s:  # asyncio may run a timer up to its clock resolution early
            asyncio.get_running_loop().call_at(ready_s, self._frame_ready, exposure_s)
            return
        self._listener.notify()

    def _pad_in_view(self, T_camera_pad: Transform) -> bool:
        """The pad (within half a metre of its centre) is in the camera's field of view, the camera
        above the pad's plane (a vehicle on a real SITL's ground, the pad beside it: level with it)."""
        p = T_camera_pad.t
        if p[2] <= 0.05:
            return False
        if float((-T_camera_pad.R.T @ p)[2]) <= 1e-3:  # the renderer's own bound (it would refuse)
            return False
        margin = 0.5 / p[2]  # half a metre around the pad centre
        return (
            abs(math.atan(p[0] / p[2])) < self._half_fov_x + margin
            and abs(math.atan(p[1] / p[2])) < self._half_fov_y + margin
        )

    def _above_pad(self, T_camera_pad: Transform) -> bool:
        """The camera above the pad plane (SimSensorHooks.every_exposure; on the ground it is not)."""
        T = T_camera_pad
        return float((-T.R.T @ T.t)[2]) > 0.05

    def read(self) -> Frame | None:
        """The newest frame whose capture latency has elapsed (older ones are dropped)."""
        if self.fails_below_m > 0.0 or self.range_m > 0.0:  # a simulated failure or a short range
            h = -self.vehicle.pd
            if (self.fails_below_m > 0.0 and h < self.fails_below_m) or (self.range_m > 0.0 and h > self.range_m):
                return None  # failed, or out of range: nothing rendered, nothing read
        self._polled = True
        now = self._clock.now()
        # the newest pose that is ready and not read yet; the poses are in exposure-time order, so
        # the scan from the newest stops at the first one already read
        pose = None
        unread = 0  # ready poses older than the newest: dropped once it is read
        for p in reversed(self._poses):
            if p[0] <= self._last_read_t:
                break
            late = self._late_s(p[0]) if self.conditions is not None else 0.0
            if late == math.inf:  # dropped by the driver: it never was a frame
                continue
            if pose is not None:
                unread += 1
            elif p[0] + self._delivery_s + late <= now:
                pose = p
        if pose is None:
            return None
        self.frames_dropped += unread
        t, T, T_cp = pose
        self._last_read_t = t
        ahead = self._renders.pop(t, None)
        for k in [k for k in self._renders if k < t]:  # exposures dropped unread
            self._renders.pop(k).cancel()
        if T_cp is None:
            T_cp = self._camera_pad(T)
        if not self._in_view(T_cp):
            self.out_of_view += 1
            return None
        if ahead is None and self._renderer is not None:  # (not polled before this exposure: none)
            ahead = self._renderer.submit(self.camera.render_optics, T_cp, fresh=True)
        if self.conditions is not None or self.occluder is not None or self.parcel is not None:
            image = self._with_conditions(t, T_cp, ahead, T)
        else:  # not started (no renderer): rendered here, as capture() does
            image = (
                self._expose(ahead.result())
                if ahead is not None
                else self._capture(T, t).image
                if self.pad_track is None
                else self._render(T_cp)
            )
        self.rendered += 1
        self._index += 1
        if not self.driver_stamp and self.unknown_latency_s == 0.0:
            return Frame(t, image, self._index)
        # a driver without a stamp of its own stamps the arrival minus the configured latency (the
        # extra latency of [sim.camera] late_s, the driver's own, is known to it as before)
        late = self._late_s(t) if self.conditions is not None else 0.0
        return Frame(
            t + self.unknown_latency_s,
            image,
            self._index,
            capture_time_s=t if self.driver_stamp else None,
            arrival_time_s=t + self._delivery_s + late if self.driver_stamp else None,
        )

    def _note_parcel(self, t: float) -> None:
        """The parcel's bottom at the exposure ``t``, kept for read() while it is out of its bay."""
        assert self._parcel_where is not None
        where = self._parcel_where()
        if where is not None:
            self._parcel_at[t] = where
        while len(self._parcel_at) > 64:
            self._parcel_at.pop(next(iter(self._parcel_at)))

    def _with_conditions(
        self, t: float, T_cp: Transform, ahead: Future[U8Image] | None, T_world_body: Transform | None = None
    ) -> U8Image:
        """The frame as the real camera gives it: motion on the optics, exposure, then the rest."""
        optics = ahead.result() if ahead is not None else self.camera.render_optics(T_cp, fresh=True)
        if self.occluder is not None:
            if self._occluder_t0 is None and (
                self._occluder_from_height_m <= 0.0 or -self.vehicle.pd < self._occluder_from_height_m
            ):
                self._occluder_t0 = t
                log.info("simulated camera: the %s's clock starts at t=%.2f s", self.occluder.kind, t)
            if self._occluder_t0 is not None:
                optics = self.occluder.paint(optics, self.camera.camera, T_cp, t - self._occluder_t0)
        bottom = self._parcel_at.get(t) if self.parcel is not None else None
        if bottom is not None and T_world_body is not None:  # hanging above whatever is on the ground
            assert self.parcel is not None
            optics = self.parcel.paint(optics, self.camera.camera, self.camera.T_world_camera(T_world_body), bottom)
        if self.conditions is None:
            return self._expose(optics)
        got = self._fates.get(t)
        velocity = got[1] if got is not None else (0.0, 0.0)
        return self.conditions.photometric(self._expose(self.conditions.motion(optics, velocity)), t)

    def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            self._task = None
        if self._renderer is not None:
            self._renderer.shutdown(wait=True, cancel_futures=True)
            self._renderer = None
        self._renders.clear()


class SimUwbSource:
    api_version: ClassVar[int] = 1

    def __init__(
        self,
        vehicle: SimVehicle,
        uwb: SimulatedUwb,
        T_world_anchors_true: Transform,
        rate_hz: float = 10.0,
        fails_below_m: float = 0.0,
        hooks: SimSensorHooks | None = None,
        pad_track: PadTrack | None = None,
    ):
        """``pad_track``: the pad moves (``[sim.pad_motion]``) and the anchors with it, fixed on it
        as ``T_world_anchors_true`` places them on the standing pad."""
        self.vehicle = vehicle
        self.pad_track = pad_track
        self.fails_below_m = fails_below_m  # a failed UWB: no ranging below this true height (0: never)
        self.uwb = uwb
        h = hooks or SimSensorHooks()
        self._twr = (h.stage_timer or untimed)("sim_uwb", uwb.twr)
        self._rate_loop = h.rate_loop
        self.rate_loop: RateLoop | None = None  # the ranging loop, once started
        self.T_anchors_world = T_world_anchors_true.inverse()
        if pad_track is not None:  # the anchors in the standing pad's frame: T_pad_anchors
            self._T_pad_anchors = pad_track.standing_pose().inverse() @ T_world_anchors_true
        self.rate_hz = rate_hz
        self._clock = LoopClock()
        self._out: list[TwrMeasurement] = []
        self._task: asyncio.Task[None] | None = None
        self.samples = 0

    def start(self) -> None:
        self._task = asyncio.get_running_loop().create_task(self._run(), name="sim-uwb")

    async def _run(self) -> None:
        rate = self.rate_loop = self._rate_loop(self._clock, self.rate_hz)
        while True:
            t = await rate.tick()
            self.vehicle.step_to(t)
            if self.fails_below_m > 0.0 and -self.vehicle.pd < self.fails_below_m:
                continue
            if self.pad_track is not None:
                self.T_anchors_world = (self.pad_track.pose(t) @ self._T_pad_anchors).inverse()
            tag = self.T_anchors_world.apply(np.array([self.vehicle.pn, self.vehicle.pe, self.vehicle.pd]))
            m = self._twr(t, tag)
            if len(m.anchor_ids) > 0:
                self._out.append(m)
                self.samples += 1
                if len(self._out) > 50:
                    del self._out[:-50]

    def read(self) -> list[TwrMeasurement]:
        out, self._out = self._out, []
        return out

    def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            with contextlib.suppress(Exception):
                self._task = None


@dataclass(frozen=True)
class CameraPlayback:
    """Hardware-in-the-loop with a recorded camera: the landing camera is replaced by ``video``
    played through the OpenCV camera plugin at its own frame times on the simulated clock.

    ``times``: the ``frame,time_s`` CSV of exposure times (None: the container's timestamps);
    ``time_offset_s`` is added to them (the recording's clock -> the simulated one; 0 for a
    recording of a simulated flight, whose clock starts where this one does). ``calibration``:
    the camera TOML for the detector (e.g. from ``companion calibrate``; None:
    ``landing.camera_calibration``)."""

    video: Path
    times: Path | None = None
    time_offset_s: float = 0.0
    calibration: str | None = None


def sim_occluder(config: SimOccluderConfig, layout: PadLayout, margin_m: float, seed: int) -> Occluder | None:
    """``[sim.camera.occluder]``'s occluder, drawn from the scenario's seed (None: none)."""
    if config.kind == "none":
        return None
    rng = np.random.default_rng([seed, OCCLUDER_STREAM])
    occ = draw_occluder(config.kind, rng, pad_size_m=layout.pad_size_m, margin_m=margin_m, duration_s=config.window_s)
    log.info("simulated camera: a %s in the frames (%s)", occ.kind, occ)
    return occ


def sim_parcel_bottom(vehicle: SimVehicle) -> tuple[float, float, float] | None:
    """The sim vehicle's parcel's bottom (world NED) once it is out of its bay, else None."""
    parcel, winch = vehicle.parcel, vehicle.winch
    if parcel is None or winch is None:
        return None
    if winch.length_m >= STOWED_M or parcel.on_ground or parcel.caught:
        return (parcel.p[0], parcel.p[1], parcel.p[2])
    return None


def sim_parcel_painter(config: SimulatedConfig) -> ParcelPainter | None:
    """``[sim.winch] draw_parcel``'s parcel, its tag the one ``[winch.camera]`` describes (None: not drawn)."""
    sw = config.sim.winch
    if not sw.draw_parcel:
        return None
    wc = config.winch.camera
    return ParcelPainter(
        ParcelLook(
            sw.parcel_size_m,
            sw.parcel_height_m,
            tag_dict=wc.tag_dict,
            tag_id=wc.tag_id if sw.parcel_tag else -1,
            tag_size_m=wc.tag_size_m,
        )
    )


def sim_landing_kit(
    config: SimulatedConfig,
    vehicle: SimVehicle,
    true_pad_ne: tuple[float, float],
    camera_playback: CameraPlayback | None = None,
    record_camera: Path | None = None,
    hooks: SimSensorHooks | None = None,
    parcel_at: Callable[[], tuple[float, float, float] | None] | None = None,
    track: PadTrack | None = None,
) -> LandingKit:
    """Simulated camera and UWB around the *true* pad, with the real detector and solver; the
    anchors are ``landing.uwb_anchors`` (as on the vehicle).

    ``track``: the moving pad's track the sensors render from (None: ``[sim.pad_motion]``'s from
    ``true_pad_ne``, on the clock from 0); a real-firmware harness passes its own to set the
    track's clock origin and stop it at the ground contact.

    ``camera_playback``: the camera is the OpenCV camera plugin playing a recorded file on the
    simulated clock, with the detector on that file's calibration; ``record_camera``: the
    simulated camera's frames are recorded as they are read. ``hooks``: a bench's instruments of
    the simulated sensors (:class:`SimSensorHooks`). ``parcel_at``: where the drawn parcel's bottom
    is (``[sim.winch] draw_parcel``; None: the sim vehicle's parcel)."""
    from companion.delivery.landing_setup import LandingSetupError, check_parcel_tag, resolve_params_file
    from companion.geometry.mounts import downward_mount, pad_pose_ned
    from companion.plugin_api import PluginError, create
    from companion.scheduling import LoopClock
    from companion.uwb.anchors import load_anchor_layout
    from companion.uwb.multilateration import Multilaterator
    from companion.vision.camera import CameraConfigError, load_camera, load_default_camera
    from companion.vision.detector import PadDetector
    from companion.vision.pad import PadLayout
    from companion_sitl.camera import SimulatedCamera
    from companion_sitl.landing_sensors import SimCameraSource, SimUwbSource
    from companion_sitl.scoring import true_pad_heading_rad
    from companion_sitl.uwb import SimulatedUwb

    lc = config.landing
    seed = config.sim.seed
    T_world_pad_true = pad_pose_ned(true_pad_ne[0], true_pad_ne[1], 0.0, yaw_rad=true_pad_heading_rad(config))
    if track is None:
        track = pad_track(config.sim.pad_motion, true_pad_ne[0], true_pad_ne[1], true_pad_heading_rad(config))
    mount = downward_mount(lc.camera_offset_body_m)
    cam_model = load_default_camera()
    layout = PadLayout()
    camera = uwb = detector = multi = None
    if (camera_playback is not None or record_camera is not None) and not lc.use_camera:
        raise LandingSetupError("a camera file is played or recorded but landing.use_camera = false")
    if camera_playback is not None and record_camera is not None:
        raise LandingSetupError("play a camera file or record one, not both in one flight")
    if lc.use_camera and camera_playback is not None:
        calib = camera_playback.calibration or lc.camera_calibration
        try:
            det_model = load_camera(resolve_params_file(calib, "camera_calibration"))
        except CameraConfigError as err:
            raise LandingSetupError(f"camera calibration {calib!r}: {err}") from None
        try:
            camera = create(
                "companion.cameras",
                "opencv",
                source=str(camera_playback.video),
                width_px=det_model.width_px,
                height_px=det_model.height_px,
                latency_s=lc.camera_latency_s,
                clock=LoopClock().now,
                playback=True,
                frame_times=camera_playback.times,
                time_offset_s=camera_playback.time_offset_s,
            )
            camera.start()  # check the file before take-off (start is idempotent: the shell's is a no-op)
        except PluginError as err:
            raise LandingSetupError(f"camera file {camera_playback.video}: {err}") from err
        markers = ("outer", "inner") if lc.markers == "both" else (lc.markers,)
        detector = PadDetector(det_model, layout, lc.detector, markers=markers)
    elif lc.use_camera:
        sim_cam = SimulatedCamera(cam_model, layout, T_body_camera=mount, T_world_pad=T_world_pad_true, seed=seed)
        camera = SimCameraSource(
            vehicle,
            sim_cam,
            lc.camera_rate_hz,
            lc.camera_latency_s,
            fails_below_m=config.sim.camera_fails_below_m,
            range_m=config.sim.camera_range_m,
            hooks=hooks,
            conditions=CameraConditions(config.sim.camera, seed),
            unknown_latency_s=config.sim.camera.unknown_latency_s,
            driver_stamp=config.sim.camera.driver_stamp,
            occluder=sim_occluder(config.sim.camera.occluder, layout, lc.drop_zone.margin_m, seed),
            occluder_from_height_m=config.sim.camera.occluder.from_height_m,
            pad_track=track,
            parcel=sim_parcel_painter(config),
            parcel_at=parcel_at,
        )
        if record_camera is not None:
            from companion.flightlog.camera_file import CameraFileError, CameraFileWriter, RecordingCamera

            try:
                writer = CameraFileWriter(record_camera, fps=lc.camera_rate_hz)
            except (CameraFileError, OSError) as err:
                raise LandingSetupError(f"recording the camera: {err}") from None
            camera = RecordingCamera(camera, writer)
        markers = ("outer", "inner") if lc.markers == "both" else (lc.markers,)
        detector = PadDetector(cam_model, layout, lc.detector, markers=markers)
        check_parcel_tag(config, layout)
    anchors = load_anchor_layout(resolve_params_file(lc.uwb_anchors, "uwb_anchors"))
    if lc.use_uwb:
        uwb = SimUwbSource(
            vehicle,
            SimulatedUwb(anchors, seed=seed + 1),
            T_world_pad_true,
            lc.uwb_rate_hz,
            fails_below_m=config.sim.uwb_fails_below_m,
            hooks=hooks,
            pad_track=track,
        )
        multi = Multilaterator(anchors, lc.multilateration)
    from companion.geometry.se3 import Transform

    return LandingKit(
        camera,
        uwb,
        detector,
        multi,
        mount,
        Transform.identity(),
        vision_in_thread=False,
        vision_attitude=lc.vision_attitude,
    )

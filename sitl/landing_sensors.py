"""Simulated landing sensors behind the plugin interface (api_version 1): a downward camera that
renders real images of the pad, and a DWM1001-like UWB tag ranging to the anchors around it.

Both are fed by simulator truth. The true pose is snapshotted at each exposure / ranging instant
(a cheap task on the shell's clock); a frame is rendered only when the shell reads it, so its
pixels show the vehicle where it was at exposure, and it becomes readable only after the capture
latency. The camera skips exposures in which the pad is outside the field of view (the detector
would find nothing; rendering them would only burn CPU in simulation).

The camera offers the frame-listener capability (version 1, :mod:`companion.plugin_api`): with a
listener attached it is called on the event loop when a frame's capture latency has elapsed (the
frame is readable), as a real camera's capture thread calls it when a frame arrives. While one is
attached (real time), each exposure in view is also rendered during its capture latency on a
render thread of its own, so that, as from a real camera, the frame is whole when it is announced:
neither the application's latency nor its event loop carries the simulator's rendering. The
lock-step simulation never attaches one (its shell polls), so it runs exactly as without.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import threading
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import ClassVar

import numpy as np

from companion.geometry.se3 import Transform
from companion.plugin_api import FRAME_LISTENER_VERSION, Frame, FrameListenerSlot
from companion.scheduling import LoopClock, RateLoop
from companion.uwb.multilateration import TwrMeasurement
from companion_sitl.camera import SimulatedCamera
from companion_sitl.uwb import SimulatedUwb
from companion_sitl.vehicle import SimVehicle

log = logging.getLogger(__name__)


_AHEAD_KEPT = 4  # frames rendered ahead and not read yet that are kept (the newest)


def _truth_pose(v: SimVehicle) -> Transform:
    return Transform.from_euler((v.pn, v.pe, v.pd), v.roll, v.pitch, v.yaw)


class SimCameraSource:
    api_version: ClassVar[int] = 1
    frame_listener_version: ClassVar[int] = FRAME_LISTENER_VERSION

    def __init__(self, vehicle: SimVehicle, camera: SimulatedCamera, rate_hz: float = 30.0, latency_s: float = 0.05):
        self.vehicle = vehicle
        self.camera = camera
        self.rate_hz = rate_hz
        self.latency_s = latency_s
        self._clock = LoopClock()
        self._poses: deque[tuple[float, Transform]] = deque(maxlen=64)
        self._task: asyncio.Task[None] | None = None
        self._index = 0
        self._last_read_t = -math.inf
        self._listener = FrameListenerSlot("simulated")
        # real time, with a listener: exposure time -> its frame rendered ahead (None: out of view)
        self._ahead: dict[float, Future[Frame | None]] = {}
        self._render_pool: ThreadPoolExecutor | None = None
        self._render_lock = threading.Lock()  # one render at a time (the camera's buffers and noise)
        self.exposures = 0
        self.rendered = 0
        self.out_of_view = 0
        cam = camera.camera
        self._half_fov_x = math.atan2(cam.width_px / 2.0, cam.fx)
        self._half_fov_y = math.atan2(cam.height_px / 2.0, cam.fy)

    def start(self) -> None:
        self._task = asyncio.get_running_loop().create_task(self._run(), name="sim-camera")

    def set_frame_listener(self, callback: Callable[[], None] | None) -> None:
        """``callback()`` on the event loop when each frame becomes readable (None detaches)."""
        self._listener.set(callback)

    async def _run(self) -> None:
        rate = RateLoop(self._clock, self.rate_hz)
        loop = asyncio.get_running_loop()
        while True:
            t = await rate.tick()
            self.vehicle.step_to(t)
            self._poses.append((t, _truth_pose(self.vehicle)))
            self.exposures += 1
            if self._listener.attached:
                if self._render_pool is None:
                    self._render_pool = ThreadPoolExecutor(1, thread_name_prefix="sim-camera-render")
                self._ahead[t] = self._render_pool.submit(self._render, t, self._poses[-1][1])
                if len(self._ahead) > _AHEAD_KEPT:  # not read (vision not wanted): the oldest goes
                    del self._ahead[next(iter(self._ahead))]
                loop.call_at(t + self.latency_s, self._frame_ready, t)

    def _render(self, t: float, T_world_body: Transform) -> Frame | None:
        """The frame exposed at ``t`` (index not yet given), or None when the pad is out of view."""
        if not self._in_view(T_world_body):
            return None
        with self._render_lock:
            image = self.camera.capture(T_world_body, t).image
        return Frame(t, image, 0)

    def _frame_ready(self, exposure_s: float) -> None:
        """The frame exposed at ``exposure_s`` is readable now: tell the listener."""
        if self._task is None:  # stopped meanwhile
            return
        ready_s = exposure_s + self.latency_s
        if self._clock.now() < ready_s:  # asyncio may run a timer up to its clock resolution early
            asyncio.get_running_loop().call_at(ready_s, self._frame_ready, exposure_s)
            return
        self._listener.notify()

    def _in_view(self, T_world_body: Transform) -> bool:
        p = self.camera.T_camera_pad(T_world_body).t
        if p[2] <= 0.05:
            return False
        margin = 0.5 / p[2]  # half a metre around the pad centre
        return (
            abs(math.atan(p[0] / p[2])) < self._half_fov_x + margin
            and abs(math.atan(p[1] / p[2])) < self._half_fov_y + margin
        )

    def read(self) -> Frame | None:
        """The newest frame whose capture latency has elapsed (older ones are dropped)."""
        now = self._clock.now()
        # the newest pose that is ready and not read yet; the poses are in exposure-time order, so
        # the scan from the newest stops at the first one already read
        pose = None
        for p in reversed(self._poses):
            if p[0] <= self._last_read_t:
                break
            if p[0] + self.latency_s <= now:
                pose = p
                break
        if pose is None:
            return None
        t, T = pose
        self._last_read_t = t
        if self._ahead:  # real time with a listener: the frame was rendered during its capture latency
            ahead = self._ahead.pop(t, None)
            for old in [k for k in self._ahead if k < t]:  # passed over: dropped, as a live camera drops them
                del self._ahead[old]
            if ahead is not None:
                done = ahead.result()  # rendered by now (it had the capture latency); else waits for it
                if done is None:
                    self.out_of_view += 1
                    return None
                self.rendered += 1
                self._index += 1
                return Frame(t, done.image, self._index)
        if not self._in_view(T):
            self.out_of_view += 1
            return None
        with self._render_lock:
            frame = self.camera.capture(T, t)
        self.rendered += 1
        self._index += 1
        return Frame(t, frame.image, self._index)

    def stop(self) -> None:
        if self._task is not None:
            self._task.cancel()
            self._task = None
        if self._render_pool is not None:
            self._render_pool.shutdown(wait=True, cancel_futures=True)
            self._render_pool = None
        self._ahead.clear()


class SimUwbSource:
    api_version: ClassVar[int] = 1

    def __init__(self, vehicle: SimVehicle, uwb: SimulatedUwb, T_world_anchors_true: Transform, rate_hz: float = 10.0):
        self.vehicle = vehicle
        self.uwb = uwb
        self.T_anchors_world = T_world_anchors_true.inverse()
        self.rate_hz = rate_hz
        self._clock = LoopClock()
        self._out: list[TwrMeasurement] = []
        self._task: asyncio.Task[None] | None = None
        self.samples = 0

    def start(self) -> None:
        self._task = asyncio.get_running_loop().create_task(self._run(), name="sim-uwb")

    async def _run(self) -> None:
        rate = RateLoop(self._clock, self.rate_hz)
        while True:
            t = await rate.tick()
            self.vehicle.step_to(t)
            tag = self.T_anchors_world.apply(np.array([self.vehicle.pn, self.vehicle.pe, self.vehicle.pd]))
            m = self.uwb.twr(t, tag)
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

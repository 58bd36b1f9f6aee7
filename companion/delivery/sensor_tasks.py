"""The landing sensors' tasks, once the fusion starts: two strategies.

- Lock-step (the simulation under virtual time, ``LandingKit.vision_in_thread = False``): one
  polled loop, camera then UWB at each tick of the kit's poll rate, nothing in a tick yielding to
  the loop, so a seeded flight is bit for bit the same every time.
- Real time (flight, and every real-time run): a task each, so a detection waiting on the
  executor never holds a UWB reading back. A camera that offers the frame-listener capability
  (:mod:`companion.plugin_api`, version 1) wakes its task through an :class:`asyncio.Event` set
  from its capture thread (``loop.call_soon_threadsafe``): the frame is read and handed to the
  detector as soon as it is readable. A camera without it is polled at the kit's rate, as is the UWB.

What a step does with a frame or a reading (detect, fuse, record) is the landing sensing's
(:mod:`companion.delivery.landing_sensing`): it hands the two steps in.
"""

from __future__ import annotations

import asyncio
import logging
from collections.abc import Awaitable, Callable
from typing import Any

from companion.plugin_api import frame_listener_of
from companion.scheduling import LoopClock, RateLoop

log = logging.getLogger(__name__)

_TASK_MEASUREMENTS = {"landing-camera": "camera", "landing-uwb": "UWB"}


def report_task_end(task: asyncio.Task[None]) -> None:
    """Say at once when a landing-sensor task dies (the flight goes on without its measurements:
    the fusion coasts on the others and the autopilot's estimate), instead of only when the shell
    ends."""
    if task.cancelled():
        return
    err = task.exception()
    if err is not None:
        log.error(
            "landing sensors stopped: %s: %s (task %s); no more %s measurements this flight",
            type(err).__name__,
            err,
            task.get_name(),
            _TASK_MEASUREMENTS.get(task.get_name(), "camera or UWB"),
        )


class SensorTasks:
    def __init__(
        self,
        kit: Any,
        clock: LoopClock,
        stats: Any,
        camera_step: Callable[[], Awaitable[None]],
        uwb_step: Callable[[], None],
        rate_loop: Callable[[LoopClock, float], RateLoop] = RateLoop,
    ):
        """``kit``: the shell's LandingKit; ``stats``: the shell's ShellStats (how the camera is
        read, the wake-ups); ``camera_step`` / ``uwb_step``: the landing sensing's handling of the
        newest frame and of the readings since the last call; ``rate_loop``: how the polls' loops are
        built (the shell's hooks)."""
        self.rate_loop = rate_loop
        self.kit = kit
        self.clock = clock
        self.stats = stats
        self.camera_step = camera_step
        self.uwb_step = uwb_step
        self.tasks: list[asyncio.Task[None]] = []

    @property
    def has_camera(self) -> bool:
        return self.kit.camera is not None and self.kit.detector is not None

    @property
    def has_uwb(self) -> bool:
        return self.kit.uwb is not None and self.kit.multilaterator is not None

    def start(self) -> None:
        loop = asyncio.get_running_loop()
        if not self.kit.vision_in_thread:
            tasks = [loop.create_task(self._lock_step(), name="landing-sensors")]
        else:
            tasks = []
            if self.has_camera:
                tasks.append(loop.create_task(self._camera_task(), name="landing-camera"))
            if self.has_uwb:
                tasks.append(loop.create_task(self._uwb_task(), name="landing-uwb"))
        for task in tasks:
            task.add_done_callback(report_task_end)
        self.tasks = tasks

    async def stop(self) -> None:
        """Cancel the tasks and wait for them: each detaches what it attached (the camera's frame
        listener) on its way out. The devices themselves are stopped by the shell. A task that
        died (logged when it did) raises its error here, once every task has ended."""
        tasks, self.tasks = self.tasks, []
        for task in tasks:
            task.cancel()
        errors: list[BaseException] = []
        for task in tasks:
            try:
                await task
            except asyncio.CancelledError:
                pass
            except Exception as err:
                errors.append(err)
        if errors:
            raise errors[0]

    async def _lock_step(self) -> None:
        rate = self.rate_loop(self.clock, self.kit.poll_rate_hz)
        while True:
            await rate.tick()
            if self.has_camera:
                await self.camera_step()
            if self.has_uwb:
                self.uwb_step()

    async def _camera_task(self) -> None:
        """Woken by the camera's frame listener when it offers one, else polled at the kit's rate.
        The listener is detached when the task ends."""
        attach = frame_listener_of(self.kit.camera)
        if attach is None:
            self.stats.camera_read = "polled"
            rate = self.rate_loop(self.clock, self.kit.poll_rate_hz)
            while True:
                await rate.tick()
                await self.camera_step()
        loop = asyncio.get_running_loop()
        ready = asyncio.Event()

        def on_frame() -> None:  # the camera's capture thread (or the loop's own, a simulated camera's)
            loop.call_soon_threadsafe(ready.set)

        self.stats.camera_read = "frame listener"
        attach(on_frame)
        try:
            while True:
                await ready.wait()
                ready.clear()  # a frame notified from here on, during the detection too, wakes the next pass
                self.stats.frames_notified += 1
                await self.camera_step()
        finally:
            attach(None)

    async def _uwb_task(self) -> None:
        """The UWB's readings at the kit's poll rate, whatever the camera does."""
        rate = self.rate_loop(self.clock, self.kit.poll_rate_hz)
        while True:
            await rate.tick()
            self.uwb_step()

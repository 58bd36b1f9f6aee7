"""The shell's landing-sensor tasks in real time: a camera offering the frame-listener capability
(plugin_api, version 1) wakes its task when a frame is readable; a camera without it is polled;
the UWB has a task of its own that a slow detection does not hold back; stopping detaches."""

from __future__ import annotations

import asyncio
import logging
import sys
import textwrap
import threading
import time
from types import SimpleNamespace
from typing import Any, ClassVar

import numpy as np
import pytest

from companion.config import load_config, shipped_params_path
from companion.delivery.shell import DeliveryShell, LandingKit
from companion.estimation.ekf import UpdateOutcome
from companion.plugin_api import (
    FRAME_LISTENER_VERSION,
    Frame,
    FrameListenerSlot,
    FrameNotifier,
    create,
    discover,
    frame_listener_of,
)
from companion.uwb.measurements import UwbFix

POLL_HZ_SLOW = 0.25  # a poll tick 4 s after the start: far later than any test here waits


class PolledCamera:
    """api_version 1 and nothing more: no frame listener."""

    api_version: ClassVar[int] = 1

    def __init__(self) -> None:
        self._latest: Frame | None = None
        self._lock = threading.Lock()
        self.reads = 0

    def put(self, frame: Frame) -> None:
        with self._lock:
            self._latest = frame

    def start(self) -> None:
        pass

    def read(self) -> Frame | None:
        with self._lock:
            self.reads += 1
            f, self._latest = self._latest, None
        return f

    def stop(self) -> None:
        pass


class NotifyingCamera(PolledCamera):
    """A capture thread of its own: each frame is stored, then the listener is told."""

    frame_listener_version: ClassVar[int] = FRAME_LISTENER_VERSION

    def __init__(self) -> None:
        super().__init__()
        self.listener = FrameListenerSlot("test")
        self.captured_at: dict[int, float] = {}

    def set_frame_listener(self, callback: Any) -> None:
        self.listener.set(callback)

    def capture_in_thread(self, index: int) -> None:
        def capture() -> None:
            self.put(Frame(float(index), np.zeros((4, 4), np.uint8), index))
            self.captured_at[index] = time.monotonic()
            self.listener.notify()

        t = threading.Thread(target=capture, name="test-capture")
        t.start()
        t.join()


class Detector:
    """Records when and on which thread each frame was detected; ``gate`` holds a detection."""

    def __init__(self, gate: threading.Event | None = None) -> None:
        self.gate = gate
        self.calls: list[tuple[int, float, str]] = []

    def detect(self, image: Any, time_s: float, down_cam: Any = None, roi_down_cam: Any = None) -> Any:
        if self.gate is not None:
            assert self.gate.wait(5.0)
        self.calls.append((int(time_s), time.monotonic(), threading.current_thread().name))
        return SimpleNamespace(time_s=time_s, ambiguous=False)


class Fusion:
    def __init__(self) -> None:
        self.markers: list[Any] = []
        self.fixes: list[UwbFix] = []

    def on_marker(self, obs: Any) -> UpdateOutcome:
        self.markers.append(obs)
        return UpdateOutcome.ACCEPTED

    def on_uwb(self, fix: UwbFix) -> None:
        self.fixes.append(fix)


class Uwb:
    api_version: ClassVar[int] = 1

    def __init__(self) -> None:
        self.pending: list[float] = []

    def start(self) -> None:
        pass

    def read(self) -> list[float]:
        out, self.pending = self.pending, []
        return out

    def stop(self) -> None:
        pass


class Multilaterator:
    def solve_twr(self, t: float) -> UwbFix:
        return UwbFix(t, 1.0, 2.0, 3.0, 1.0, 0.01, ("a", "b", "c", "d"), "anchors")


def _shell(camera: Any, detector: Detector, uwb: Any = None, poll_rate_hz: float = POLL_HZ_SLOW) -> DeliveryShell:
    config = load_config(shipped_params_path("sitl_short.toml"))
    kit = LandingKit(
        camera,
        uwb,
        detector,
        Multilaterator() if uwb is not None else None,
        None,
        None,
        vision_in_thread=True,
        poll_rate_hz=poll_rate_hz,
    )
    autopilot = SimpleNamespace(telemetry=SimpleNamespace(attitude=None))  # no attitude yet
    shell = DeliveryShell(config, autopilot=autopilot, landing=kit)  # type: ignore[arg-type]
    shell.vision_always = True
    shell.fusion = Fusion()
    return shell


async def _until(pred: Any, timeout_s: float = 3.0) -> None:
    t_end = time.monotonic() + timeout_s
    while not pred():
        assert time.monotonic() < t_end, "timed out"
        await asyncio.sleep(0.002)


def test_the_capability_is_found_by_version() -> None:
    assert frame_listener_of(PolledCamera()) is None
    cam = NotifyingCamera()
    assert isinstance(cam, FrameNotifier) and not isinstance(PolledCamera(), FrameNotifier)
    assert frame_listener_of(cam) == cam.set_frame_listener

    class FutureCamera(NotifyingCamera):
        frame_listener_version: ClassVar[int] = FRAME_LISTENER_VERSION + 1

    assert frame_listener_of(FutureCamera()) is None  # a version this companion does not speak: polled


async def test_a_notified_frame_is_detected_at_once_not_at_the_next_poll_tick() -> None:
    cam, det = NotifyingCamera(), Detector()
    shell = _shell(cam, det)
    shell.sensors.start()
    try:
        await _until(lambda: cam.listener.attached)
        cam.capture_in_thread(1)
        await _until(lambda: len(shell.fusion.markers) == 1)
        index, detected_at, thread = det.calls[0]
        assert index == 1 and thread != "test-capture" and thread != threading.current_thread().name  # the executor
        # well before the first poll tick (4 s): the listener woke the camera task
        assert detected_at - cam.captured_at[1] < 1.0
        assert shell.marker_tick_pending  # accepted while the fused estimate steers: guidance ticks early
        cam.capture_in_thread(2)
        await _until(lambda: len(shell.fusion.markers) == 2)
        assert [c[0] for c in det.calls] == [1, 2]
        assert shell.stats.camera_read == "frame listener" and shell.stats.frames_notified == 2
        assert cam.reads == 2  # read only when told
    finally:
        await shell.sensors.stop()


async def test_a_camera_without_the_capability_is_polled() -> None:
    cam, det = PolledCamera(), Detector()
    shell = _shell(cam, det, poll_rate_hz=100.0)
    shell.sensors.start()
    try:
        cam.put(Frame(7.0, np.zeros((4, 4), np.uint8), 7))
        await _until(lambda: len(shell.fusion.markers) == 1)
        assert det.calls[0][0] == 7 and shell.stats.camera_read == "polled"
        await _until(lambda: cam.reads >= 5)  # it keeps polling
        assert shell.stats.frames_notified == 0
    finally:
        await shell.sensors.stop()


@pytest.fixture
def old_camera_plugin(tmp_path, monkeypatch):
    """A third-party camera plugin written for api_version 1 before the frame listener, as pip installs it."""
    pkg = tmp_path / "acme_cameras"
    pkg.mkdir()
    (pkg / "__init__.py").write_text(
        textwrap.dedent(
            """
            import numpy as np
            from companion.plugin_api import Frame

            class OldCamera:
                api_version = 1
                def __init__(self):
                    self.reads = 0
                def start(self): pass
                def read(self):
                    self.reads += 1
                    return Frame(float(self.reads), np.zeros((4, 4), np.uint8), self.reads) if self.reads == 3 else None
                def stop(self): pass
            """
        )
    )
    dist = tmp_path / "acme_cameras-1.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: acme-cameras\nVersion: 1.0\n")
    (dist / "entry_points.txt").write_text("[companion.cameras]\nacme_old = acme_cameras:OldCamera\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    yield
    sys.modules.pop("acme_cameras", None)


async def test_a_plugin_written_before_the_capability_loads_and_is_polled(old_camera_plugin) -> None:
    loaded, report = discover("companion.cameras")
    assert "acme_old" in loaded and all(r.ok for r in report if r.name == "acme_old")
    cam = create("companion.cameras", "acme_old")
    assert not hasattr(cam, "set_frame_listener") and frame_listener_of(cam) is None
    det = Detector()
    shell = _shell(cam, det, poll_rate_hz=100.0)
    shell.sensors.start()
    try:
        await _until(lambda: len(shell.fusion.markers) == 1)
        assert det.calls[0][0] == 3 and shell.stats.camera_read == "polled"
    finally:
        await shell.sensors.stop()
    assert cam.reads >= 3


async def test_a_slow_detection_does_not_hold_the_uwb_back() -> None:
    gate = threading.Event()
    cam, det, uwb = NotifyingCamera(), Detector(gate), Uwb()
    shell = _shell(cam, det, uwb, poll_rate_hz=100.0)
    shell.sensors.start()
    try:
        await _until(lambda: cam.listener.attached)
        cam.capture_in_thread(1)
        await asyncio.sleep(0.05)  # the detection is now waiting on the gate, on the executor
        uwb.pending.append(12.5)
        await _until(lambda: len(shell.fusion.fixes) == 1)
        assert shell.fusion.fixes[0].time_s == 12.5 and not det.calls  # fused while the detection waits
        gate.set()
        await _until(lambda: len(shell.fusion.markers) == 1)
    finally:
        gate.set()
        await shell.sensors.stop()


async def test_stopping_cancels_the_tasks_and_detaches_the_listener() -> None:
    cam, det, uwb = NotifyingCamera(), Detector(), Uwb()
    shell = _shell(cam, det, uwb)
    shell.sensors.start()
    tasks = list(shell.sensors.tasks)
    assert sorted(t.get_name() for t in tasks) == ["landing-camera", "landing-uwb"]
    await _until(lambda: cam.listener.attached)
    await shell.sensors.stop()
    assert all(t.cancelled() for t in tasks) and not shell.sensors.tasks
    assert not cam.listener.attached
    cam.capture_in_thread(1)  # a frame after the stop wakes nothing
    await asyncio.sleep(0.05)
    assert not det.calls and cam.listener.notified == 0


async def test_a_dead_sensor_task_is_raised_when_the_shell_stops_them(caplog) -> None:
    class Broken(PolledCamera):
        def read(self) -> Frame | None:
            raise OSError("device gone")

    uwb = Uwb()
    shell = _shell(Broken(), Detector(), uwb, poll_rate_hz=100.0)
    with caplog.at_level(logging.ERROR, logger="companion.delivery.shell"):
        shell.sensors.start()
        await _until(lambda: any(t.done() for t in shell.sensors.tasks))
        await asyncio.sleep(0)  # the done callback
    assert "(task landing-camera); no more camera measurements" in caplog.text
    uwb.pending.append(3.0)  # the UWB goes on without the camera
    await _until(lambda: len(shell.fusion.fixes) == 1)
    try:
        await shell.sensors.stop()
    except OSError as err:
        assert "device gone" in str(err)
    else:
        raise AssertionError("the dead camera task's error was not raised")

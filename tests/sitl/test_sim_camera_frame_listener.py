"""The simulated camera's frame listener (plugin_api, version 1): told on the event loop the moment
each frame's capture latency has elapsed, and the frame it announces is the one ``read()`` returns,
its optics rendered ahead on the camera's render thread, not by ``read()`` on the loop."""

from __future__ import annotations

import asyncio
import threading
from types import SimpleNamespace

import pytest

from companion.plugin_api import FRAME_LISTENER_VERSION, frame_listener_of
from companion.vision.camera import load_default_camera
from companion_sitl.camera import SimCameraConfig, SimulatedCamera
from companion_sitl.clock import run_virtual
from companion_sitl.landing_sensors import SimCameraSource

RATE_HZ, LATENCY_S = 30.0, 0.05


def _source() -> SimCameraSource:
    # a small, plain ground keeps the set-up fast; 5 m straight above the pad: every frame shows it
    cam = SimulatedCamera(load_default_camera(), config=SimCameraConfig(ground_size_m=8.0, clutter=0), seed=0)
    above = SimpleNamespace(pn=0.0, pe=0.0, pd=-5.0, roll=0.0, pitch=0.0, yaw=0.0, step_to=lambda t: None)
    return SimCameraSource(above, cam, RATE_HZ, LATENCY_S)  # type: ignore[arg-type]


def _render_threads(src: SimCameraSource) -> list[str]:
    """The names of the threads the camera's optics (the expensive part of a frame) render on."""
    names: list[str] = []
    render = src.camera.render_optics

    def recorded(*args: object, **kwargs: object) -> object:
        names.append(threading.current_thread().name)
        return render(*args, **kwargs)  # type: ignore[arg-type]

    src.camera.render_optics = recorded  # type: ignore[method-assign]
    return names


def test_each_frame_is_announced_when_it_becomes_readable_and_read_then() -> None:
    src = _source()
    assert src.frame_listener_version == FRAME_LISTENER_VERSION and frame_listener_of(src) is not None
    render_threads = _render_threads(src)

    async def go() -> list[tuple[float, float | None]]:
        loop = asyncio.get_running_loop()
        got: list[tuple[float, float | None]] = []

        def listener() -> None:
            f = src.read()
            got.append((loop.time(), f.time_s if f is not None else None))

        src.set_frame_listener(listener)
        src.start()
        await asyncio.sleep(0.26)  # exposures 1..6 readable by then (the 7th at 0.283 s)
        src.set_frame_listener(None)
        await asyncio.sleep(0.2)  # frames exposed meanwhile are not announced
        src.stop()
        return got

    got = run_virtual(go())
    exposures = [k / RATE_HZ for k in range(1, 7)]  # the first exposure is one period in
    assert [e for _, e in got] == pytest.approx(exposures)
    assert [t for t, _ in got] == pytest.approx([e + LATENCY_S for e in exposures])
    assert src.rendered == len(exposures)
    # rendered during the capture latency on the camera's own thread, never by read() on the loop
    assert len(render_threads) >= len(exposures)
    assert all(name.startswith("sim-camera-render") for name in render_threads)


def test_unread_frames_are_not_hoarded_and_an_old_one_read_late_is_rendered_then() -> None:
    src = _source()
    render_threads = _render_threads(src)

    async def go() -> tuple[int, int, float | None]:
        src.set_frame_listener(lambda: None)  # told, but never reads (vision not wanted)
        src.start()
        await asyncio.sleep(1.0)
        kept = src.pending_renders
        rendered = len(render_threads)
        f = src.read()  # the newest readable one, whatever was dropped before it
        src.stop()
        return kept, rendered, f.time_s if f is not None else None

    kept, rendered, t = run_virtual(go())
    # renders of unread exposures are cancelled once four newer ones wait (those not begun never run)
    assert 0 < kept <= 4 and 0 < rendered <= 30
    assert t == pytest.approx(28 / RATE_HZ)  # exposure 28 (0.933 s) was readable at 1.0 s, 29 not yet


def test_nothing_is_announced_after_the_camera_stops() -> None:
    src = _source()

    async def go() -> int:
        calls: list[float] = []
        src.set_frame_listener(lambda: calls.append(0.0))
        src.start()
        await asyncio.sleep(1.0 / RATE_HZ + 0.01)  # one exposure taken, its frame not readable yet
        src.stop()
        await asyncio.sleep(0.2)
        return len(calls)

    assert run_virtual(go()) == 0

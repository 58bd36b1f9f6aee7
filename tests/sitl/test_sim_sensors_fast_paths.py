"""Fast paths of the embedded simulator that must not change what it computes: the Gauss-Markov
coefficients kept between steps, and the camera source's scan for the newest ready exposure."""

from __future__ import annotations

import asyncio
import math

import numpy as np

from companion.geometry import Transform
from companion.vision.camera import load_default_camera
from companion_sitl.camera import SimulatedCamera
from companion_sitl.landing_sensors import SimCameraSource
from companion_sitl.vehicle import _GaussMarkov


def test_gauss_markov_step_equals_the_formula_bit_for_bit_when_dt_or_parameters_change() -> None:
    rng = np.random.default_rng(2)
    g = _GaussMarkov(0.7, 12.0, 0.3)
    x = g.x
    for k in range(300):
        dt = 0.005 if k < 100 else (0.002 if k < 200 else float(rng.uniform(1e-4, 0.5)))
        if k == 150:
            g.sigma = 1.9  # a changed parameter is not served from the kept coefficients
        if k == 250:
            g.tau = 3.0
        n = float(rng.standard_normal())
        a = math.exp(-dt / g.tau)
        x = a * x + g.sigma * math.sqrt(1.0 - a * a) * n
        assert g.step(dt, n) == x


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def now(self) -> float:
        return self.t


def test_camera_source_reads_the_newest_ready_unread_exposure() -> None:
    cam = SimulatedCamera(load_default_camera(), seed=0)
    src = SimCameraSource(vehicle=None, camera=cam, rate_hz=30.0, latency_s=0.05)  # type: ignore[arg-type]
    clock = _Clock()
    src._clock = clock  # type: ignore[assignment]
    above = Transform.from_euler([0.0, 0.0, -5.0], 0.0, 0.0, 0.0)  # over the pad: in view
    beside = Transform.from_euler([40.0, 0.0, -5.0], 0.0, 0.0, 0.0)  # the pad far out of view
    for k in range(10):
        src._poses.append((k / 30, beside if k == 7 else above, None))  # T_camera_pad not computed yet
    clock.t = 0.04
    assert src.read() is None  # nothing exposed 50 ms ago yet
    clock.t = 0.12  # exposures 0..2 are ready: the newest, 2, is read, 0 and 1 are dropped
    f = src.read()
    assert f is not None and f.time_s == 2 / 30 and src.rendered == 1
    assert src.read() is None  # nothing new is ready
    clock.t = 0.30  # 3..7 ready: the newest, 7, does not show the pad
    assert src.read() is None and src.out_of_view == 1 and src.rendered == 1
    clock.t = 0.32  # 8 ready
    f = src.read()
    assert f is not None and f.time_s == 8 / 30 and f.index == 2
    clock.t = 10.0
    f = src.read()
    assert f is not None and f.time_s == 9 / 30
    assert src.read() is None


class _Track:
    """Truth for the camera source: a pose that is a function of the time (a descent over the pad
    that drifts out of view for a while)."""

    def step_to(self, t: float) -> None:
        self.pn, self.pe, self.pd = 0.3 * math.sin(t), (30.0 if 0.6 < t < 0.8 else 0.4 * t), -6.0 + 2.0 * t
        self.roll, self.pitch, self.yaw = 0.05 * math.sin(3.0 * t), 0.04 * math.cos(2.0 * t), 0.1 * t


def test_frames_rendered_ahead_on_the_thread_are_the_frames_rendered_on_read() -> None:
    from companion_sitl.clock import run_virtual
    from companion_sitl.landing_sensors import _truth_pose

    track = _Track()

    async def read_for(duration_s: float, period_s: float) -> list[tuple[float, np.ndarray]]:
        src = SimCameraSource(track, SimulatedCamera(load_default_camera(), seed=4), 30.0, 0.05)  # type: ignore[arg-type]
        src.start()
        out = []
        for _ in range(round(duration_s / period_s)):
            await asyncio.sleep(period_s)
            f = src.read()
            if f is not None:
                out.append((f.time_s, f.image))
        assert src.render_thread_running  # the frames came from the render thread
        src.stop()
        assert src.out_of_view > 0 and src.rendered == len(out)
        return out

    # read at 20 Hz: some exposures are dropped unread (their renders cancelled or discarded)
    frames = run_virtual(read_for(1.5, 0.05))
    twin = SimulatedCamera(load_default_camera(), seed=4)  # renders each frame on read, as capture() does
    assert len(frames) > 15
    for t, image in frames:
        track.step_to(t)
        assert np.array_equal(image, twin.capture(_truth_pose(track), t).image), t


def test_exposures_are_rendered_ahead_only_while_the_camera_is_read() -> None:
    from companion_sitl.clock import run_virtual

    class _Above:  # 5 m over the pad: every exposure shows it
        pn, pe, pd, roll, pitch, yaw = 0.0, 0.0, -5.0, 0.0, 0.0, 0.0

        def step_to(self, t: float) -> None:
            pass

    src = SimCameraSource(_Above(), SimulatedCamera(load_default_camera(), seed=0), 30.0, 0.05)  # type: ignore[arg-type]
    renders: list[int] = []
    render = src.camera.render_optics

    def counted(*args: object, **kwargs: object) -> object:
        renders.append(1)
        return render(*args, **kwargs)  # type: ignore[arg-type]

    src.camera.render_optics = counted  # type: ignore[method-assign]

    async def go() -> tuple[tuple[int, int], list[int]]:
        src.start()
        await asyncio.sleep(0.5)  # 15 exposures in view, nobody reads (vision not wanted yet)
        unread = (len(renders), src.pending_renders)
        pending = []
        for _ in range(30):  # then polled at 60 Hz, as the lock-step shell does
            await asyncio.sleep(1.0 / 60.0)
            src.read()
            pending.append(src.pending_renders)
        src.stop()
        return unread, pending

    unread, pending = run_virtual(go())
    assert unread == (0, 0)  # nothing rendered for nobody
    assert max(pending) > 0  # while read, the next exposures are rendered ahead (during their latency)
    assert src.rendered >= 14 and src.rendered <= len(renders) <= src.rendered + 2  # (one or two ahead at the stop)

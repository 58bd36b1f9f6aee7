"""The simulated camera's latency the configuration does not know about ([sim.camera]
unknown_latency_s) and its honest driver stamps (driver_stamp; docs/clock.md)."""

from __future__ import annotations

import asyncio
from types import SimpleNamespace

import pytest

from companion.plugin_api import Frame
from companion.vision.camera import load_default_camera
from companion_sitl.camera import SimCameraConfig, SimulatedCamera
from companion_sitl.clock import run_virtual
from companion_sitl.landing_sensors import SimCameraSource

RATE_HZ, LATENCY_S = 30.0, 0.05


def _source(**kwargs: object) -> SimCameraSource:
    cam = SimulatedCamera(load_default_camera(), config=SimCameraConfig(ground_size_m=8.0, clutter=0), seed=0)
    above = SimpleNamespace(pn=0.0, pe=0.0, pd=-5.0, roll=0.0, pitch=0.0, yaw=0.0, step_to=lambda t: None)
    return SimCameraSource(above, cam, RATE_HZ, LATENCY_S, **kwargs)  # type: ignore[arg-type]


def _announced(src: SimCameraSource) -> list[tuple[float, Frame]]:
    async def go() -> list[tuple[float, Frame]]:
        loop = asyncio.get_running_loop()
        got: list[tuple[float, Frame]] = []

        def listener() -> None:
            f = src.read()
            if f is not None:
                got.append((loop.time(), f))

        src.set_frame_listener(listener)
        src.start()
        await asyncio.sleep(0.4)
        src.stop()
        return got

    return run_virtual(go())


def test_by_default_frames_carry_no_stamp_of_their_own():
    got = _announced(_source())
    assert got and all(f.capture_time_s is None and f.arrival_time_s is None for _, f in got)
    assert [t - f.time_s for t, f in got] == pytest.approx([LATENCY_S] * len(got))


@pytest.mark.parametrize("driver_stamp", [False, True])
def test_an_unknown_latency_delays_the_frames_and_only_the_driver_stamp_tells(driver_stamp):
    got = _announced(_source(unknown_latency_s=0.08, driver_stamp=driver_stamp))
    assert len(got) >= 6
    for arrived_s, f in got:
        # stamped as a stamp-less driver stamps it: arrival minus the configured latency
        assert arrived_s - f.time_s == pytest.approx(LATENCY_S)
        if driver_stamp:
            assert f.capture_time_s is not None and f.arrival_time_s == pytest.approx(arrived_s)
            assert arrived_s - f.capture_time_s == pytest.approx(LATENCY_S + 0.08)  # the truth
            assert f.capture_time_s * RATE_HZ == pytest.approx(round(f.capture_time_s * RATE_HZ))  # an exposure
        else:
            assert f.capture_time_s is None and f.arrival_time_s is None


@pytest.mark.parametrize("bad", [-0.01, float("nan"), 2.0])
def test_a_bad_unknown_latency_is_named(bad):
    with pytest.raises(ValueError, match="unknown_latency_s"):
        _source(unknown_latency_s=bad)

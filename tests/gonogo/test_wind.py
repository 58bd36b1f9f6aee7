"""The wind go / no-go: the autopilot's wind estimate against the limit (hand-computed), no take-off
above it, and a return when it stays above it in flight (embedded simulator, whose autopilot
reports the wind at the vehicle as its estimate)."""

from __future__ import annotations

import pytest

from companion.autopilot.types import Wind
from companion.config import shipped_params_path
from companion.delivery.gonogo import WindMonitor
from companion.delivery.shell import DeliveryShell
from companion.scheduling import LoopClock
from companion_lab.demo import run_demo
from companion_sitl.autopilot import SimAutopilot
from companion_sitl.clock import run_virtual
from companion_sitl.params import load_simulated_config
from companion_sitl.vehicle import SimVehicle


def test_wind_monitor() -> None:
    m = WindMonitor(limit_m_s=6.0, exceed_s=3.0, max_age_s=3.0)
    assert m.take_off_problem(10.0, None) == "no fresh wind estimate from the autopilot"
    assert m.take_off_problem(10.0, Wind(6.0, 3.0, 4.0)) == "no fresh wind estimate from the autopilot"  # 4 s old
    assert m.take_off_problem(10.0, Wind(9.0, 3.0, 4.0)) is None  # 5 m/s
    why = m.take_off_problem(10.0, Wind(9.0, 6.0, 8.0))  # 10 m/s
    assert why == "wind 10.0 m/s (the autopilot's estimate) above go_no_go.wind_limit_m_s = 6 m/s"
    # in flight: above for 3 s before the return; a dip below starts the count again
    assert m.update(20.0, Wind(20.0, 6.0, 8.0)) is None
    assert m.update(22.0, Wind(22.0, 6.0, 8.0)) is None
    assert m.update(22.5, Wind(22.5, 3.0, 4.0)) is None
    assert m.update(23.0, Wind(23.0, 6.0, 8.0)) is None
    assert m.update(26.0, Wind(26.0, 6.0, 8.0)) == (
        "wind 10.0 m/s (the autopilot's estimate) above go_no_go.wind_limit_m_s = 6 m/s for 3.0 s"
    )


def cfg(wind_m_s: float, limit_m_s: float = 6.0):  # type: ignore[no-untyped-def]
    return load_simulated_config(
        shipped_params_path("delivery_paper.toml"),
        overrides={"go_no_go": {"wind_limit_m_s": limit_m_s}, "sim": {"wind_speed_m_s": wind_m_s}},
    )


def test_no_take_off_above_the_limit() -> None:
    r = run_demo(cfg(9.0))
    assert r.phase == "failed" and not r.delivered
    assert (
        r.failure.startswith("refused before take-off: wind ") and "above go_no_go.wind_limit_m_s = 6 m/s" in r.failure
    )
    assert not any(kind == "armed" for _, kind, _, _ in r.events)


@pytest.mark.flight
def test_wind_rising_in_flight_brings_the_parcel_home() -> None:
    config = cfg(2.0)

    async def go() -> DeliveryShell:
        vehicle = SimVehicle(config.sim)
        ap = SimAutopilot(config.sim, vehicle)
        shell = DeliveryShell(config, ap)

        async def weather() -> None:
            await LoopClock().sleep_until(30.0)
            vehicle.set_wind(11.0, 270.0)  # a front passes: 11 m/s from the west

        import asyncio

        task = asyncio.get_running_loop().create_task(weather())
        try:
            await shell.run(timeout_s=600.0)
        finally:
            task.cancel()
            await ap.close()
        return shell

    shell = run_virtual(go())
    s = shell.mission.summary
    assert s.returned and not s.delivered, s.failure
    (ev,) = [e for e in s.events if e.kind.value == "go_no_go"]
    assert ev.detail.startswith("abandoning the delivery, flying home: wind ") and "for 3.0 s" in ev.detail
    assert 33.0 <= ev.time_s < 40.0  # 3 s after the estimate crossed 6 m/s

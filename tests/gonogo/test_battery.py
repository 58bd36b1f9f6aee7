"""The battery go / no-go: the way home's time and the use per second (hand-computed), the refusal
before take-off, and a delivery abandoned for home on the embedded simulator's battery."""

from __future__ import annotations

import pytest

from companion.config import shipped_params_path
from companion.delivery.gonogo import BatteryMonitor, WayHome, time_home_s
from companion_lab.demo import run_demo
from companion_sitl.params import load_simulated_config

# the paper's speeds: cruise v3 5 m/s, descent v1 2 m/s, landing 0.5 m/s below 3 m, climb v5 1.5 m/s to 45 m
WAY = WayHome(5.0, 2.0, 0.5, final_descent_alt_m=3.0, climb_m_s=1.5, cruise_height_m=45.0, arc_radius_m=6.0)


def test_time_home() -> None:
    # 100 m / 5 + (45 - 3) m / 2 + 3 m / 0.5 = 20 + 21 + 6
    assert time_home_s(WAY, 100.0, 45.0) == pytest.approx(47.0)
    # on the ground at the pad: climb 45 m / 1.5 = 30 s first
    assert time_home_s(WAY, 100.0, 0.0) == pytest.approx(77.0)
    # below the final-descent height within two arcs of home: no climb, 2 m / 0.5
    assert time_home_s(WAY, 10.0, 2.0) == pytest.approx(10.0 / 5.0 + 4.0)


def test_measured_use_and_verdict() -> None:
    m = BatteryMonitor(reserve_pct=20.0, measure_s=30.0)
    m.update(0.0, 100.0, airborne=False)  # on the ground: does not count
    m.update(5.0, 100.0, airborne=True)
    assert m.use_pct_per_s() is None
    m.update(25.0, 98.0, airborne=True)
    assert m.use_pct_per_s() is None  # 20 s flown < 30 s
    m.update(45.0, 96.0, airborne=True)  # 40 s flown, 4 % used
    use = m.use_pct_per_s()
    assert use is not None and use[0] == pytest.approx(0.1) and use[1]
    v = m.verdict(96.0, 47.0)
    assert v is not None and not v.go_home and v.needed_pct == pytest.approx(4.7)
    v = m.verdict(24.7, 47.0)  # exactly the way home plus the reserve: time to go
    assert v is not None and v.go_home
    assert "24.7 % left; the way home takes 47 s x 0.100 %/s (measured in flight) = 4.7 %" in v.reason()
    assert "plus the reserve of 20 % = 24.7 %" in v.reason()
    configured = BatteryMonitor(reserve_pct=10.0, use_pct_per_s=0.5)
    assert configured.use_pct_per_s() == (0.5, False)


def cfg(**go_no_go: object):  # type: ignore[no-untyped-def]
    return load_simulated_config(
        shipped_params_path("delivery_paper.toml"),
        overrides={"go_no_go": {"battery_check": True, **go_no_go}, "sim": {"vehicle": {"battery_endurance_s": 120.0}}},
    )


def test_not_enough_for_the_round_trip_is_refused_before_take_off() -> None:
    # 0.9 %/s configured: the leg (d = 99.72 m) takes 99.72 / 5 + 45 / 1.5 + 42 / 2 + 3 / 0.5 = 76.9 s
    # each way: 153.9 s x 0.9 = 138.5 % + 20 %
    r = run_demo(cfg(battery_use_pct_per_s=0.9))
    assert r.phase == "failed" and not r.delivered
    assert r.failure == (
        "refused before take-off: not enough charge for the round trip: battery 100.0 % left; the round trip takes "
        "154 s x 0.900 %/s (configured) = 138.5 %, plus the reserve of 20 % = 158.5 %"
    )
    assert not any(kind == "armed" for _, kind, _, _ in r.events)


@pytest.mark.flight
def test_a_draining_battery_abandons_the_delivery_and_flies_home() -> None:
    # the simulator's battery empties in 120 s of flight (0.83 %/s), measured after 30 s in the air:
    # 41 s into the outbound (t = 46 s) 63.5 % are left and the way home takes 46 s x 0.833 %/s
    # = 38.7 % + 25 % reserve; home at t = 95 s
    r = run_demo(cfg(battery_reserve_pct=25.0))
    assert r.returned and not r.delivered, r.failure
    (ev,) = [d for _, kind, _, d in r.events if kind == "go_no_go"]
    assert ev.startswith("abandoning the delivery, flying home: battery") and "(measured in flight)" in ev
    assert r.failure.startswith("returned without delivering: battery")
    assert r.flight_time_s < 120.0  # landed before the battery was flat

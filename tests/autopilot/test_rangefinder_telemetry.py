"""DISTANCE_SENSOR into RangefinderReading on both backends, the stream asked for only with
[mission.rangefinder] on, and the sim vehicle's rangefinder (off unless its parameters fit one)."""

from __future__ import annotations

import math
from types import SimpleNamespace

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.ardupilot.autopilot import DISTANCE_SENSOR_MSG_ID
from companion.autopilot.interface import TelemetryCache
from companion.autopilot.px4 import Px4Autopilot
from companion.autopilot.types import MAV_SENSOR_ROTATION_PITCH_270, RangefinderReading
from companion_sitl.mavlink.factory import mavlink_sim_vehicle


def test_the_stream_is_asked_for_only_with_the_rangefinder_on(mav) -> None:  # type: ignore[no-untyped-def]
    off, on = (mav.short_config(rangefinder={"enabled": enabled}) for enabled in (False, True))
    assert DISTANCE_SENSOR_MSG_ID not in ArduPilotAutopilot.from_config(off).stream_rates_hz
    assert ArduPilotAutopilot.from_config(on).stream_rates_hz[DISTANCE_SENSOR_MSG_ID] == 10.0
    assert not Px4Autopilot.from_config(off).want_rangefinder
    assert Px4Autopilot.from_config(on).want_rangefinder


def test_ardupilot_decodes_distance_sensor_in_centimetres() -> None:
    ap = ArduPilotAutopilot("udpin:127.0.0.1:0")
    ap._post = lambda fn, *args: fn(*args)  # type: ignore[method-assign]
    enc = mavlink.MAVLink(None)
    m = enc.distance_sensor_encode(1000, 20, 700, 153, mavlink.MAV_DISTANCE_SENSOR_LASER, 0, 25, 0, signal_quality=87)
    ap._on_distance_sensor(m, 12.5)
    r = ap.telemetry.rangefinder
    assert r == RangefinderReading(12.5, 1.53, 0.2, 7.0, MAV_SENSOR_ROTATION_PITCH_270, 87)
    m = enc.distance_sensor_encode(1100, 20, 700, 140, mavlink.MAV_DISTANCE_SENSOR_LASER, 0, 25, 0)
    ap._on_distance_sensor(m, 12.6)
    assert ap.telemetry.rangefinder is not None and ap.telemetry.rangefinder.signal_quality_pct is None  # 0: unknown
    forward = enc.distance_sensor_encode(1200, 20, 700, 300, mavlink.MAV_DISTANCE_SENSOR_LASER, 1, 0, 0)
    ap._on_distance_sensor(forward, 12.7)
    assert ap.telemetry.rangefinder.time_s == 12.6  # a forward sensor's range is no height
    assert ap.telemetry.rejected["RangefinderReading"] == 1 and ap.telemetry.received["RangefinderReading"] == 2


@pytest.mark.parametrize(("pitch_deg", "down"), [(270.0, True), (-90.0, True), (0.0, False), (90.0, False)])
def test_px4_takes_mavsdk_s_euler_orientation(pitch_deg: float, down: bool) -> None:
    ap = Px4Autopilot("udpin://127.0.0.1:0")
    on = ap._rangefinder_handler(lambda: 3.0)
    o = SimpleNamespace(roll_deg=0.0, pitch_deg=pitch_deg, yaw_deg=0.0)
    on(SimpleNamespace(current_distance_m=1.25, minimum_distance_m=0.0, maximum_distance_m=100.0, orientation=o))
    r = ap.telemetry.rangefinder
    if down:
        assert r == RangefinderReading(3.0, 1.25, 0.0, 100.0, MAV_SENSOR_ROTATION_PITCH_270, None)
    else:
        assert r is None and ap.telemetry.rejected["RangefinderReading"] == 1


def test_the_cache_rejects_a_reading_that_is_not_finite() -> None:
    tc = TelemetryCache()
    assert not tc.push_rangefinder(RangefinderReading(1.0, math.nan, 0.2, 7.0))
    assert tc.rangefinder is None and tc.rejected == {"RangefinderReading": 1}


@pytest.mark.parametrize(
    ("dialect", "params", "lo", "hi"),
    [
        ("ardupilot", {"RNGFND1_TYPE": 100.0, "RNGFND1_MIN": 0.3, "RNGFND1_MAX": 6.0, "SIM_SONAR_RND": 0.05}, 0.3, 6.0),
        ("px4", {"SIH_DISTSNSR_MAX": 100.0}, 0.0, 100.0),
    ],
)
def test_the_sim_vehicle_measures_the_true_height_along_its_tilted_axis(mav, dialect, params, lo, hi) -> None:  # type: ignore[no-untyped-def]
    cfg = mav.short_config(rangefinder={"enabled": True}).sim
    assert mavlink_sim_vehicle(cfg, dialect).build_message(DISTANCE_SENSOR_MSG_ID) is None  # none fitted: nothing sent

    def ranges(seed: int) -> list[float]:
        sim = mavlink_sim_vehicle(cfg.model_copy(update={"seed": seed}), dialect, params=params)
        v = sim.vehicle
        v.pd, v.roll, v.pitch = -2.0, math.radians(10.0), math.radians(-5.0)
        out = []
        for _ in range(50):
            m = sim.build_message(DISTANCE_SENSOR_MSG_ID)
            assert (m.min_distance, m.max_distance, m.orientation) == (round(100 * lo), round(100 * hi), 25)
            out.append(m.current_distance / 100.0)
        return out

    along = 2.0 / (math.cos(math.radians(10.0)) * math.cos(math.radians(-5.0)))
    noise = params.get("SIM_SONAR_RND", 0.0)
    a = ranges(1)
    assert all(abs(d - along) <= noise + 0.005 for d in a)
    assert a == ranges(1)  # seeded
    if noise:
        assert a != ranges(2) and max(a) - min(a) > noise  # SIM_SONAR_RND: uniform within +-noise

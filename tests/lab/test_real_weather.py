"""The weather driven on the real ArduCopter SITL (lab/real_weather.py): the conversions to SITL
parameters, the processes' statistics and the driver's schedule, without a SITL."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion_lab.real_weather import (
    DRIVE_HZ,
    EARTH_RADIUS_M,
    FirmwareWeather,
    WeatherDriver,
    WeatherError,
    WeatherProcess,
    glitch_deg,
    static_params,
    wind_speed_dir,
)
from companion_sitl.params import SimConfig

W = FirmwareWeather.of(SimConfig(wind_speed_m_s=4.0, wind_from_deg=90.0))


def test_weather_of_a_draw_takes_the_embedded_defaults():
    assert W.gust_std_m_s == pytest.approx(0.8)  # -1 = 20 % of the mean wind
    assert (W.gps_noise_m, W.gps_walk_m, W.gps_walk_time_constant_s) == (0.05, 0.15, 20.0)
    assert (W.gyro_noise_rad_s, W.accel_noise_m_s2, W.baro_noise_m) == (0.003, 0.05, 0.1)


@pytest.mark.parametrize(
    ("north", "east", "speed", "from_deg"),
    [
        (-5.0, 0.0, 5.0, 0.0),  # air moving south: wind from the north
        (0.0, -3.0, 3.0, 90.0),  # moving west: from the east
        (3.0, 4.0, 5.0, 180.0 + math.degrees(math.atan2(4.0, 3.0))),
        (0.0, 0.0, 0.0, 0.0),
    ],
)
def test_wind_speed_and_direction_from_the_air_velocity(north, east, speed, from_deg):
    s, d = wind_speed_dir(north, east)
    assert s == pytest.approx(speed)
    assert d == pytest.approx(from_deg)
    assert 0.0 <= d < 360.0


def test_glitch_degrees_move_the_fix_by_metres():
    gx, gy = glitch_deg(1.0, 1.0, 60.0)
    assert gx == pytest.approx(math.degrees(1.0 / EARTH_RADIUS_M))
    assert gy == pytest.approx(2.0 * gx)  # cos 60 deg = 1/2: a degree of longitude is half as long


def test_sensor_noise_as_the_sitls_uniform_amplitudes():
    p = dict(static_params(W, hover_throttle=0.5))
    # uniform on [-a, a] has std a / sqrt(3); the gyro's a is SIM_GYR1_RND deg/s x throttle
    assert math.radians(p["SIM_GYR1_RND"]) * 0.5 / math.sqrt(3) == pytest.approx(0.003)
    assert p["SIM_ACC1_RND"] / math.sqrt(3) == pytest.approx(0.05)
    assert p["SIM_BARO_RND"] / math.sqrt(3) == pytest.approx(0.1)
    assert p["SIM_WIND_TURB"] == 0.0
    with pytest.raises(WeatherError, match=r"MOT_THST_HOVER = 0\.0"):
        static_params(W, 0.0)


def test_the_processes_have_the_drawn_statistics():
    proc = WeatherProcess(W, seed=3, dt=0.2)
    xs = np.array([proc.step() for _ in range(60000)])  # 12000 s, 600 gust correlation times
    wind, gps = xs[:, 0, :], xs[:, 1, :]
    # mean wind from the east (blowing west), gusts around it with std 0.8 m/s on each axis
    assert wind[:, 1].mean() == pytest.approx(-4.0, abs=0.05)
    assert wind[:, 0].std() == pytest.approx(0.8, rel=0.05)
    # GPS: wander 0.15 m and white 0.05 m: std sqrt(0.15^2 + 0.05^2)
    assert gps[:, 0].std() == pytest.approx(math.hypot(0.15, 0.05), rel=0.15)
    # gust correlation at one time constant (3 s = 15 steps) is 1/e
    g = wind[:, 0] - wind[:, 0].mean()
    rho = float(np.corrcoef(g[:-15], g[15:])[0, 1])
    assert rho == pytest.approx(math.exp(-1.0), abs=0.05)


def test_the_same_seed_gives_the_same_weather():
    a, b = WeatherProcess(W, 7), WeatherProcess(W, 7)
    assert [a.step() for _ in range(50)] == [b.step() for _ in range(50)]
    assert [WeatherProcess(W, 8).step() for _ in range(3)] != [WeatherProcess(W, 7).step() for _ in range(3)]


class _Clock:
    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def test_the_driver_sends_wind_and_glitch_and_leaves_the_mean_wind():
    sent: list[tuple[str, float]] = []
    d = WeatherDriver(WeatherProcess(W, 1), lambda n, v: sent.append((n, v)), lat_deg=0.0)
    d.apply((0.0, -4.0), (1.0, 0.0))
    assert dict(sent) == pytest.approx(
        {
            "SIM_WIND_SPD": 4.0,
            "SIM_WIND_DIR": 90.0,
            "SIM_GPS1_GLTCH_X": math.degrees(1.0 / EARTH_RADIUS_M),
            "SIM_GPS1_GLTCH_Y": 0.0,
        }
    )
    sent.clear()
    d.stop()  # never started: it only leaves the mean wind and no glitch
    assert dict(sent) == pytest.approx(
        {"SIM_WIND_SPD": 4.0, "SIM_WIND_DIR": 90.0, "SIM_GPS1_GLTCH_X": 0.0, "SIM_GPS1_GLTCH_Y": 0.0}
    )


def test_the_driver_keeps_its_rate_and_counts_late_ticks():
    clock = _Clock()
    sent: list[str] = []

    def send(name: str, value: float) -> None:
        sent.append(name)
        if name == "SIM_GPS1_GLTCH_Y":  # one tick's four values sent: time moves on
            clock.t += 1.0 / DRIVE_HZ if d.ticks != 2 else 1.0  # the third tick takes 1 s

    d = WeatherDriver(WeatherProcess(W, 1), send, lat_deg=0.0, clock=clock)
    d.run(max_ticks=6)
    assert d.ticks == 6
    assert d.overruns == 1
    assert sent.count("SIM_WIND_SPD") == 6
    assert d.max_gust_m_s > 0.0 and d.max_gps_error_m > 0.0


def test_profile_weather_only_on_the_arducopter_profile():
    from companion_sitl.profiles import apply_profile

    calm = apply_profile(SimConfig(profile="arducopter-sitl", wind_speed_m_s=4.0))
    assert (calm.gust_std_m_s, calm.gps_noise_m, calm.gps_walk_m) == (0.0, 0.0, 0.02)
    kept = apply_profile(SimConfig(profile="arducopter-sitl", wind_speed_m_s=4.0, profile_weather=True))
    assert (kept.gust_std_effective_m_s, kept.gps_noise_m, kept.gps_walk_m) == (pytest.approx(0.8), 0.05, 0.15)
    assert kept.ready_delay_s == calm.ready_delay_s == 41.0  # the rest of the profile still applies
    with pytest.raises(ValueError, match="profile_weather = true with profile 'px4-sih'"):
        SimConfig(profile="px4-sih", profile_weather=True)


def test_gps_step_figures_on_synthetic_rows():
    from companion_lab.gps_step_probe import figures

    rows = [(0.1 * k, "hover", 0.0, 0.0) for k in range(10)]
    # a first-order move of -1 m with a 1 s time constant; the estimate stays put
    rows += [(1.0 + 0.1 * k, "glitch", -(1.0 - math.exp(-0.1 * k)), 0.0) for k in range(101)]
    f = figures(rows, 1.0)
    assert f["truth_63pct_s"] == pytest.approx(1.0, abs=0.1)
    assert f["truth_move_m"] == pytest.approx(-1.0, abs=0.01) and f["estimate_move_m"] == 0.0
    with pytest.raises(ValueError, match="no hover or glitch"):
        figures(rows[:10], 1.0)

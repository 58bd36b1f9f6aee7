"""Weather and sensor noise on the real ArduCopter SITL, drawn from the embedded campaign's
distributions (``companion campaign landing --autopilot ardupilot --weather``; docs/weather.md).

The embedded simulator flies each draw's mean wind with Gauss-Markov gusts (std 20 % of the mean
speed, 3 s correlation), a GPS that wanders (0.15 m, 20 s) with white noise (0.05 m) on top, and
noisy gyro, accelerometer and barometer (``[sim]`` defaults, sitl/vehicle.py). ArduCopter 4.7's
SITL has no gust process of that kind (SIM_WIND_TURB re-draws the direction of a 0.04 s AR(1) every
physics step: high-frequency buffeting, see :func:`static_params`) and no horizontal GPS wander
(SIM_GPS1_NOISE is a slow vertical sine; the horizontal HNSE came after 4.7), so both are driven
from outside, as a ground station would set them: :class:`WeatherDriver` steps the same processes
at :data:`DRIVE_HZ` and sends the wind as SIM_WIND_SPD / SIM_WIND_DIR and the GPS error as the
glitch offset SIM_GPS1_GLTCH_X / _Y (degrees of latitude / longitude, SIM_GPS.cpp). The sensor
noise is set once per SITL (SIM_GYR1_RND, SIM_ACC1_RND, SIM_BARO_RND), converted to the SITL's
uniform noise and, for the gyro, its scaling by throttle (AP_InertialSensor_SITL.cpp).
"""

from __future__ import annotations

import logging
import math
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from companion_sitl.params import SimConfig
from companion_sitl.vehicle import GaussMarkov

log = logging.getLogger(__name__)

DRIVE_HZ = 5.0  # the SITL GPS's own rate (SIM_GPS1_HZ = 5): one glitch offset per fix
WIND_TC_S = 0.2  # SIM_WIND_TC: the SITL's low-pass on wind changes (default 5 s would damp the gusts)
EARTH_RADIUS_M = 6378100.0  # RADIUS_OF_EARTH (AP_Math/definitions.h), as SIM_GPS.cpp converts metres
SQRT3 = math.sqrt(3.0)  # rand_float() is uniform on [-1, 1]: std = amplitude / sqrt(3)


class WeatherError(RuntimeError):
    """The SITL did not take a weather setting (a parameter it does not have, or no echo)."""


@dataclass(frozen=True)
class FirmwareWeather:
    """One draw's weather and sensor noise, in the embedded simulator's terms (SimConfig fields)."""

    wind_speed_m_s: float
    wind_from_deg: float
    gust_std_m_s: float
    gust_time_constant_s: float
    gps_noise_m: float
    gps_walk_m: float
    gps_walk_time_constant_s: float
    gyro_noise_rad_s: float
    accel_noise_m_s2: float
    baro_noise_m: float

    @classmethod
    def of(cls, sim: SimConfig) -> FirmwareWeather:
        """The weather ``sim`` describes (a campaign draw's [sim] before any profile)."""
        return cls(
            wind_speed_m_s=sim.wind_speed_m_s,
            wind_from_deg=sim.wind_from_deg,
            gust_std_m_s=sim.gust_std_effective_m_s,
            gust_time_constant_s=sim.gust_time_constant_s,
            gps_noise_m=sim.gps_noise_m,
            gps_walk_m=sim.gps_walk_m,
            gps_walk_time_constant_s=sim.gps_walk_time_constant_s,
            gyro_noise_rad_s=sim.gyro_noise_rad_s,
            accel_noise_m_s2=sim.accel_noise_m_s2,
            baro_noise_m=sim.baro_noise_m,
        )


def static_params(w: FirmwareWeather, hover_throttle: float) -> list[tuple[str, float]]:
    """The SITL parameters set once per SITL for ``w``'s sensor noise.

    Each SITL noise is ``amplitude * rand_float()``, uniform on [-1, 1] (std amplitude / sqrt(3)).
    The gyro's amplitude is SIM_GYR1_RND in deg/s times the throttle when the motors run
    (AP_InertialSensor_SITL.cpp), so it is scaled by the hover throttle (MOT_THST_HOVER) to give
    ``gyro_noise_rad_s`` in hover. The accelerometer's is SIM_ACC1_RND in m/s^2, the barometer's
    SIM_BARO_RND in m. SIM_WIND_TURB stays 0: its buffeting is not the gust process this draw
    describes, which :class:`WeatherDriver` flies instead."""
    if not 0.05 <= hover_throttle <= 1.0:
        raise WeatherError(f"MOT_THST_HOVER = {hover_throttle}: expected a hover throttle in 0.05..1")
    return [
        ("SIM_GYR1_RND", math.degrees(w.gyro_noise_rad_s) * SQRT3 / hover_throttle),
        ("SIM_ACC1_RND", w.accel_noise_m_s2 * SQRT3),
        ("SIM_BARO_RND", w.baro_noise_m * SQRT3),
        ("SIM_WIND_TURB", 0.0),
        ("SIM_WIND_TC", WIND_TC_S),
    ]


def wind_speed_dir(north_m_s: float, east_m_s: float) -> tuple[float, float]:
    """SIM_WIND_SPD and SIM_WIND_DIR (where it blows from, 0..360 deg) of the air moving
    (``north_m_s``, ``east_m_s``)."""
    speed = math.hypot(north_m_s, east_m_s)
    if speed == 0.0:
        return 0.0, 0.0
    return speed, math.degrees(math.atan2(-east_m_s, -north_m_s)) % 360.0


def glitch_deg(north_m: float, east_m: float, lat_deg: float) -> tuple[float, float]:
    """SIM_GPS1_GLTCH_X / _Y (degrees added to latitude / longitude, SIM_GPS.cpp) that move the
    reported fix ``north_m`` / ``east_m``."""
    return (
        math.degrees(north_m / EARTH_RADIUS_M),
        math.degrees(east_m / (EARTH_RADIUS_M * math.cos(math.radians(lat_deg)))),
    )


class WeatherProcess:
    """The draw's gusts and GPS error as time series: the same processes and step as the embedded
    vehicle (sitl/vehicle.py: Gauss-Markov gusts and wander, white GPS noise), stepped at ``dt``."""

    def __init__(self, w: FirmwareWeather, seed: int, dt: float = 1.0 / DRIVE_HZ) -> None:
        self.w = w
        self.dt = dt
        self._rng = np.random.default_rng([seed, 0x57EA])
        self._gust = [GaussMarkov(w.gust_std_m_s, w.gust_time_constant_s) for _ in range(2)]
        self._walk = [GaussMarkov(w.gps_walk_m, w.gps_walk_time_constant_s) for _ in range(2)]
        for g in self._walk:  # from the stationary distribution, as the embedded vehicle starts
            g.x = g.sigma * float(self._rng.standard_normal())
        wf = math.radians(w.wind_from_deg)
        self._mean = (-w.wind_speed_m_s * math.cos(wf), -w.wind_speed_m_s * math.sin(wf))

    def step(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """The next (wind N, E in m/s) and (GPS error N, E in m)."""
        n = self._rng.standard_normal(6).tolist()
        wind = (self._mean[0] + self._gust[0].step(self.dt, n[0]), self._mean[1] + self._gust[1].step(self.dt, n[1]))
        walk = (self._walk[0].step(self.dt, n[2]), self._walk[1].step(self.dt, n[3]))
        gps = (walk[0] + self.w.gps_noise_m * n[4], walk[1] + self.w.gps_noise_m * n[5])
        return wind, gps


class WeatherDriver:
    """Flies a :class:`WeatherProcess` on a SITL: every 1 / DRIVE_HZ s (absolute deadlines) it
    sends the wind and the GPS glitch through ``send(name, value)`` (fire-and-forget PARAM_SET on
    the truth link). ``stop`` leaves the mean wind and no glitch. Counts its late ticks."""

    def __init__(
        self,
        process: WeatherProcess,
        send: Callable[[str, float], None],
        lat_deg: float,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.process = process
        self._send = send
        self._lat = lat_deg
        self._clock = clock
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self.ticks = 0
        self.overruns = 0
        self.max_gust_m_s = 0.0
        self.max_gps_error_m = 0.0

    def apply(self, wind: tuple[float, float], gps: tuple[float, float]) -> None:
        spd, frm = wind_speed_dir(*wind)
        gx, gy = glitch_deg(gps[0], gps[1], self._lat)
        for name, value in (
            ("SIM_WIND_SPD", spd),
            ("SIM_WIND_DIR", frm),
            ("SIM_GPS1_GLTCH_X", gx),
            ("SIM_GPS1_GLTCH_Y", gy),
        ):
            self._send(name, value)

    def run(self, max_ticks: int | None = None) -> None:
        """Drive on this thread until :meth:`stop`, a failed send, or ``max_ticks`` ticks
        (:meth:`start` runs it on a thread of its own)."""
        self._run(max_ticks)

    def _run(self, max_ticks: int | None = None) -> None:
        dt = self.process.dt
        mean = self.process._mean
        next_t = self._clock()
        while not self._stop.is_set() and (max_ticks is None or self.ticks < max_ticks):
            wind, gps = self.process.step()
            self.max_gust_m_s = max(self.max_gust_m_s, math.hypot(wind[0] - mean[0], wind[1] - mean[1]))
            self.max_gps_error_m = max(self.max_gps_error_m, math.hypot(*gps))
            try:
                self.apply(wind, gps)
            except Exception:  # a lost link ends the landing elsewhere; the weather just stops
                log.exception("weather driver: sending the weather failed; it stops")
                return
            self.ticks += 1
            next_t += dt
            wait = next_t - self._clock()
            if wait < 0.0:
                self.overruns += 1
                next_t = self._clock()  # start again from now, not a burst of late ticks
            elif self._stop.wait(wait):
                break

    def start(self) -> WeatherDriver:
        self._thread = threading.Thread(target=self._run, name="weather-driver", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=5.0)
        w = self.process.w
        wf = math.radians(w.wind_from_deg)
        self.apply((-w.wind_speed_m_s * math.cos(wf), -w.wind_speed_m_s * math.sin(wf)), (0.0, 0.0))

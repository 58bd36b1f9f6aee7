"""The simulated environment's wind: a mean from ``[sim] wind_from_deg`` / ``wind_speed_m_s`` with
Gauss-Markov gusts per axis (``gust_std_m_s``, ``gust_time_constant_s``), faded towards the ground
by the autopilot profile's ramp (``wind_ramp_height_m``: the SITL's own wind does; profiles.py).

:class:`SimWind` is the part of :class:`~companion_sitl.vehicle.SimVehicle` that holds it; the
vehicle's drag, the parcel on the winch's line and the simulated autopilots' wind report read
:attr:`SimWind.now`.
"""

from __future__ import annotations

import math

import numpy as np

from companion_sitl.gauss_markov import GaussMarkov
from companion_sitl.params import SimConfig


def wind_mean_ned(speed_m_s: float, from_deg: float) -> tuple[float, float, float]:
    """The air's velocity (N, E, D; m/s) of a wind of ``speed_m_s`` blowing from ``from_deg``."""
    wf = math.radians(from_deg)
    return (-speed_m_s * math.cos(wf), -speed_m_s * math.sin(wf), 0.0)


class SimWind:
    """The wind at the vehicle: mean + gusts (``now``, N, E, D; m/s), one draw of ``rng`` per axis
    and physics step."""

    def __init__(self, c: SimConfig, rng: np.random.Generator, ramp_height_m: float) -> None:
        self.rng = rng
        self.ramp_height_m = ramp_height_m
        self.mean = wind_mean_ned(c.wind_speed_m_s, c.wind_from_deg)
        gs = c.gust_std_effective_m_s
        tau = c.gust_time_constant_s
        self.gusts = [GaussMarkov(gs, tau), GaussMarkov(gs, tau), GaussMarkov(0.3 * gs, tau)]
        self.now = list(self.mean)

    def step(self, dt: float, pd: float) -> None:
        """The wind: mean + gusts, faded towards the ground (the vehicle at down ``pd``) by the
        profile's ramp."""
        rn = self.rng.standard_normal(3).tolist()  # Python floats: the same values, no numpy scalars
        for i in range(3):
            self.now[i] = self.mean[i] + self.gusts[i].step(dt, rn[i])
        ramp = self.ramp_height_m
        if ramp > 0.0 and -pd < ramp:  # the SITL's wind fades towards the ground (profiles.py)
            k = math.sqrt(max(0.0, -pd) / ramp)
            for i in range(3):
                self.now[i] *= k

    def set_mean(self, speed_m_s: float, from_deg: float) -> None:
        """Change the mean wind (a test's weather change); the gusts go on around it."""
        self.mean = wind_mean_ned(speed_m_s, from_deg)

"""The first-order Gauss-Markov process the simulator's slow disturbances are made of: the wind's
gusts (sitl/wind.py), the GPS error's wander (sitl/gps_error.py) and the autopilot's velocity-estimate
error (sitl/estimator_error.py); lab/real_weather.py drives a real SITL's weather with it."""

from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass
class GaussMarkov:
    """First-order Gauss-Markov process x' = -x/tau + w, stationary std ``sigma``."""

    sigma: float
    tau: float
    x: float = 0.0
    # (dt, sigma, tau) -> (a, sigma * sqrt(1 - a^2)) of the last step: the physics steps at one dt
    _coef: tuple[float, float, float, float, float] | None = field(default=None, repr=False, compare=False)

    def step(self, dt: float, n: float) -> float:
        c = self._coef
        if c is None or c[0] != dt or c[1] != self.sigma or c[2] != self.tau:
            a = math.exp(-dt / self.tau)
            c = self._coef = (dt, self.sigma, self.tau, a, self.sigma * math.sqrt(1.0 - a * a))
        self.x = c[3] * self.x + c[4] * n
        return self.x

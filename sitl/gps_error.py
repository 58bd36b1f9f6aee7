"""The simulated GPS's error and the part of it the autopilot's position estimate takes.

The error is a slow wander per axis (Gauss-Markov, ``[sim] gps_walk_m`` over
``gps_walk_time_constant_s``, the vertical 1.5 times the horizontal), started from its stationary
distribution, plus a constant bias (``gps_bias_m``: it lives in the reported home and global
position). Where the autopilot profile says the estimate takes the error with a lag
(``gps_error_estimate_tau_s`` > 0, first or second order), the receiver's 5 Hz fixes add their white
noise (``gps_noise_m``) and the estimate follows that error (profiles.py): a vehicle held on its
estimate then moves against it.

:class:`GpsError` is the part of :class:`~companion_sitl.vehicle.SimVehicle` that holds it.
"""

from __future__ import annotations

import math

import numpy as np

from companion_sitl.gauss_markov import GaussMarkov
from companion_sitl.params import SimConfig
from companion_sitl.profiles import AutopilotProfile

GPS_FIX_PERIOD_S = 0.2  # a GPS receiver's 5 Hz fixes (ArduPilot SITL's default SIM_GPS1_HZ)


class GpsError:
    """The GPS error's wander (``walk``, N, E, D), its bias, and ``in_est`` / ``in_est_rate``: the
    part of the horizontal error the estimate has taken (N, E; m) and its rate (m/s: the velocity
    estimate's error, and the second-order state)."""

    def __init__(self, c: SimConfig, profile: AutopilotProfile, rng: np.random.Generator, dt: float) -> None:
        self.profile = profile
        self.rng = rng
        self.bias = tuple(c.gps_bias_m)
        # autopilot estimate error: slow wander (horizontal/vertical) + constant bias
        self.walk = [
            GaussMarkov(c.gps_walk_m, c.gps_walk_time_constant_s),
            GaussMarkov(c.gps_walk_m, c.gps_walk_time_constant_s),
            GaussMarkov(1.5 * c.gps_walk_m, c.gps_walk_time_constant_s),
        ]
        for w in self.walk:  # start from the stationary distribution
            w.x = w.sigma * float(rng.standard_normal())
        self.in_est = [self.walk[0].x, self.walk[1].x]
        self.in_est_rate = [0.0, 0.0]
        # the GPS fix's white noise (gps_noise_m) at the receiver's 5 Hz, which the estimate takes
        # too; its own generator, so the other draws stay as they were
        self.rng_fix = np.random.default_rng([c.seed, 0x6F1C])
        self.fix_noise = (0.0, 0.0)
        self.fix_next_s = 0.0
        # the estimate's response per physics step (computed once: the physics runs at one dt): the
        # first-order step coefficient, and the second-order x'' = w^2 (err - x) - 2 zeta w x' as
        # (w^2, 2 zeta w), (0, 0) for first order
        tau_e = profile.gps_error_estimate_tau_s
        self.lag_a = 1.0 - math.exp(-dt / tau_e) if tau_e > 0.0 else 1.0
        w_e = 1.0 / tau_e if tau_e > 0.0 else 0.0
        self.est_2nd = (w_e * w_e, 2.0 * profile.gps_error_estimate_damping * w_e)

    def step(self, t: float, dt: float, gps_noise_m: float) -> None:
        """The GPS error's random walk, and the part of it the autopilot's estimate has taken
        where the profile has one (gps_error_estimate_*; the fixes' noise ``gps_noise_m``, read
        from the vehicle's configuration each step)."""
        rg = self.rng.standard_normal(3).tolist()
        for i in range(3):
            self.walk[i].step(dt, rg[i])
        if self.profile.gps_error_estimate_tau_s <= 0.0:
            return
        if t >= self.fix_next_s:
            self.fix_next_s = t + GPS_FIX_PERIOD_S
            r = self.rng_fix.standard_normal(2).tolist()
            self.fix_noise = (gps_noise_m * r[0], gps_noise_m * r[1])
        # the estimate takes the error (first or second order, gps_error_estimate_*); a vehicle
        # held on the estimate then moves against it (GUIDED's position target, sitl/modes.py)
        a = self.lag_a
        w2, c2 = self.est_2nd
        for i in range(2):
            err = self.walk[i].x + self.fix_noise[i]
            if c2 > 0.0:  # second order, semi-implicit Euler (w dt <= 0.03 here)
                rate = self.in_est_rate[i]
                rate += dt * (w2 * (err - self.in_est[i]) - c2 * rate)
                self.in_est_rate[i] = rate
                self.in_est[i] += dt * rate
            else:  # first order, exact for the error held over dt
                d = a * (err - self.in_est[i])
                self.in_est[i] += d
                self.in_est_rate[i] = d / dt

"""The autopilot's estimator errors beyond the GPS's (sitl/gps_error.py), from its profile
(profiles.py): the velocity estimate's error and the estimator state of this flight.

* The velocity error (``velocity_error_m_s`` > 0): Gauss-Markov per axis, started from its
  stationary distribution; what the autopilot reports, and where the profile says so
  (``velocity_loop_on_estimate``) what its velocity loop flies on.
* The estimator state (``estimator_states``: one drawn per flight, :class:`EstimatorState`): an
  attitude offset (reported - true roll, pitch, yaw), a horizontal velocity bias that depends on
  the height (traced in a descent from ``VELOCITY_BIAS_DESCENT_START_M``, drifting on past the
  traced window at rates drawn per flight), and the position estimate's share of it (it follows
  the bias, GPS pulls it back).

:class:`EstimatorError` is the part of :class:`~companion_sitl.vehicle.SimVehicle` that holds them.
Its generators are children of the vehicle's seed sequence, spawned in the order the draws have
always had (a profile without these errors draws nothing).
"""

from __future__ import annotations

import math

import numpy as np

from companion_sitl.gauss_markov import GaussMarkov
from companion_sitl.profiles import (
    VELOCITY_BIAS_DESCENT_SPEED_M_S,
    VELOCITY_BIAS_DESCENT_START_M,
    VELOCITY_BIAS_DRIFT_MAX_M_S,
    VELOCITY_BIAS_DRIFT_RATE_M_S2,
    VELOCITY_BIAS_HEIGHTS_M,
    AutopilotProfile,
    EstimatorState,
)


class EstimatorError:
    """``verr``: the velocity error (N, E, D; empty without one); ``state``: the estimator state
    (None without one), with ``att_bias`` (rad), ``pos_bias`` (N, E; m), ``descent_t0`` (when the
    descent passed VELOCITY_BIAS_DESCENT_START_M; None: not in such a descent) and ``drift_m_s2``
    (N, E: the drift past the traced window)."""

    def __init__(
        self, profile: AutopilotProfile, ss: np.random.SeedSequence, rng_misc: np.random.Generator, pd: float
    ) -> None:
        self._init_velocity_error(profile, ss)
        self._init_state(profile, ss, rng_misc, pd)

    def _init_velocity_error(self, pr: AutopilotProfile, ss: np.random.SeedSequence) -> None:
        """The autopilot's velocity-estimate error (profile; none for ideal: no draw, no cost)."""
        self.verr: list[GaussMarkov] = []
        self.rng: np.random.Generator | None = None
        if pr.velocity_error_m_s > 0.0:
            self.rng = np.random.default_rng(ss.spawn(1)[0])
            self.verr = [
                GaussMarkov(pr.velocity_error_m_s, pr.velocity_error_tau_s),
                GaussMarkov(pr.velocity_error_m_s, pr.velocity_error_tau_s),
                GaussMarkov(pr.velocity_error_down_m_s, pr.velocity_error_tau_s),
            ]
            for w in self.verr:
                w.x = w.sigma * float(self.rng.standard_normal())

    def _init_state(
        self, pr: AutopilotProfile, ss: np.random.SeedSequence, rng_misc: np.random.Generator, pd: float
    ) -> None:
        """The estimator's state for this flight (drawn after the error's start so a profile
        without states draws exactly as before)."""
        self.state: EstimatorState | None = None
        self.att_bias = (0.0, 0.0, 0.0)  # reported - true roll, pitch, yaw (rad)
        self.pos_bias = [0.0, 0.0]  # the position estimate's share of the velocity bias (N, E; m)
        self.above_start = False
        self.descent_t0: float | None = None
        self.drift_m_s2: tuple[float, ...] = (0.0, 0.0)
        if not pr.estimator_states:
            return
        u = float(self.rng.uniform()) if self.rng is not None and self.verr else float(rng_misc.uniform())
        acc = 0.0
        for es in pr.estimator_states:
            acc += es.probability
            self.state = es
            if u < acc:
                break
        assert self.state is not None
        roll_b, pitch_b, yaw_b = self.state.attitude_bias_deg
        self.att_bias = (math.radians(roll_b), math.radians(pitch_b), math.radians(yaw_b))
        # the position estimate's share of the bias, from its steady state on the ground
        tau_p = self.state.position_follows_bias_tau_s
        b0 = self.velocity_bias(0.0, pd)
        self.pos_bias = [b0[0] * tau_p, b0[1] * tau_p]
        # the drift's rates from a stream of their own: every other draw stays as it was
        rng = np.random.default_rng(ss.spawn(1)[0])
        self.drift_m_s2 = tuple(VELOCITY_BIAS_DRIFT_RATE_M_S2 * x for x in rng.standard_normal(2).tolist())

    def velocity_bias(self, time_s: float, pd: float) -> tuple[float, float]:
        """The estimator state's horizontal velocity bias (N, E): linear between the heights it
        was measured at, constant outside them. In a descent from above the traced descent's start,
        at the height that descent had reached after the time since passing it (the estimate
        wanders with time in calm flight, so a slower descent or a hover lands on more of it);
        elsewhere at the true height above ground (the vehicle at down ``pd``)."""
        es = self.state
        if es is None:
            return (0.0, 0.0)
        hs, vs = VELOCITY_BIAS_HEIGHTS_M, es.velocity_bias_m_s
        if self.descent_t0 is not None:
            h = VELOCITY_BIAS_DESCENT_START_M - VELOCITY_BIAS_DESCENT_SPEED_M_S * (time_s - self.descent_t0)
            if h < hs[0]:  # past the traced window: drifting on
                late_s = (hs[0] - h) / VELOCITY_BIAS_DESCENT_SPEED_M_S
                cap = VELOCITY_BIAS_DRIFT_MAX_M_S
                dn, de = (max(-cap, min(cap, r * late_s)) for r in self.drift_m_s2)
                return (vs[0][0] + dn, vs[0][1] + de)
        else:
            h = -pd
        if h <= hs[0]:
            return vs[0]
        for i in range(1, len(hs)):
            if h <= hs[i]:
                k = (h - hs[i - 1]) / (hs[i] - hs[i - 1])
                a, b = vs[i - 1], vs[i]
                return (a[0] + k * (b[0] - a[0]), a[1] + k * (b[1] - a[1]))
        return vs[-1]

    def step(self, t: float, dt: float, pd: float) -> None:
        """One physics step: the velocity error's wander, then the estimator state's bias."""
        if self.verr:
            assert self.rng is not None
            rv = self.rng.standard_normal(3).tolist()
            for i in range(3):
                self.verr[i].step(dt, rv[i])
        if self.state is not None:
            self._step_bias(t, dt, pd)

    def _step_bias(self, t: float, dt: float, pd: float) -> None:
        """The estimator state's position bias: it drifts with the velocity bias, GPS pulls it
        back (EstimatorState); and the time the traced descent's start was passed on the way down."""
        es = self.state
        assert es is not None
        if -pd > VELOCITY_BIAS_DESCENT_START_M:
            self.above_start, self.descent_t0 = True, None
        elif self.above_start:  # passing the traced descent's start on the way down
            self.above_start, self.descent_t0 = False, t
        # exact step of de/dt = b - e / tau for b constant over dt
        bn, be = self.velocity_bias(t, pd)
        tau_p = es.position_follows_bias_tau_s
        a = math.exp(-dt / tau_p)
        self.pos_bias[0] = a * self.pos_bias[0] + (1.0 - a) * tau_p * bn
        self.pos_bias[1] = a * self.pos_bias[1] + (1.0 - a) * tau_p * be

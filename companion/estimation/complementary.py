"""Complementary filter on an attitude vector (dart eq 14), used by FCF-CF (dart sec. 3.2.4).

dart eq 14:   Phi_hat[k+1] = lambda (Phi_hat[k] + T Omega[k]) + (1 - lambda) Phi[k]

with Phi the attitude measured by the vision system and Omega the angular velocity from the
gyroscope. The filter is split into its two halves so the two sensors can run at their own
rates (gyroscope 200 Hz, vision ~30 Hz aperiodic, dart sec. 4):

- :meth:`ComplementaryFilter.predict` integrates the gyro term, Phi_hat += T Omega, at every
  gyro sample (summed over a vision period this is the T Omega of eq 14 with T the vision
  period);
- :meth:`ComplementaryFilter.correct` blends a vision measurement, Phi_hat = lambda Phi_hat +
  (1 - lambda) Phi, written as Phi_hat + (1 - lambda) wrap(Phi - Phi_hat) so that angles near
  +-pi blend the short way round (algebraically eq 14).

:meth:`ComplementaryFilter.update` is eq 14 in one call.

``Omega`` is the rate of change of the angle vector. The paper feeds the gyro rates directly
(a small-angle approximation); callers that know the Euler kinematics pass the Euler rates
(J_r(Phi) omega, geometry.euler_rates_matrix) — dart_estimators.FcfCfEstimator does.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Sequence

from companion.geometry import wrap_angle
from companion.param_kinds import ComplementaryTable

logger = logging.getLogger(__name__)


#: dart eq 14 weight lambda and the wrapped components: ``[estimator.complementary]`` of a Dart
#: file, every key declared once (unit, limits, description) in
#: companion.param_kinds.ComplementaryTable (``from_time_constant`` too)
ComplementaryConfig = ComplementaryTable


class ComplementaryFilter:
    """dart eq 14 on a 3-vector of angles (rad). Pure and synchronous.

    The state is undefined until the first vision measurement (``initialised``); the first
    measurement is taken as is. Non-finite inputs are rejected and counted in ``rejected``.
    """

    def __init__(self, config: ComplementaryConfig | None = None) -> None:
        self.config = config or ComplementaryConfig()
        self._phi = [0.0, 0.0, 0.0]
        self._t: float | None = None
        self.initialised = False
        self.rejected = 0
        self.gaps = 0

    @property
    def angles(self) -> tuple[float, float, float]:
        return (self._phi[0], self._phi[1], self._phi[2])

    @property
    def time_s(self) -> float | None:
        return self._t

    def reset(self, angles: Sequence[float] | None = None, time_s: float | None = None) -> None:
        if angles is None:
            self._phi = [0.0, 0.0, 0.0]
            self.initialised = False
        else:
            self._phi = [float(a) for a in angles]
            self.initialised = True
        self._t = time_s

    def predict(self, time_s: float, rates: Sequence[float]) -> bool:
        """The gyro half of dart eq 14: Phi_hat += T Omega, T from the timestamps."""
        r0, r1, r2 = rates
        if not (math.isfinite(time_s) and math.isfinite(r0) and math.isfinite(r1) and math.isfinite(r2)):
            self.rejected += 1
            return False
        t_prev = self._t
        if t_prev is None:
            self._t = time_s
            return True
        dt = time_s - t_prev
        if not dt > 0.0:
            self.rejected += 1
            return False
        if dt > self.config.max_dt_s:
            dt = self.config.max_dt_s
            self.gaps += 1
        self._t = time_s
        if self.initialised:
            phi = self._phi
            w0, w1, w2 = self.config.wrap
            a0 = phi[0] + dt * r0
            a1 = phi[1] + dt * r1
            a2 = phi[2] + dt * r2
            phi[0] = wrap_angle(a0) if w0 else a0
            phi[1] = wrap_angle(a1) if w1 else a1
            phi[2] = wrap_angle(a2) if w2 else a2
        return True

    def correct(self, measured: Sequence[float]) -> bool:
        """The vision half of dart eq 14: Phi_hat = lambda Phi_hat + (1 - lambda) Phi."""
        m = [float(v) for v in measured]
        if len(m) != 3 or not all(math.isfinite(v) for v in m):
            self.rejected += 1
            return False
        if not self.initialised:
            self._phi = m
            self.initialised = True
            return True
        k = 1.0 - self.config.lam
        phi = self._phi
        for i, w in enumerate(self.config.wrap):
            innov = wrap_angle(m[i] - phi[i]) if w else m[i] - phi[i]
            v = phi[i] + k * innov
            phi[i] = wrap_angle(v) if w else v
        return True

    def update(
        self, time_s: float, rates: Sequence[float], measured: Sequence[float] | None
    ) -> tuple[float, float, float]:
        """dart eq 14 in one step: predict with the gyro, then blend ``measured`` (if any)."""
        self.predict(time_s, rates)
        if measured is not None:
            self.correct(measured)
        return self.angles

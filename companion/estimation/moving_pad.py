"""The delivery EKF extended to a pad that moves (``[landing.moving_pad]``, docs/moving-pad.md).

The paper's filter (delivery section 4.2.3, eqs 10-11) models the GPS bias as a random walk,
b_p' = 0 + noise, in a frame in which the pad sits at its configured place: a displaced pad is a
constant bias (delivery 5.2). A pad on a moving vehicle is a bias that changes at the pad's
velocity. With p the vehicle in the pad-fixed frame and g the GPS position (eq 12, xi = 1:
g = p + b_p), p = x - (pad(t) - pad_0) and b_p = g - p = pad(t) - pad_0 + GPS error, so

    p' = u_v - xi [v; 0],      b_p' = [v; 0],      v' = w  (white, the pad's acceleration)

with v the pad's horizontal velocity (north, east): a constant-velocity model on the horizontal
bias, two states appended to eq 10's twelve (x[12:14]). Before xi = 1 (no pad-local datum yet) p
is the GPS-frame position, which the pad's motion does not move (eq 12 with xi = 0), so the
coupling into p is off until the switch; the coupling into b_p is always on (b_p has no
observation then either). The measurement models (eqs 12-15) are unchanged: v enters only
through the prediction. Eq 11 becomes, for the two new rows and the coupling,

    p_h <- p_h - xi v dt,    b_p,h <- b_p,h + v dt,    v <- v,

F gains -xi dt I at (p_h, v) and +dt I at (b_p,h, v), and Q_f gains sigma_a^2 dt on v (a random
walk on the velocity: the pad's acceleration as white noise of density sigma_a^2). The filter is
the dense form (14 states: ~2x the cost of the 12-state sparse one, which stays the default bit
for bit: the moving pad is opt-in).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from companion.config import EkfConfig, MovingPadConfig
from companion.estimation.ekf import (
    _TWO_PI,
    DeliveryEkf,
    EkfSensor,
    propagate,
    propagation_jacobians,
)
from companion.geometry import Transform

N_MOVING = 14
V_IDX = slice(12, 14)  # the pad's velocity (north, east), m/s


def propagate_moving(x: np.ndarray, u: np.ndarray, dt: float, xi: float) -> np.ndarray:
    """f(x, u, dt) of delivery eq 11 with the pad's velocity (module doc): 14 states."""
    out = np.empty(N_MOVING)
    out[0:12] = propagate(x[0:12], u, dt)
    v = x[12:14]
    out[0:2] -= xi * v * dt  # the vehicle in the pad-fixed frame: the pad drives away under it
    out[6:8] += v * dt  # the bias follows the pad
    out[12:14] = v
    return out


def moving_jacobians(x: np.ndarray, u: np.ndarray, dt: float, xi: float) -> tuple[np.ndarray, np.ndarray]:
    """F = df/dx (14x14) and G = df/du (14x6) of :func:`propagate_moving` (eq 6's Jacobians)."""
    F12, G12 = propagation_jacobians(x[0:12], u, dt)
    F = np.eye(N_MOVING)
    F[0:12, 0:12] = F12
    F[0, 12] = F[1, 13] = -xi * dt
    F[6, 12] = F[7, 13] = dt
    G = np.zeros((N_MOVING, 6))
    G[0:12] = G12
    return F, G


class MovingPadEkf(DeliveryEkf):
    """:class:`DeliveryEkf` with the pad's horizontal velocity (14 states; module doc). The
    measurement updates are the 12-state filter's (their Jacobians have zero columns for v)."""

    def __init__(
        self,
        config: EkfConfig | None = None,
        moving_pad: MovingPadConfig | None = None,
        T_body_camera: Transform | None = None,
        x0: ArrayLike | None = None,
        pad_down_m: float = 0.0,
    ) -> None:
        x12 = None if x0 is None else np.asarray(x0, dtype=float).reshape(N_MOVING)[0:12]
        super().__init__(config, T_body_camera=T_body_camera, x0=x12, pad_down_m=pad_down_m)
        mp = self.moving_pad = moving_pad or MovingPadConfig(enabled=True)
        x = np.zeros(N_MOVING)
        x[0:12] = self.x
        if x0 is not None:
            x[12:14] = np.asarray(x0, dtype=float).reshape(N_MOVING)[12:14]
        P = np.zeros((N_MOVING, N_MOVING))
        P[0:12, 0:12] = self.P
        P[12, 12] = P[13, 13] = mp.initial_speed_sigma_m_s**2
        if not np.all(np.isfinite(x)):
            raise ValueError("x0 must be finite")
        self.x, self.P = x, P
        self._qf14 = np.concatenate([self._qf_density, [mp.accel_sigma_m_s2**2] * 2])
        self._Qu6 = np.diag(self._qu)

    @property
    def pad_velocity_ne(self) -> tuple[float, float]:
        """The pad's estimated velocity (north, east; m/s)."""
        return float(self.x[12]), float(self.x[13])

    @property
    def pad_velocity_sigma_m_s(self) -> float:
        """1-sigma of the pad's estimated speed (the larger axis; m/s)."""
        return math.sqrt(max(float(self.P[12, 12]), float(self.P[13, 13])))

    @property
    def process_noise_density(self) -> np.ndarray:
        """Q_f's diagonal per second (a copy): eq 6's twelve, then the pad velocity's (m/s)^2/s."""
        return self._qf14.copy()

    def predict(self, u: ArrayLike, dt_s: float) -> bool:
        """Eqs 5, 6 with the extended eq 11 (module doc), dense."""
        steps = self._dense_steps(u, dt_s)
        if steps is None:
            return False
        uu, n, h = steps
        Qf = np.diag(self._qf14 * h)
        xi = 1.0 if self.xi else 0.0
        for _ in range(n):
            F, G = moving_jacobians(self.x, uu, h, xi)
            self.x = propagate_moving(self.x, uu, h, xi)  # eq 5 with the extended eq 11
            self.P = F @ self.P @ F.T + G @ self._Qu6 @ G.T + Qf  # eq 6
        self.x[3] = (self.x[3] + math.pi) % _TWO_PI - math.pi
        self.x[5] = (self.x[5] + math.pi) % _TWO_PI - math.pi
        self.P = (self.P + self.P.T) * 0.5
        self._condition()
        return True

    def _note_gate_rejection(self, sensor: EkfSensor) -> None:
        """As the 12-state filter's; a pad sensor's reset also forgets the pad's velocity."""
        before = self.counters[self._gate_resets_key[sensor]]
        super()._note_gate_rejection(sensor)
        if self.counters[self._gate_resets_key[sensor]] != before and sensor is not EkfSensor.SDK and self.xi:
            self.P[V_IDX, :] = 0.0
            self.P[:, V_IDX] = 0.0
            self.P[V_IDX, V_IDX] = np.eye(2) * self.moving_pad.initial_speed_sigma_m_s**2

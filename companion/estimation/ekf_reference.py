"""The 12-state EKF's steps in their straightforward dense form (delivery eqs 5-15): the
reference that :mod:`companion.estimation.ekf`, which exploits the model's sparsity, is checked
and timed against.

:class:`DenseDeliveryEkf` is a :class:`~companion.estimation.ekf.DeliveryEkf` whose prediction
and correction are the textbook products: eq 6 with the full 12x12 F and 12x6 G, eq 9 with the
inverse of S, the Joseph form (I - KH) P (I - KH)^T + K R K^T with the full 12-column H, and
h_ArUco / its Jacobian from :func:`~companion.estimation.ekf.h_aruco` and
:func:`~companion.estimation.ekf.jacobian_aruco`. The tests check that the optimised filter
stays numerically equal to it (tests/estimation/test_ekf_sparse.py) and ``companion bench ekf``
times both in one run.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from companion.estimation.ekf import (
    _TWO_PI,
    N_STATES,
    DeliveryEkf,
    EkfSensor,
    UpdateOutcome,
    h_aruco,
    jacobian_aruco,
    propagate,
    propagation_jacobians,
)
from companion.geometry import Transform


def _dense_aruco_model(x: np.ndarray, T_bc: Transform, T_wm: Transform) -> tuple[np.ndarray, np.ndarray]:
    """Delivery eqs 13-14 and the full 6x12 Jacobian, each from its own function."""
    return h_aruco(x, T_bc, T_wm), jacobian_aruco(x, T_bc, T_wm)


class DenseDeliveryEkf(DeliveryEkf):
    """The same filter with every step in dense matrix form (the reference of the sparse one)."""

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self._aruco_model_fn = _dense_aruco_model

    def _symmetrise_and_condition(self) -> None:
        """(P + P^T) / 2 (the dense products are symmetric only to rounding), then the diagonal floor."""
        self.P = (self.P + self.P.T) * 0.5
        self._condition()

    def predict(self, u: ArrayLike, dt_s: float) -> bool:
        steps = self._dense_steps(u, dt_s)
        if steps is None:
            return False
        uu, n, h = steps
        Qf = np.diag(self._qf_density * h)
        for _ in range(n):
            F, G = propagation_jacobians(self.x, uu, h)
            self.x = propagate(self.x, uu, h)  # eq 5 with eq 11
            self.P = F @ self.P @ F.T + G @ self._Qu @ G.T + Qf  # eq 6
        self.x[3] = (self.x[3] + math.pi) % _TWO_PI - math.pi
        self.x[5] = (self.x[5] + math.pi) % _TWO_PI - math.pi
        self._symmetrise_and_condition()
        return True

    def _update(
        self, sensor: EkfSensor, z: np.ndarray, hx: np.ndarray, H: np.ndarray, R: np.ndarray, has_angles: bool
    ) -> UpdateOutcome:
        H_full = np.zeros((H.shape[0], N_STATES))
        H_full[:, 0 : H.shape[1]] = H
        H = H_full
        y = z - hx
        if has_angles:
            y[3:6] = (y[3:6] + math.pi) % _TWO_PI - math.pi
        PHt = self.P @ H.T
        S = H @ PHt + R
        S = 0.5 * (S + S.T)
        try:
            np.linalg.cholesky(S)  # S must be positive definite
            S_inv = np.linalg.inv(S)
        except np.linalg.LinAlgError:
            return self._count(sensor, UpdateOutcome.REJECTED_NUMERICAL)
        d2 = float(y @ S_inv @ y)
        gate = self._gate_threshold(len(y))
        if not math.isfinite(d2) or (self.config.gating_enabled and d2 > gate):
            self._note_gate_rejection(sensor)
            return self._count(sensor, UpdateOutcome.REJECTED_GATE)
        self.consecutive_rejections[sensor] = 0
        K = PHt @ S_inv  # eq 9
        self.x = self.x + K @ y  # eq 7
        self.x[3] = (self.x[3] + math.pi) % _TWO_PI - math.pi
        self.x[5] = (self.x[5] + math.pi) % _TWO_PI - math.pi
        IKH = np.eye(N_STATES) - K @ H
        self.P = IKH @ self.P @ IKH.T + K @ R @ K.T  # Joseph form of eq 8
        self._symmetrise_and_condition()
        return self._count(sensor, UpdateOutcome.ACCEPTED)

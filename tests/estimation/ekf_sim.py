"""A small synthetic flight for the EKF tests: truth, noisy inputs and sensor samples."""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from companion.geometry import Transform, euler_rates_matrix

GPS_BIAS = np.array([1.5, -2.0, 0.7])
GYRO_BIAS = np.array([0.01, -0.015, 0.008])
HOVER = np.array([8.0, -6.0, -20.0])
LAND = np.array([0.2, -0.1, -1.5])


def _smooth(s: float) -> float:
    s = min(1.0, max(0.0, s))
    return s * s * (3 - 2 * s)


@dataclass(frozen=True)
class Truth:
    t: float
    p: np.ndarray
    v: np.ndarray
    euler: np.ndarray
    rates_body: np.ndarray


def position(t: float, t_hover: float = 10.0, t_descent: float = 40.0) -> np.ndarray:
    s = _smooth((t - t_hover) / t_descent)
    p = HOVER + (LAND - HOVER) * s
    p = p + np.array([0.0, 0.4 * math.sin(0.5 * t), 0.0])
    return p


def euler(t: float) -> np.ndarray:
    return np.array([0.05 * math.sin(0.7 * t), 0.04 * math.cos(0.5 * t), 0.3 + 0.02 * t])


def truth(t: float) -> Truth:
    h = 1e-5
    v = (position(t + h) - position(t - h)) / (2 * h)
    r = euler(t)
    rdot = (euler(t + h) - euler(t - h)) / (2 * h)
    w = np.linalg.solve(euler_rates_matrix(r[0], r[1]), rdot)
    return Truth(t, position(t), v, r, w)


def aruco_truth(tr: Truth, T_body_camera: Transform, T_world_marker: Transform) -> Transform:
    T_wb = Transform.from_euler(tr.p, *tr.euler)
    return T_body_camera.inverse() @ T_wb.inverse() @ T_world_marker  # delivery eq 13

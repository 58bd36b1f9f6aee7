"""Every EKF Jacobian (delivery eqs 6, 11-15) against central finite differences."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.estimation.ekf import (
    h_aruco,
    h_sdk,
    h_uwb,
    jacobian_aruco,
    jacobian_sdk,
    jacobian_uwb,
    propagate,
    propagation_jacobians,
    wrap_angles,
)
from companion.geometry import Transform, euler_rates_matrix, euler_to_rotmat

EPS = 1e-6


def _fd(fn, x: np.ndarray, angle_rows: tuple[int, ...] = ()) -> np.ndarray:  # type: ignore[no-untyped-def]
    cols = []
    for k in range(len(x)):
        e = np.zeros(len(x))
        e[k] = EPS
        diff = fn(x + e) - fn(x - e)
        if angle_rows:
            idx = list(angle_rows)
            diff[idx] = wrap_angles(diff[idx])
        cols.append(diff / (2 * EPS))
    return np.column_stack(cols)


def _states(n: int, seed: int = 0) -> list[np.ndarray]:
    rng = np.random.default_rng(seed)
    out = []
    for _ in range(n):
        x = np.concatenate(
            [
                rng.uniform(-20, 20, 3),
                [rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.uniform(-math.pi, math.pi)],
                rng.uniform(-3, 3, 3),
                rng.uniform(-0.05, 0.05, 3),
            ]
        )
        out.append(x)
    return out


CAMERA_DOWN = Transform(euler_to_rotmat(0.0, 0.0, math.pi / 2), np.array([0.1, 0.0, 0.05]))
MARKER_FLAT = Transform(euler_to_rotmat(math.pi, 0.0, 0.3), np.array([2.0, -1.0, 0.0]))


def test_propagation_is_eq11() -> None:
    x = _states(1)[0]
    u = np.array([1.0, -2.0, 0.5, 0.1, -0.2, 0.3])
    dt = 0.01
    out = propagate(x, u, dt)
    np.testing.assert_allclose(out[0:3], x[0:3] + u[0:3] * dt)
    np.testing.assert_allclose(out[3:6], x[3:6] + euler_rates_matrix(x[3], x[4]) @ (u[3:6] - x[9:12]) * dt)
    np.testing.assert_array_equal(out[6:12], x[6:12])  # constant biases


@pytest.mark.parametrize("seed", range(5))
def test_F_and_G_match_finite_differences(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    for x in _states(4, seed):
        u = np.concatenate([rng.uniform(-5, 5, 3), rng.uniform(-1.5, 1.5, 3)])
        dt = float(rng.uniform(0.001, 0.1))
        F, G = propagation_jacobians(x, u, dt)
        np.testing.assert_allclose(F, _fd(lambda xx, u=u, dt=dt: propagate(xx, u, dt), x), atol=1e-8)
        np.testing.assert_allclose(G, _fd(lambda uu, x=x, dt=dt: propagate(x, uu, dt), u), atol=1e-8)


@pytest.mark.parametrize("xi", [0.0, 1.0])
@pytest.mark.parametrize("with_angles", [True, False])
def test_H_sdk_matches_finite_differences(xi: float, with_angles: bool) -> None:
    for x in _states(5, 7):
        H = jacobian_sdk(xi, with_angles)
        np.testing.assert_allclose(H, _fd(lambda xx: h_sdk(xx, xi, with_angles), x), atol=1e-8)
        # eq 12: xi switches the bias in
        expected = x[0:3] + xi * x[6:9]
        np.testing.assert_allclose(h_sdk(x, xi, with_angles)[0:3], expected)


def test_H_uwb_matches_finite_differences() -> None:
    for x in _states(5, 8):
        np.testing.assert_allclose(jacobian_uwb(), _fd(h_uwb, x), atol=1e-9)
        np.testing.assert_array_equal(h_uwb(x), x[0:3])  # eq 15


def test_h_aruco_is_eq13() -> None:
    for x in _states(5, 9):
        T_wb = Transform.from_euler(x[0:3], x[3], x[4], x[5])
        T_cm = CAMERA_DOWN.inverse() @ T_wb.inverse() @ MARKER_FLAT  # eq 13
        h = h_aruco(x, CAMERA_DOWN, MARKER_FLAT)
        np.testing.assert_allclose(h[0:3], T_cm.t, atol=1e-12)
        np.testing.assert_allclose(euler_to_rotmat(*h[3:6]), T_cm.R, atol=1e-12)  # eq 14


@pytest.mark.parametrize("seed", range(4))
def test_H_aruco_matches_finite_differences(seed: int) -> None:
    rng = np.random.default_rng(200 + seed)
    for x in _states(5, seed + 20):
        # hovering over the marker with the camera looking down (roll of T_camera_marker ~ pi,
        # right at the wrap) and arbitrary mounts and marker poses
        for T_bc, T_wm in (
            (CAMERA_DOWN, MARKER_FLAT),
            (
                Transform(euler_to_rotmat(*rng.uniform(-0.5, 0.5, 3)), rng.uniform(-0.2, 0.2, 3)),
                Transform(euler_to_rotmat(*rng.uniform(-1.0, 1.0, 3)), rng.uniform(-5, 5, 3)),
            ),
        ):
            H = jacobian_aruco(x, T_bc, T_wm)
            num = _fd(lambda xx, T_bc=T_bc, T_wm=T_wm: h_aruco(xx, T_bc, T_wm), x, angle_rows=(3, 4, 5))
            np.testing.assert_allclose(H, num, atol=1e-6)
            assert np.all(H[:, 6:12] == 0.0)


def test_wrap_angles_range() -> None:
    a = np.array([-3 * math.pi, -math.pi, 0.0, math.pi, 2.5 * math.pi, 7.0])
    w = wrap_angles(a)
    assert np.all(w >= -math.pi) and np.all(w < math.pi)
    np.testing.assert_allclose(np.cos(w), np.cos(a), atol=1e-12)
    np.testing.assert_allclose(np.sin(w), np.sin(a), atol=1e-12)

import math

import numpy as np
import pytest

from companion.geometry import (
    Transform,
    euler_rates_matrix,
    euler_to_quat,
    euler_to_rotmat,
    quat_multiply,
    quat_to_euler,
    quat_to_rotmat,
    rotmat_to_euler,
    rotmat_to_quat,
    wrap_angle,
)

rng = np.random.default_rng(7)
ANGLES = [(r, p, y) for r, p, y in rng.uniform([-3, -1.5, -3.1], [3, 1.5, 3.1], size=(50, 3))]


@pytest.mark.parametrize("rpy", ANGLES)
def test_euler_rotmat_quat_round_trips(rpy):
    R = euler_to_rotmat(*rpy)
    assert np.allclose(R @ R.T, np.eye(3), atol=1e-12)
    assert math.isclose(np.linalg.det(R), 1.0, abs_tol=1e-12)
    assert np.allclose(rotmat_to_euler(R), rpy, atol=1e-9)
    q = euler_to_quat(*rpy)
    assert np.allclose(quat_to_rotmat(q), R, atol=1e-12)
    assert np.allclose(quat_to_euler(q), rpy, atol=1e-9)
    assert np.allclose(quat_to_rotmat(rotmat_to_quat(R)), R, atol=1e-12)


def test_zyx_convention_hand_computed():
    # yaw 90 deg: body x (forward) points east in NED
    R = euler_to_rotmat(0.0, 0.0, math.pi / 2)
    assert np.allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    # pitch +30 deg (nose up): body x points north and up (negative down)
    R = euler_to_rotmat(0.0, math.radians(30), 0.0)
    assert np.allclose(R @ [1, 0, 0], [math.cos(math.radians(30)), 0, -0.5], atol=1e-12)


def test_quaternion_product_composes_rotations():
    a, b = euler_to_quat(0.1, 0.2, 0.3), euler_to_quat(-0.4, 0.1, 1.0)
    assert np.allclose(quat_to_rotmat(quat_multiply(a, b)), quat_to_rotmat(a) @ quat_to_rotmat(b), atol=1e-12)


def test_euler_rates_matrix_matches_numerical_derivative():
    # J_r (delivery eq 11): d/dt euler = J_r @ body_rates. Check by integrating R' = R [w]x.
    rpy = np.array([0.3, -0.4, 1.2])
    w = np.array([0.5, -0.2, 0.8])
    dt = 1e-6
    R = euler_to_rotmat(*rpy)
    wx = np.array([[0, -w[2], w[1]], [w[2], 0, -w[0]], [-w[1], w[0], 0]])
    R2 = R @ (np.eye(3) + wx * dt)
    u, _, vt = np.linalg.svd(R2)
    num = (np.array(rotmat_to_euler(u @ vt)) - rpy) / dt
    assert np.allclose(euler_rates_matrix(rpy[0], rpy[1]) @ w, num, atol=1e-5)


def test_wrap_angle():
    assert math.isclose(wrap_angle(3 * math.pi / 2), -math.pi / 2)
    assert math.isclose(wrap_angle(-3 * math.pi / 2), math.pi / 2)
    assert -math.pi <= wrap_angle(math.pi) < math.pi


def test_transform_compose_and_inverse():
    T_ab = Transform.from_euler([1, 2, 3], 0.1, 0.2, 0.3)
    T_bc = Transform.from_euler([-1, 0.5, 2], -0.3, 0.1, 1.0)
    p_c = np.array([0.3, -0.7, 1.1])
    assert np.allclose((T_ab @ T_bc).apply(p_c), T_ab.apply(T_bc.apply(p_c)))
    assert np.allclose((T_ab @ T_ab.inverse()).matrix(), np.eye(4), atol=1e-12)
    assert np.allclose(Transform.from_matrix(T_ab.matrix()).t, T_ab.t)
    with pytest.raises(ValueError):
        Transform.from_matrix(np.eye(3))

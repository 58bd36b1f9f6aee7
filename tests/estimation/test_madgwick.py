"""Madgwick filter (dart eqs 8-13)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.estimation.madgwick import MadgwickConfig, MadgwickFilter, quat_to_euler_floats
from companion.geometry import (
    euler_to_quat,
    euler_to_rotmat,
    quat_conjugate,
    quat_multiply,
    quat_to_euler,
    quat_to_rotmat,
)

G = 9.80665
DT = 1.0 / 200.0


def specific_force(R_wb: np.ndarray) -> tuple[float, float, float]:
    """What a perfect accelerometer at rest reads: -gravity in the body frame (FRD)."""
    f = R_wb.T @ np.array([0.0, 0.0, -G])
    return (float(f[0]), float(f[1]), float(f[2]))


def tilt_error(q_est: np.ndarray, R_true: np.ndarray) -> float:
    """Angle between the estimated and true 'down' directions in the body: the observable part."""
    d_est = quat_to_rotmat(q_est).T @ np.array([0.0, 0.0, 1.0])
    d_true = R_true.T @ np.array([0.0, 0.0, 1.0])
    return math.acos(max(-1.0, min(1.0, float(d_est @ d_true))))


def rotation_error(q_est: np.ndarray, q_true: np.ndarray) -> float:
    dq = quat_multiply(quat_conjugate(q_true), q_est)
    return 2.0 * math.acos(min(1.0, abs(float(dq[0]))))


def test_static_roll_pitch_converge_from_wrong_start() -> None:
    true_rpy = (0.2, -0.3, 0.4)
    R = euler_to_rotmat(*true_rpy)
    f = MadgwickFilter()
    f.reset_euler(-0.4, 0.3, -0.5)  # about 0.6 rad off in roll and pitch
    a = specific_force(R)
    errors = []
    for k in range(1200):  # 6 s at 200 Hz, gravity only
        assert f.update(k * DT, (0.0, 0.0, 0.0), a)
        errors.append(tilt_error(np.array(f.quaternion), R))
    roll, pitch, _ = f.euler()
    # the accelerometer correction is gamma*mu/T = 0.1 /s in quaternion units, 0.2 rad/s
    assert errors[0] > 0.5
    assert errors[-1] < 0.005
    assert abs(roll - true_rpy[0]) < 0.005 and abs(pitch - true_rpy[1]) < 0.005
    # the tilt error decreases (no divergence), roughly at the fixed step rate
    assert errors[400] < errors[0] - 0.25
    # yaw is not observable from the accelerometer: it is not tested


def _body_rate_truth(q0: np.ndarray, w: np.ndarray, t: float) -> np.ndarray:
    """Exact attitude for a constant body rate: q(t) = q0 (x) exp(w t / 2)."""
    n = float(np.linalg.norm(w))
    half = 0.5 * n * t
    dq = np.concatenate([[math.cos(half)], math.sin(half) * w / n])
    return quat_multiply(q0, dq)


def test_tracks_constant_rate_rotation_with_noise_and_jitter() -> None:
    rng = np.random.default_rng(42)
    q0 = euler_to_quat(0.1, -0.1, 0.3)
    w = np.array([0.3, -0.2, 0.5])  # rad/s, body frame
    f = MadgwickFilter(q_init=tuple(q0))
    t = 0.0
    tilt_errors = []
    rot_errors = []
    for _ in range(800):  # ~4 s, jittered sampling 3-7 ms
        q_true = _body_rate_truth(q0, w, t)
        R = quat_to_rotmat(q_true)
        gyro = w + rng.normal(0.0, 0.005, 3)
        acc = np.array(specific_force(R)) + rng.normal(0.0, 0.05, 3)
        assert f.update(t, tuple(gyro), tuple(acc))
        tilt_errors.append(tilt_error(np.array(f.quaternion), R))
        rot_errors.append(rotation_error(np.array(f.quaternion), q_true))
        t += float(rng.uniform(0.003, 0.007))
    # observable tilt stays tight throughout
    assert max(tilt_errors) < 0.02
    # yaw from the gyro only: eq 13 scales the gyro term by (1 - gamma); over ~2.5 rad of
    # rotation that is ~0.013 rad, plus noise
    assert max(rot_errors) < 0.03
    assert f.rejected == 0 and f.accel_rejected == 0


def test_one_step_matches_eqs_8_to_13_by_hand() -> None:
    """An independent numpy computation of eqs 8, 12, 13 for one sample."""
    cfg = MadgwickConfig(mu=0.2, gamma=0.3, nominal_rate_hz=100.0)
    q = euler_to_quat(0.3, -0.2, 0.1)
    f = MadgwickFilter(cfg, q_init=tuple(q))
    gyro = np.array([0.4, -0.1, 0.2])
    acc = np.array([1.0, -2.0, -9.0])
    T = 0.02  # twice the nominal period: mu[kT] = 0.2 * 2 = 0.4
    assert f.update(1.0, (0.0, 0.0, 0.0), tuple(acc))  # starts the clock only
    assert np.allclose(f.quaternion, q)
    f.update(1.0 + T, tuple(gyro), tuple(acc))

    # eq 8 with eq 7: q_g = q + T * 0.5 * q (x) (0, w)
    q_g = q + T * 0.5 * quat_multiply(q, np.concatenate([[0.0], gyro]))
    # eqs 9-11: f = R^T e_z - (-a/|a|), J = df/dq, grad = J^T f
    w_, x, y, z = q
    d = -acc / np.linalg.norm(acc)
    fv = np.array(
        [
            2 * (x * z - w_ * y) - d[0],
            2 * (w_ * x + y * z) - d[1],
            1 - 2 * (x * x + y * y) - d[2],
        ]
    )
    J = np.array(
        [
            [-2 * y, 2 * z, -2 * w_, 2 * x],
            [2 * x, 2 * w_, 2 * z, 2 * y],
            [0.0, -4 * x, -4 * y, 0.0],
        ]
    )
    grad = J.T @ fv
    # eq 12 with mu[kT] = mu T / T_nom
    q_a = q - 0.2 * (T / 0.01) * grad / np.linalg.norm(grad)
    # eq 13
    fused = 0.3 * q_a + 0.7 * q_g
    fused /= np.linalg.norm(fused)
    assert np.allclose(f.quaternion, fused, atol=1e-12)


def test_euler_output_is_zyx_of_the_quaternion() -> None:
    rng = np.random.default_rng(1)
    for _ in range(20):
        rpy = (rng.uniform(-3, 3), rng.uniform(-1.4, 1.4), rng.uniform(-3, 3))
        q = euler_to_quat(*rpy)
        assert np.allclose(quat_to_euler_floats(*q), quat_to_euler(q), atol=1e-12)
        f = MadgwickFilter(q_init=tuple(q))
        assert np.allclose(f.euler(), rpy, atol=1e-9)
        est = f.estimate()
        assert est.roll_rad == pytest.approx(rpy[0]) and est.yaw_rad == pytest.approx(rpy[2])


def test_rejects_and_counts_bad_samples() -> None:
    f = MadgwickFilter()
    level = (0.0, 0.0, -G)
    assert f.update(0.0, (0.0, 0.0, 0.0), level)
    q_before = f.quaternion
    assert not f.update(0.005, (math.nan, 0.0, 0.0), level)  # NaN gyro: whole sample dropped
    assert not f.update(0.005, (0.0, math.inf, 0.0), level)
    assert not f.update(math.nan, (0.0, 0.0, 0.0), level)
    assert not f.update(0.0, (0.0, 0.0, 0.0), level)  # time did not advance
    assert f.rejected == 4 and f.quaternion == q_before

    # NaN or zero accelerometer: gyro-only propagation (eq 8), counted
    assert f.update(0.01, (0.0, 0.0, 1.0), (math.nan, 0.0, -G))
    assert f.update(0.02, (0.0, 0.0, 1.0), (0.0, 0.0, 0.0))
    assert f.update(0.03, (0.0, 0.0, 1.0), (0.0, 0.0, 1e6))
    assert f.accel_rejected == 3
    # three gyro-only steps of 10 ms at 1 rad/s (the rejected samples did not move the clock):
    # yaw 0.03 rad, no (1 - gamma) factor
    assert f.euler()[2] == pytest.approx(0.03, abs=1e-5)
    assert all(math.isfinite(v) for v in f.quaternion)

    # a long gap is integrated as max_dt_s and counted
    f.update(10.0, (0.0, 0.0, 1.0), (math.nan, 0.0, 0.0))
    assert f.gaps == 1
    assert f.euler()[2] == pytest.approx(0.03 + 0.1, abs=1e-3)


def test_reset_from_accel() -> None:
    R = euler_to_rotmat(0.25, -0.15, 0.0)
    f = MadgwickFilter()
    assert f.reset_from_accel(specific_force(R), yaw_rad=0.7)
    assert np.allclose(f.euler(), (0.25, -0.15, 0.7), atol=1e-9)
    assert not f.reset_from_accel((0.0, 0.0, 0.0))


def test_config_validation() -> None:
    with pytest.raises(ValueError):
        MadgwickConfig(gamma=1.5)
    with pytest.raises(ValueError):
        MadgwickConfig(mu=-1.0)
    with pytest.raises(ValueError):
        MadgwickFilter(q_init=(0.0, 0.0, 0.0, 0.0))

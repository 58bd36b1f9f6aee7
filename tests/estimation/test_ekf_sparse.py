"""The EKF's structured steps (sparse, exactly symmetric eq 6; one-pass h_ArUco + Jacobian; the
regrouped Joseph form on the non-zero columns of H; Cholesky solves) against the straightforward dense form
(:class:`companion.estimation.ekf_reference.DenseDeliveryEkf`), on seeded random states,
inputs and measurements."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.estimation.ekf import (
    DeliveryEkf,
    EkfConfig,
    EkfSensor,
    UpdateOutcome,
    aruco_model,
    h_aruco,
    jacobian_aruco,
    joseph_covariance,
    propagate,
    propagate_covariance,
    propagation_blocks,
    propagation_jacobians,
)
from companion.estimation.ekf_reference import DenseDeliveryEkf
from companion.geometry import Transform, euler_to_rotmat

RTOL = 1e-9


def _close(a: np.ndarray, b: np.ndarray) -> None:
    """Equal to ~1e-9 relative (entries far below the matrix's scale compared at that scale)."""
    scale = max(float(np.max(np.abs(b))), 1e-300)
    np.testing.assert_allclose(a, b, rtol=RTOL, atol=RTOL * scale)


def _random_state(rng: np.random.Generator) -> np.ndarray:
    x = np.empty(12)
    x[0:3] = rng.normal(0.0, 5.0, 3) + np.array([0.0, 0.0, -8.0])
    x[3:5] = rng.uniform(-0.6, 0.6, 2)
    x[5] = rng.uniform(-math.pi, math.pi)
    x[6:9] = rng.normal(0.0, 1.0, 3)
    x[9:12] = rng.normal(0.0, 0.02, 3)
    return x


def _random_cov(rng: np.random.Generator) -> np.ndarray:
    A = rng.normal(0.0, 1.0, (12, 12)) * rng.uniform(0.01, 1.0, 12)
    return A @ A.T + np.eye(12) * 1e-4


def _transform(rng: np.random.Generator, t_sigma: float) -> Transform:
    return Transform(euler_to_rotmat(*rng.uniform(-math.pi, math.pi, 3) * [1.0, 0.45, 1.0]), rng.normal(0, t_sigma, 3))


@pytest.mark.parametrize("seed", range(5))
def test_propagation_blocks_and_sparse_covariance_equal_the_dense_eq_6(seed: int) -> None:
    rng = np.random.default_rng(seed)
    Qu = np.diag(rng.uniform(0.01, 0.5, 6))
    for _ in range(40):
        x, P = _random_state(rng), _random_cov(rng)
        u = rng.normal(0.0, 1.0, 6)
        dt = float(rng.uniform(0.001, 0.05))
        qf = rng.uniform(1e-6, 1e-2, 12) * dt
        F, G = propagation_jacobians(x, u, dt)
        x_next, F3, G6 = propagation_blocks(x, u, dt)
        _close(x_next, propagate(x, u, dt))
        _close(F3, F[3:6])
        np.testing.assert_array_equal(F[[0, 1, 2, 6, 7, 8, 9, 10, 11]], np.eye(12)[[0, 1, 2, 6, 7, 8, 9, 10, 11]])
        _close(G6, G[0:6])
        assert not np.any(G[6:])
        dense = F @ P @ F.T + G @ Qu @ G.T + np.diag(qf)  # eq 6
        _close(propagate_covariance(P, F3, G6, np.diag(Qu), qf), dense)


@pytest.mark.parametrize("seed", range(5))
def test_aruco_model_equals_h_and_jacobian(seed: int) -> None:
    rng = np.random.default_rng(100 + seed)
    for _ in range(40):
        x = _random_state(rng)
        T_bc, T_wm = _transform(rng, 0.1), _transform(rng, 2.0)
        hx, H6 = aruco_model(x, T_bc, T_wm)
        _close(hx, h_aruco(x, T_bc, T_wm))
        H = jacobian_aruco(x, T_bc, T_wm)
        _close(H6, H[:, 0:6])
        assert not np.any(H[:, 6:])


def _pair(rng: np.random.Generator, gating: bool) -> tuple[DeliveryEkf, DenseDeliveryEkf, Transform]:
    T_bc = _transform(rng, 0.1)
    x0 = _random_state(rng)
    x0[0:3] = rng.normal(0.0, 1.0, 3) + np.array([0.0, 0.0, -6.0])
    P0 = _random_cov(rng) * 0.01
    cfg = EkfConfig(gating_enabled=gating)
    return (
        DeliveryEkf(cfg, T_body_camera=T_bc, x0=x0, P0=P0),
        DenseDeliveryEkf(cfg, T_body_camera=T_bc, x0=x0, P0=P0),
        T_bc,
    )


class _Fix:
    def __init__(self, p: np.ndarray, pdop: float) -> None:
        self.time_s, self.x_m, self.y_m, self.z_m, self.pdop = 0.0, float(p[0]), float(p[1]), float(p[2]), pdop


@pytest.mark.parametrize(("seed", "gating"), [(0, False), (1, False), (2, True), (3, True)])
def test_filter_runs_equal_the_dense_filter(seed: int, gating: bool) -> None:
    """Predict at 200 Hz with ArUco, UWB and SDK updates in between: the same outcomes, and x, P
    equal to ~1e-9 relative after every step (including the xi switch)."""
    rng = np.random.default_rng(200 + seed)
    fast, dense, T_bc = _pair(rng, gating)
    T_wm = Transform(euler_to_rotmat(math.pi, 0.0, rng.uniform(-math.pi, math.pi)), rng.normal(0, 0.5, 3))
    T_wa = _transform(rng, 1.0)
    outcomes = set()
    for i in range(300):
        u = rng.normal(0.0, 0.3, 6)
        dt = 0.005 if i % 50 else 0.12  # and now and then a long step (sub-stepped)
        assert fast.predict(u, dt) == dense.predict(u, dt)
        if i % 7 == 3:
            truth = dense.x + rng.normal(0.0, 0.05, 12)
            T_cm = (T_bc.inverse() @ Transform.from_euler(truth[0:3], *truth[3:6]).inverse()) @ T_wm
            T_cm = Transform(T_cm.R, T_cm.t + rng.normal(0.0, 0.2 if i % 21 == 3 else 0.01, 3))
            a, b = fast.update_aruco(T_cm, T_wm), dense.update_aruco(T_cm, T_wm)
        elif i % 7 == 5:
            fix = _Fix(rng.normal(0.0, 3.0, 3), float(rng.uniform(1.0, 3.0)))
            a, b = fast.update_uwb(fix, T_wa), dense.update_uwb(fix, T_wa)
        elif i % 11 == 0:
            pos, eul = dense.x[0:3] + rng.normal(0, 0.3, 3), dense.x[3:6] + rng.normal(0, 0.02, 3)
            a, b = fast.update_sdk(pos, eul), dense.update_sdk(pos, eul)
        else:
            continue
        assert a is b
        outcomes.add(a)
        assert fast.xi == dense.xi
        _close(fast.x, dense.x)
        _close(fast.P, dense.P)
    assert UpdateOutcome.ACCEPTED in outcomes
    assert fast.counters == dense.counters


def _aruco_model_numpy(x: np.ndarray, T_bc: Transform, T_wm: Transform) -> tuple[np.ndarray, np.ndarray]:
    """The one-pass h_ArUco + Jacobian with its 3x3 products as numpy matmuls (the form before the
    products were written out on floats)."""
    roll, pitch, yaw = (float(v) for v in x[3:6])
    cp, sp, cy, sy = math.cos(pitch), math.sin(pitch), math.cos(yaw), math.sin(yaw)
    C = T_bc.R.T @ euler_to_rotmat(roll, pitch, yaw).T
    q = C @ (T_wm.t - x[0:3])
    M = C @ T_wm.R
    B = C @ np.array([[cy * cp, -sy, 0.0], [sy * cp, cy, 0.0], [-sp, 0.0, 1.0]])
    hx = np.r_[q - T_bc.R.T @ T_bc.t, math.atan2(M[2, 1], M[2, 2]), -math.asin(M[2, 0]), math.atan2(M[1, 0], M[0, 0])]
    H = np.zeros((6, 6))
    H[0:3, 0:3] = -C
    for k in range(3):
        b = B[:, k]
        H[0:3, 3 + k] = np.cross(q, b)
        dM = -np.cross(b[:, None], M, axis=0)  # -[b]x M
        H[3, 3 + k] = (M[2, 2] * dM[2, 1] - M[2, 1] * dM[2, 2]) / (M[2, 1] ** 2 + M[2, 2] ** 2)
        H[4, 3 + k] = -dM[2, 0] / math.sqrt(1.0 - M[2, 0] ** 2)
        H[5, 3 + k] = (M[0, 0] * dM[1, 0] - M[1, 0] * dM[0, 0]) / (M[1, 0] ** 2 + M[0, 0] ** 2)
    return hx, H


def test_aruco_model_on_floats_equals_the_numpy_products_to_1e_12() -> None:
    """The written-out 3x3 products (summed in numpy's order; bit for bit where numpy's matmul
    runs without FMA, as in the golden digests' pinned arithmetic) against the matmul form."""
    rng = np.random.default_rng(7)
    for _ in range(300):
        x = _random_state(rng)
        T_bc, T_wm = _transform(rng, 0.1), _transform(rng, 2.0)
        hx, H = aruco_model(x, T_bc, T_wm)
        hx_ref, H_ref = _aruco_model_numpy(x, T_bc, T_wm)
        np.testing.assert_allclose(hx, hx_ref, rtol=1e-12, atol=1e-12 * float(np.max(np.abs(hx_ref))))
        np.testing.assert_allclose(H, H_ref, rtol=1e-12, atol=1e-12 * float(np.max(np.abs(H_ref))))


def test_covariance_step_keeps_p_exactly_symmetric_and_sums_g_q_g_t_by_hand() -> None:
    """Eq 6 as predict runs it: a symmetric P gives an exactly symmetric result (the changed rows
    mirrored into the columns, the 3x3 block and G_r Q_w G_r^T summed once), equal to the dense
    F P F^T + G Q_u G^T + Q_f; and the attitude noise block against hand-computed values."""
    rng = np.random.default_rng(8)
    for _ in range(200):
        x, P = _random_state(rng), _random_cov(rng)
        P = (P + P.T) * 0.5
        u, dt = rng.normal(0.0, 1.0, 6), float(rng.uniform(0.001, 0.05))
        qu, qf = rng.uniform(0.01, 0.5, 6), rng.uniform(1e-6, 1e-2, 12) * dt
        F, G = propagation_jacobians(x, u, dt)
        out = propagate_covariance(P, *propagation_blocks(x, u, dt)[1:], qu, qf)
        np.testing.assert_array_equal(out, out.T)
        _close(out, F @ P @ F.T + G @ np.diag(qu) @ G.T + np.diag(qf))
    # with P = 0 and F's blocks irrelevant, the attitude block is G_r Q_w G_r^T + Q_f,r: for
    # roll = pitch = 0, J_r = I, so it is dt^2 diag(q_w) + Q_f,r
    dt, qu, qf = 0.01, np.array([1.0, 2.0, 3.0, 0.5, 0.25, 0.125]), np.full(12, 1e-3)
    _, F3, G6 = propagation_blocks(np.zeros(12), np.zeros(6), dt)
    out = propagate_covariance(np.zeros((12, 12)), F3, G6, qu, qf)
    np.testing.assert_allclose(np.diag(out)[0:6], dt * dt * qu + 1e-3, rtol=1e-15)
    np.testing.assert_array_equal(out - np.diag(np.diag(out)), 0.0)
    # pitch = 0.3, roll = 0.2: J_r rows [1, sr tp, cr tp], [0, cr, -sr], [0, sr/cp, cr/cp]
    r, p = 0.2, 0.3
    Jr = np.array([[1.0, math.sin(r) * math.tan(p), math.cos(r) * math.tan(p)],
                   [0.0, math.cos(r), -math.sin(r)],
                   [0.0, math.sin(r) / math.cos(p), math.cos(r) / math.cos(p)]])  # fmt: skip
    x = np.zeros(12)
    x[3:5] = r, p
    _, F3, G6 = propagation_blocks(x, np.zeros(6), dt)
    out = propagate_covariance(np.zeros((12, 12)), F3, G6, qu, np.zeros(12))
    want = dt * dt * np.einsum("ik,k,jk->ij", Jr, qu[3:6], Jr)
    np.testing.assert_allclose(out[3:6, 3:6], want, rtol=1e-14, atol=1e-20)


def test_predict_on_floats_is_bit_for_bit_the_block_functions() -> None:
    """DeliveryEkf.predict (state kept as floats through sub-steps and the wrap, eq 6's diagonal
    cached per step length) against propagation_blocks + propagate_covariance + the wrap, one step
    and sub-stepped; P stays exactly symmetric, so nothing is re-symmetrised."""
    rng = np.random.default_rng(9)
    cfg = EkfConfig()
    for dt in (0.005, 0.12):
        for _ in range(50):
            x0, P0 = _random_state(rng), _random_cov(rng)
            x0[5] = 3.14159  # near the wrap
            u = rng.normal(0.0, 1.0, 6)
            ekf = DeliveryEkf(cfg, x0=x0, P0=P0)
            assert ekf.predict(u, dt)
            n = max(1, math.ceil(dt / cfg.max_step_s - 1e-9))
            h = dt / n
            x, P = x0.copy(), (P0 + P0.T) * 0.5
            for _ in range(n):
                x, F3, G6 = propagation_blocks(x, u, h)
                P = propagate_covariance(P, F3, G6, ekf.input_noise_variances, ekf.process_noise_density * h)
            x[3] = (x[3] + math.pi) % (2 * math.pi) - math.pi
            x[5] = (x[5] + math.pi) % (2 * math.pi) - math.pi
            np.testing.assert_array_equal(ekf.x, x)
            np.testing.assert_array_equal(ekf.P, P)
            np.testing.assert_array_equal(ekf.P, ekf.P.T)


@pytest.mark.parametrize("seed", range(3))
def test_joseph_covariance_equals_the_dense_joseph_form_for_any_gain(seed: int) -> None:
    """P + N + N^T, N = (K S / 2 - P H^T) K^T, against (I - KH) P (I - KH)^T + K R K^T with the
    full 12-column H: for the optimal gain and for gains far from it (the Joseph form holds for
    any K), with S as computed (not re-symmetrised); exactly symmetric for a symmetric P."""
    rng = np.random.default_rng(300 + seed)
    for _ in range(50):
        P = _random_cov(rng)
        P = (P + P.T) * 0.5
        H = np.zeros((6, 12))
        H[:, 0:6] = rng.normal(0.0, 1.0, (6, 6))
        R = np.diag(rng.uniform(1e-4, 0.1, 6))
        PHt = P[:, 0:6] @ H[:, 0:6].T
        S = H[:, 0:6] @ PHt[0:6] + R
        K_opt = PHt @ np.linalg.inv(S)
        for K in (K_opt, K_opt * (1.0 + rng.normal(0.0, 0.3, K_opt.shape)), rng.normal(0.0, 1.0, (12, 6))):
            IKH = np.eye(12) - K @ H
            dense = IKH @ P @ IKH.T + K @ R @ K.T
            got = joseph_covariance(P, K, PHt, S)
            np.testing.assert_array_equal(got, got.T)
            _close(got, dense)


def test_every_step_keeps_p_exactly_symmetric() -> None:
    """The filter never re-symmetrises P: predict (sub-stepped too), the three updates, the xi
    switch, gate resets and an asymmetric P0 (symmetrised on construction) leave P == P^T."""
    rng = np.random.default_rng(11)
    T_bc = _transform(rng, 0.1)
    x0 = _random_state(rng)
    x0[0:3] = [0.3, -0.2, -6.0]
    P0 = _random_cov(rng) * 0.01
    P0[0, 1] += 1e-6  # asymmetric on purpose
    ekf = DeliveryEkf(EkfConfig(gate_reset_after_rejections=3), T_body_camera=T_bc, x0=x0, P0=P0)
    np.testing.assert_array_equal(ekf.P, ekf.P.T)
    T_wm = Transform(euler_to_rotmat(math.pi, 0.0, 0.4), np.array([0.2, 0.1, 0.0]))
    accepted: set[EkfSensor] = set()
    for i in range(400):
        assert ekf.predict(rng.normal(0.0, 0.3, 6), 0.12 if i % 40 == 0 else 0.005)
        np.testing.assert_array_equal(ekf.P, ekf.P.T)
        truth = ekf.x + rng.normal(0.0, 0.02, 12)
        if i % 5 == 1:
            T_cm = (T_bc.inverse() @ Transform.from_euler(truth[0:3], *truth[3:6]).inverse()) @ T_wm
            outcome, sensor = ekf.update_aruco(T_cm, T_wm), EkfSensor.ARUCO
        elif i % 5 == 2:
            outcome, sensor = ekf.update_uwb(_Fix(truth[0:3], 1.5), Transform.identity()), EkfSensor.UWB
        elif i % 5 == 3:
            far = 50.0 if 100 <= i < 200 else 0.0  # a GPS jump: gate rejections, then resets
            outcome = ekf.update_sdk(truth[0:3] + truth[6:9] * ekf.xi + far, truth[3:6])
            sensor = EkfSensor.SDK
        else:
            continue
        if outcome is UpdateOutcome.ACCEPTED:
            accepted.add(sensor)
        np.testing.assert_array_equal(ekf.P, ekf.P.T)
    assert accepted == set(EkfSensor) and ekf.xi
    assert ekf.counters["sdk.gate_resets"] > 0


def test_condition_repairs_small_variances_as_the_array_test_did() -> None:
    """The float screen in _condition: a small variance is repaired and counted; NaN on the
    diagonal is not 'small' (compares False, as before) but does not hide a small one elsewhere."""
    ekf = DeliveryEkf(EkfConfig(), x0=np.zeros(12))
    P = np.eye(12)
    P[4, 4] = 1e-20
    P[0, 0] = math.nan
    ekf.P = P.copy()
    ekf._condition()
    assert ekf.counters["covariance.repairs"] == 1
    assert ekf.P[4, 4] == ekf.config.min_variance and math.isnan(ekf.P[0, 0])
    ekf.P = np.eye(12)
    ekf.P[0, 0] = math.nan
    ekf._condition()
    assert ekf.counters["covariance.repairs"] == 1  # NaN alone: nothing to repair

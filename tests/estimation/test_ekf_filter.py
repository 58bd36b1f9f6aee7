"""The 12-state EKF (delivery 4.2.3) on synthetic flights: bias convergence, robustness."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

from companion.estimation.ekf import DeliveryEkf, EkfConfig, UpdateOutcome
from companion.estimation.types import StateEstimate
from companion.geometry import Transform, euler_to_rotmat
from companion.uwb.anchors import anchor_frame_to_ned, load_anchor_layout
from companion.uwb.measurements import UwbFix
from companion.uwb.multilateration import Multilaterator
from companion_sitl.uwb import SimulatedUwb, UwbSimConfig

sys.path.insert(0, str(Path(__file__).parent))
from ekf_sim import GPS_BIAS, GYRO_BIAS, aruco_truth, truth

LAYOUT = load_anchor_layout()
T_WORLD_ANCHOR = anchor_frame_to_ned([0.0, 0.0, 0.0], heading_rad=math.pi / 2)  # pad frame = ENU
T_ANCHOR_WORLD = T_WORLD_ANCHOR.inverse()
CAMERA_DOWN = Transform(euler_to_rotmat(0.0, 0.0, math.pi / 2), np.array([0.1, 0.0, 0.05]))
MARKER = Transform(euler_to_rotmat(math.pi, 0.0, 0.0), np.zeros(3))  # flat on the pad, x north


def _assert_spd(P: np.ndarray) -> None:
    assert np.array_equal(P, P.T)
    np.linalg.cholesky(P)  # raises unless positive definite


def test_gps_bias_converges_with_gps_plus_uwb() -> None:
    rng = np.random.default_rng(1)
    sim = SimulatedUwb(LAYOUT, UwbSimConfig(range_sigma_m=0.05, nlos_probability=0.03), seed=2)
    mlat = Multilaterator(LAYOUT)
    ekf = DeliveryEkf(EkfConfig(sdk_position_sigma_m=0.5))
    dt = 0.01
    xi_at = None
    steps = 5000
    for k in range(1, steps + 1):
        t = k * dt
        tr = truth(t)
        gyro = tr.rates_body + GYRO_BIAS + rng.normal(0, 0.005, 3)
        ekf.predict(np.concatenate([tr.v + rng.normal(0, 0.1, 3), gyro]), dt)
        if k % 10 == 0:  # SDK pose at 10 Hz: biased GPS (delivery 4.2.3)
            ekf.update_sdk(tr.p + GPS_BIAS + rng.normal(0, 0.3, 3), tr.euler + rng.normal(0, 0.01, 3))
        if k % 10 == 5:  # UWB at 10 Hz, unbiased, in the pad/anchor frame
            prior = T_ANCHOR_WORLD.apply(ekf.x[0:3])
            fix = mlat.solve_twr(sim.twr(t, T_ANCHOR_WORLD.apply(tr.p)), prior_m=prior)
            if isinstance(fix, UwbFix):
                ekf.update_uwb(fix, T_WORLD_ANCHOR)
        if xi_at is None and ekf.xi:
            xi_at = t
        if t < 10.0:  # hovering 20 m up: out of UWB range, GPS only, bias not yet included
            assert not ekf.xi
            np.testing.assert_array_equal(ekf.x[6:9], 0.0)
        _assert_spd(ekf.P)
    assert xi_at is not None and xi_at > 10.0
    tr = truth(steps * dt)
    np.testing.assert_allclose(ekf.x[6:9], GPS_BIAS, atol=0.15)
    np.testing.assert_allclose(ekf.x[0:3], tr.p, atol=0.15)
    np.testing.assert_allclose(ekf.x[9:12], GYRO_BIAS, atol=0.006)
    assert ekf.counters["uwb.accepted"] > 120
    est = ekf.estimate(steps * dt)
    assert isinstance(est, StateEstimate) and est.source == "ekf"
    assert (est.gps_bias_north_m, est.gps_bias_east_m, est.gps_bias_down_m) == tuple(ekf.x[6:9])
    assert est.position_ned == tuple(ekf.x[0:3])


def test_long_noisy_run_with_nan_and_outliers_never_diverges() -> None:
    rng = np.random.default_rng(3)
    ekf = DeliveryEkf(T_body_camera=CAMERA_DOWN)
    dt = 0.01
    injected = {"input": 0, "sdk_nan": 0, "sdk_out": 0, "uwb_out": 0, "aruco_nan": 0, "aruco_out": 0}
    errors = []
    for k in range(1, 6001):
        t = 10.0 + k * dt  # the descent part of the flight
        tr = truth(t)
        u = np.concatenate([tr.v + rng.normal(0, 0.2, 3), tr.rates_body + GYRO_BIAS + rng.normal(0, 0.01, 3)])
        if rng.random() < 0.01:
            u[rng.integers(6)] = rng.choice([math.nan, math.inf, -math.inf])
            injected["input"] += 1
        ekf.predict(u, dt)
        if k % 10 == 0:
            pos = tr.p + GPS_BIAS + rng.normal(0, 0.8, 3)
            eul = tr.euler + rng.normal(0, 0.02, 3)
            roll = rng.random()
            if roll < 0.03:
                pos[rng.integers(3)] = math.nan
                injected["sdk_nan"] += 1
            elif roll < 0.06:
                pos = pos + rng.choice([-1, 1]) * 40.0
                injected["sdk_out"] += 1
            ekf.update_sdk(pos, eul)
        if k % 10 == 3:
            p = tr.p + rng.normal(0, 0.1, 3)
            if rng.random() < 0.05:
                p = p + rng.normal(0, 1, 3) / 0.2 * 3.0  # a wild fix (15 m scale)
                injected["uwb_out"] += 1
            ekf.update_uwb(
                UwbFix(t, *T_ANCHOR_WORLD.apply(p), pdop=1.5, residual_rms_m=0.05, anchors_used=(), frame="pad"),
                T_WORLD_ANCHOR,
            )
        if k % 4 == 1:
            T = aruco_truth(tr, CAMERA_DOWN, MARKER)
            r, pch, y = T.euler()
            h = -tr.p[2]
            meas = Transform.from_euler(
                T.t + rng.normal(0, 0.02 + 0.01 * h, 3),
                r + rng.normal(0, 0.2),
                pch + rng.normal(0, 0.2),
                y + rng.normal(0, 0.03),
            )
            roll = rng.random()
            if roll < 0.02:
                meas = Transform(meas.R, np.array([math.nan, 0.0, 1.0]))
                injected["aruco_nan"] += 1
            elif roll < 0.04:
                meas = Transform(meas.R, meas.t + np.array([5.0, -5.0, 0.0]))
                injected["aruco_out"] += 1
            ekf.update_aruco(meas, MARKER)
        _assert_spd(ekf.P)
        assert np.all(np.isfinite(ekf.x))
        assert -math.pi <= ekf.x[5] < math.pi
        errors.append(np.linalg.norm(ekf.x[0:3] - tr.p))
    c = ekf.counters
    assert c["input.nonfinite"] == injected["input"]
    assert c["sdk.rejected_nonfinite"] == injected["sdk_nan"]
    assert c["aruco.rejected_nonfinite"] == injected["aruco_nan"]
    assert c["sdk.rejected_gate"] >= injected["sdk_out"]
    assert c["uwb.rejected_gate"] >= 0.8 * injected["uwb_out"]
    assert c["aruco.rejected_gate"] >= 0.8 * injected["aruco_out"]
    assert c["aruco.accepted"] > 1000 and c["uwb.accepted"] > 450
    assert max(errors[-3000:]) < 0.5
    assert float(np.sqrt(np.mean(np.square(errors[-3000:])))) < 0.12
    np.testing.assert_allclose(ekf.x[6:9], GPS_BIAS, atol=0.4)


def _converged_gps_only() -> DeliveryEkf:
    ekf = DeliveryEkf()
    rng = np.random.default_rng(5)
    for _ in range(300):
        ekf.predict(np.zeros(6), 0.01)
        ekf.update_sdk(np.array([10.0, 5.0, -8.0]) + rng.normal(0, 0.3, 3), rng.normal(0, 0.01, 3))
    return ekf


def _fix(p_world: np.ndarray, pdop: float = 1.0) -> UwbFix:
    return UwbFix(0.0, *T_ANCHOR_WORLD.apply(p_world), pdop=pdop, residual_rms_m=0.0, anchors_used=(), frame="pad")


def test_xi_switch_keeps_the_gps_expectation_and_admits_an_offset_pad() -> None:
    ekf = _converged_gps_only()
    assert not ekf.xi and np.all(ekf.x[6:9] == 0.0)
    gps_pos = ekf.x[0:3].copy()
    assert ekf.P[0, 0] < 0.1  # confident about the GPS position...
    # ...but the pad is 4 m away from where GPS says: without the xi transform this is gated out
    truth_p = gps_pos - np.array([3.0, -2.0, 1.5])
    assert ekf.update_uwb(_fix(truth_p), T_WORLD_ANCHOR) is UpdateOutcome.ACCEPTED
    assert ekf.xi
    for _ in range(20):
        ekf.predict(np.zeros(6), 0.05)
        assert ekf.update_uwb(_fix(truth_p), T_WORLD_ANCHOR) is UpdateOutcome.ACCEPTED
        assert ekf.update_sdk(gps_pos, np.zeros(3)) is UpdateOutcome.ACCEPTED
    np.testing.assert_allclose(ekf.x[0:3], truth_p, atol=0.05)
    np.testing.assert_allclose(ekf.x[0:3] + ekf.x[6:9], gps_pos, atol=0.1)  # eq 12 with xi = 1


def test_gate_rejects_a_gps_jump_and_counts_it() -> None:
    ekf = _converged_gps_only()
    x_before = ekf.x.copy()
    assert ekf.update_sdk(ekf.x[0:3] + np.array([50.0, 0, 0]), np.zeros(3)) is UpdateOutcome.REJECTED_GATE
    np.testing.assert_array_equal(ekf.x, x_before)
    assert ekf.counters["sdk.rejected_gate"] == 1
    loose = DeliveryEkf(EkfConfig(gating_enabled=False))
    loose.x, loose.P = ekf.x.copy(), ekf.P.copy()
    assert loose.update_sdk(ekf.x[0:3] + np.array([50.0, 0, 0]), np.zeros(3)) is UpdateOutcome.ACCEPTED


def test_nonfinite_measurements_and_inputs_are_counted() -> None:
    ekf = DeliveryEkf()
    x0 = ekf.x.copy()
    assert ekf.update_sdk([math.nan, 0, 0], [0, 0, 0]) is UpdateOutcome.REJECTED_NONFINITE
    assert ekf.update_sdk([0, 0, 0], [0, math.inf, 0]) is UpdateOutcome.REJECTED_NONFINITE
    assert ekf.update_uwb(_fix(np.array([math.nan, 0.0, 0.0])), T_WORLD_ANCHOR) is UpdateOutcome.REJECTED_NONFINITE
    bad = Transform(np.eye(3), np.array([0.0, math.inf, 1.0]))
    assert ekf.update_aruco(bad, MARKER) is UpdateOutcome.REJECTED_NONFINITE
    np.testing.assert_array_equal(ekf.x, x0)
    ekf.predict([1.0, 0, 0, 0, 0, 0], 0.1)
    ekf.predict([math.nan, 0, 0, 0, 0, 0], 0.1)  # holds the last finite input
    np.testing.assert_allclose(ekf.x[0], 0.2)
    assert not ekf.predict([0] * 6, math.nan) and not ekf.predict([0] * 6, -0.1)
    c = ekf.counters
    assert (c["sdk.rejected_nonfinite"], c["uwb.rejected_nonfinite"], c["aruco.rejected_nonfinite"]) == (2, 1, 1)
    assert c["input.nonfinite"] == 1 and c["predict.bad_dt"] == 2


def test_aruco_height_gate_and_camera_model() -> None:
    ekf = DeliveryEkf(T_body_camera=CAMERA_DOWN, x0=np.r_[0.3, -0.2, -35.0, np.zeros(9)])
    T = aruco_truth(truth(0.0), CAMERA_DOWN, MARKER)
    assert ekf.update_aruco(T, MARKER) is UpdateOutcome.REJECTED_HEIGHT  # delivery 5.1: > 30 m
    assert ekf.counters["aruco.rejected_height"] == 1
    # below 30 m perfect marker observations pull the filter onto the truth
    x_true = np.r_[0.3, -0.2, -6.0, 0.02, -0.01, 0.4, np.zeros(6)]
    ekf = DeliveryEkf(T_body_camera=CAMERA_DOWN, x0=x_true + np.r_[0.5, -0.4, 0.3, 0.0, 0.0, 0.05, np.zeros(6)])
    T_wb = Transform.from_euler(x_true[0:3], *x_true[3:6])
    meas = CAMERA_DOWN.inverse() @ T_wb.inverse() @ MARKER
    for _ in range(30):
        assert ekf.update_aruco(meas, MARKER) is UpdateOutcome.ACCEPTED
        # roll/pitch from the marker are poor (eq 14's R): the autopilot attitude pins them
        assert ekf.update_sdk(x_true[0:3], x_true[3:6]) is UpdateOutcome.ACCEPTED
    np.testing.assert_allclose(ekf.x[0:3], x_true[0:3], atol=0.01)
    assert abs(ekf.x[5] - x_true[5]) < 0.01
    assert ekf.xi


def test_measurement_noise_grows_with_height() -> None:
    cfg = EkfConfig(uwb_position_sigma_gain_m_per_m=0.05)
    moved = []
    for down in (-1.0, -8.0):
        ekf = DeliveryEkf(cfg, x0=np.r_[0.0, 0.0, down, np.zeros(9)])
        ekf.xi = True
        ekf.update_uwb(_fix(np.array([0.5, 0.0, down])), T_WORLD_ANCHOR)
        moved.append(ekf.x[0])
    assert 0.0 < moved[1] < moved[0]  # higher up: noisier UWB, smaller correction
    sdk = []
    for gain in (0.0, 0.2):
        ekf = DeliveryEkf(EkfConfig(sdk_position_sigma_gain_m_per_m=gain), x0=np.r_[0.0, 0.0, -20.0, np.zeros(9)])
        ekf.update_sdk([1.0, 0.0, -20.0])
        sdk.append(ekf.x[0])
    assert sdk[1] < sdk[0]


def test_config_validation() -> None:
    with pytest.raises(ValueError, match="sdk_position_sigma_m"):
        EkfConfig(sdk_position_sigma_m=0.0)
    with pytest.raises(ValueError, match="uwb_position_sigma_gain_m_per_m"):
        EkfConfig(uwb_position_sigma_gain_m_per_m=-1.0)
    with pytest.raises(ValueError, match="gate_probability"):
        EkfConfig(gate_probability=1.0)
    with pytest.raises(ValueError, match="finite"):
        EkfConfig(input_rate_sigma_rad_s=math.nan)


def test_long_prediction_is_split_and_stays_spd() -> None:
    ekf = DeliveryEkf()
    ekf.predict([0, 0, 0, 0.0, 0.0, 1.0], 2.0)  # 2 s gap, yaw rate 1 rad/s
    assert ekf.x[5] == pytest.approx(2.0, abs=1e-9)
    _assert_spd(ekf.P)
    ekf.predict([0, 0, 0, 0.0, 0.0, 1.0], 2.0)
    assert ekf.x[5] == pytest.approx(4.0 - 2 * math.pi, abs=1e-9)  # wrapped to [-pi, pi)


def test_first_sdk_pose_initialises_and_local_data_waits_for_it() -> None:
    ekf = DeliveryEkf()
    assert ekf.update_uwb(_fix(np.array([1.0, 2.0, -3.0])), T_WORLD_ANCHOR) is UpdateOutcome.REJECTED_UNINITIALIZED
    assert ekf.counters["uwb.rejected_uninitialized"] == 1
    assert ekf.update_sdk([100.0, -50.0, -30.0], [0.1, -0.1, 3.0]) is UpdateOutcome.ACCEPTED
    np.testing.assert_allclose(ekf.x[0:6], [100.0, -50.0, -30.0, 0.1, -0.1, 3.0])
    assert ekf.P[0, 0] == pytest.approx(EkfConfig().sdk_position_sigma_m ** 2)
    assert not ekf.xi
    _assert_spd(ekf.P)


def test_gate_lockout_recovers_after_consecutive_rejections() -> None:
    ekf = _converged_gps_only()
    gps = ekf.x[0:3].copy()
    assert ekf.update_uwb(_fix(gps + 0.1), T_WORLD_ANCHOR) is UpdateOutcome.ACCEPTED
    for _ in range(30):
        ekf.update_uwb(_fix(gps + 0.1), T_WORLD_ANCHOR)
        ekf.update_sdk(gps, np.zeros(3))
    # the pad is moved 6 m (or the fixes jump for good): rejected at first, then re-acquired
    moved = gps + np.array([6.0, 0.0, 0.0])
    outcomes = [ekf.update_uwb(_fix(moved), T_WORLD_ANCHOR) for _ in range(25)]
    n = EkfConfig().gate_reset_after_rejections
    assert outcomes[:n] == [UpdateOutcome.REJECTED_GATE] * n
    assert outcomes[n] is UpdateOutcome.ACCEPTED
    assert ekf.counters["uwb.gate_resets"] == 1
    np.testing.assert_allclose(ekf.x[0:3], moved, atol=0.1)
    _assert_spd(ekf.P)


def test_chi2_gate_quantile_is_scipys_chi2_ppf_to_the_bit():
    from scipy.stats import chi2

    from companion.estimation.ekf import chi2_ppf

    for p in (0.5, 0.9, 0.95, 0.99, 0.997, 0.9999):
        for dof in (1, 2, 3, 6, 9):
            assert chi2_ppf(p, dof) == float(chi2.ppf(p, dof)), (p, dof)
    assert chi2_ppf(0.95, 3) == pytest.approx(7.8147, abs=1e-4)  # the textbook table value

"""Delayed measurements: applied at capture time, re-predicted to now, same as on time."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np

from companion.estimation.delayed import DelayedMeasurementBuffer
from companion.estimation.ekf import DeliveryEkf, EkfSensor, UpdateOutcome
from companion.geometry import Transform, euler_to_rotmat
from companion.uwb.anchors import anchor_frame_to_ned
from companion.uwb.measurements import UwbFix

sys.path.insert(0, str(Path(__file__).parent))
from ekf_sim import GPS_BIAS, GYRO_BIAS, aruco_truth, truth

CAMERA_DOWN = Transform(euler_to_rotmat(0.0, 0.0, math.pi / 2), np.array([0.1, 0.0, 0.05]))
MARKER = Transform(euler_to_rotmat(math.pi, 0.0, 0.2), np.array([0.1, -0.1, 0.0]))
T_WA = anchor_frame_to_ned([0.0, 0.0, 0.0], heading_rad=math.pi / 2)

T0 = 30.0  # mid-descent, ~10 m up
DT = 0.01


def _inputs(n: int, seed: int = 0) -> list[tuple[float, np.ndarray, int]]:
    rng = np.random.default_rng(seed)
    out = []
    for k in range(1, n + 1):
        t = T0 + k * DT
        tr = truth(t)
        u = np.concatenate([tr.v + rng.normal(0, 0.1, 3), tr.rates_body + GYRO_BIAS + rng.normal(0, 0.005, 3)])
        out.append((t, u, k))
    return out


def _sdk(k: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed * 100000 + k)
    tr = truth(T0 + k * DT)
    return tr.p + GPS_BIAS + rng.normal(0, 0.3, 3), tr.euler + rng.normal(0, 0.01, 3)


def _aruco(t: float) -> Transform:
    T = aruco_truth(truth(t), CAMERA_DOWN, MARKER)
    angles = np.array(T.euler()) + np.array([0.05, -0.04, 0.01])
    return Transform.from_euler(T.t + np.array([0.03, -0.02, 0.05]), *angles)


def _new() -> DelayedMeasurementBuffer:
    tr = truth(T0)
    x0 = np.r_[tr.p + GPS_BIAS, tr.euler, np.zeros(6)]
    return DelayedMeasurementBuffer(DeliveryEkf(T_body_camera=CAMERA_DOWN, x0=x0), start_time_s=T0, history_s=0.5)


def _run(delay_aruco_s: float, delay_uwb_s: float) -> DelayedMeasurementBuffer:
    """200 inputs at 100 Hz, SDK at 20 Hz; an ArUco pose captured at t_a (between two inputs)
    and a UWB fix captured at t_u, each delivered ``delay`` later (0: on time)."""
    buf = _new()
    t_a = T0 + 0.8234  # camera exposure time
    t_u = T0 + 0.9117
    fix = UwbFix(
        t_u, *T_WA.inverse().apply(truth(t_u).p + 0.04), pdop=1.4, residual_rms_m=0.03, anchors_used=(), frame="pad"
    )
    pending = [(t_a + delay_aruco_s, EkfSensor.ARUCO), (t_u + delay_uwb_s, EkfSensor.UWB)]
    for t, u, k in _inputs(200):
        for due, kind in list(pending):
            if due <= t:  # deliver before the input event at t (on time: at capture time)
                aruco = kind is EkfSensor.ARUCO
                out = buf.update_aruco(t_a, _aruco(t_a), MARKER) if aruco else buf.update_uwb(fix, T_WA)
                assert out is UpdateOutcome.ACCEPTED
                pending.remove((due, kind))
        buf.predict(t, u)
        if k % 5 == 0:
            pos, eul = _sdk(k)
            buf.update_sdk(t, pos, eul)
    assert not pending
    return buf


def test_delayed_measurements_equal_on_time() -> None:
    on_time = _run(0.0, 0.0)
    late = _run(0.087, 0.143)  # camera latency 87 ms, UWB 143 ms; SDK samples arrive between
    assert late.counters.delayed_applied == 2 and late.counters.replayed_events > 20
    assert on_time.counters.delayed_applied == 0
    assert late.now_s == on_time.now_s
    np.testing.assert_allclose(late.ekf.x, on_time.ekf.x, rtol=0, atol=1e-9)
    np.testing.assert_allclose(late.ekf.P, on_time.ekf.P, rtol=0, atol=1e-9)
    assert late.ekf.xi and on_time.ekf.xi
    assert late.ekf.counters == on_time.ekf.counters
    assert late.estimate() == on_time.estimate()
    # and the late measurement did change the estimate (it was not silently dropped)
    ignored = _new()
    for t, u, k in _inputs(200):
        ignored.predict(t, u)
        if k % 5 == 0:
            ignored.update_sdk(t, *_sdk(k))
    assert np.linalg.norm(ignored.ekf.x[0:3] - late.ekf.x[0:3]) > 1e-3


def test_too_old_measurements_are_refused_and_counted() -> None:
    buf = _new()
    for t, u, _ in _inputs(100):
        buf.predict(t, u)
    x_before = buf.ekf.x.copy()
    out = buf.update_aruco(buf.now_s - 0.6, _aruco(buf.now_s - 0.6), MARKER)  # history is 0.5 s
    assert out is UpdateOutcome.REJECTED_TOO_OLD
    assert buf.counters.too_old == 1 and buf.counters.extra["aruco.rejected_too_old"] == 1
    np.testing.assert_array_equal(buf.ekf.x, x_before)
    assert buf.update_sdk(math.nan, [0, 0, 0]) is UpdateOutcome.REJECTED_TOO_OLD
    # a late one inside the history is applied
    assert buf.update_aruco(buf.now_s - 0.3, _aruco(buf.now_s - 0.3), MARKER) is UpdateOutcome.ACCEPTED


def test_input_handling() -> None:
    buf = _new()
    buf.predict(T0 + 0.01, [1.0, 0, 0, 0, 0, 0])
    buf.predict(T0 + 0.02, [math.nan, 0, 0, 0, 0, 0])  # keeps holding the last finite input
    buf.predict(T0 + 0.03, [0, 0, 0, 0, 0, 0])
    buf.predict(T0 + 0.025, [5.0, 0, 0, 0, 0, 0])  # out of order: ignored
    assert buf.counters.input_nonfinite == 1 and buf.counters.input_out_of_order == 1
    x0 = truth(T0).p[0] + GPS_BIAS[0]
    np.testing.assert_allclose(buf.ekf.x[0], x0 + 0.02, atol=1e-12)  # 1 m/s held for 20 ms
    assert buf.estimate().time_s == T0 + 0.03

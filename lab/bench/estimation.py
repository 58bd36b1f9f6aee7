"""Micro-benchmark of the 12-state EKF (for ``companion bench ekf``)."""

from __future__ import annotations

import math
import time

import numpy as np

from companion.estimation.delayed import DelayedMeasurementBuffer
from companion.estimation.ekf import DeliveryEkf, EkfConfig
from companion.estimation.ekf_reference import DenseDeliveryEkf
from companion.geometry import Transform, euler_to_rotmat


class _Fix:
    """A minimal UWB fix (the EKF takes anything with these fields)."""

    def __init__(self, t: float, p: np.ndarray) -> None:
        self.time_s, self.x_m, self.y_m, self.z_m, self.pdop = t, float(p[0]), float(p[1]), float(p[2]), 1.5


def _per_call_us(fn, n: int) -> float:  # type: ignore[no-untyped-def]
    for i in range(min(n, 100)):  # warm up (caches, CPU clock) before timing
        fn(i)
    t0 = time.perf_counter()
    for i in range(n):
        fn(i)
    return (time.perf_counter() - t0) / n * 1e6


def _per_call_cpu_us(fn, n: int) -> float:  # type: ignore[no-untyped-def]
    """CPU microseconds per call of this thread: on a loaded core the wall figure also counts the
    time other processes had the core; this one is the EKF's own work there."""
    for i in range(min(n, 100)):
        fn(i)
    t0 = time.thread_time()
    for i in range(n):
        fn(i)
    return (time.thread_time() - t0) / n * 1e6


def bench_ekf(n: int = 2000) -> dict[str, float]:
    """Microseconds per EKF step: predict, each sensor update, and a delayed (replayed) update.

    Gating is disabled so every update runs the full correction. ``n`` calls of each. The
    ``dense_*`` figures time the same predict and ArUco update in their straightforward dense
    form (:class:`~companion.estimation.ekf_reference.DenseDeliveryEkf`) in the same run, and
    ``speedup_predict_plus_aruco`` is their ratio (target: predict + ArUco <= 50 us).
    """
    if n < 1:
        raise ValueError("n must be >= 1")
    T_bc = Transform(euler_to_rotmat(0.0, 0.0, math.pi / 2), np.array([0.1, 0.0, 0.05]))
    T_wm = Transform(euler_to_rotmat(math.pi, 0.0, 0.0), np.zeros(3))
    x0 = np.r_[0.2, -0.1, -5.0, 0.02, -0.01, 0.3, np.zeros(6)]
    ekf = DeliveryEkf(EkfConfig(gating_enabled=False), T_body_camera=T_bc, x0=x0)
    u = np.array([0.1, -0.2, 0.3, 0.01, -0.02, 0.05])
    rng = np.random.default_rng(0)
    noise = rng.normal(0, 0.01, (n, 3))
    T_cm = T_bc.inverse() @ Transform.from_euler(x0[0:3], *x0[3:6]).inverse() @ T_wm
    T_wa = Transform.identity()
    out: dict[str, float] = {}
    out["predict_us"] = _per_call_us(lambda i: ekf.predict(u, 0.005), n)
    out["update_sdk_us"] = _per_call_us(lambda i: ekf.update_sdk(x0[0:3] + noise[i], x0[3:6]), n)
    out["update_sdk_position_us"] = _per_call_us(lambda i: ekf.update_sdk(x0[0:3] + noise[i]), n)
    out["update_aruco_us"] = _per_call_us(lambda i: ekf.update_aruco(Transform(T_cm.R, T_cm.t + noise[i]), T_wm), n)
    out["update_uwb_us"] = _per_call_us(lambda i: ekf.update_uwb(_Fix(0.0, x0[0:3] + noise[i]), T_wa), n)
    # a camera frame 50 ms late at a 200 Hz input rate: 10 inputs replayed per update
    buf = DelayedMeasurementBuffer(DeliveryEkf(EkfConfig(gating_enabled=False), T_bc, x0), 0.0, 0.5)
    t = 0.0
    for _ in range(20):
        t += 0.005
        buf.predict(t, u)
    m = max(1, n // 10)

    def delayed(i: int) -> None:
        nonlocal t
        t += 0.005
        buf.predict(t, u)
        buf.update_aruco(t - 0.05, Transform(T_cm.R, T_cm.t + noise[i % n]), T_wm)

    out["delayed_aruco_50ms_us"] = _per_call_us(delayed, m)
    # the same predict + ArUco update in the straightforward dense form, in this run
    dense = DenseDeliveryEkf(EkfConfig(gating_enabled=False), T_body_camera=T_bc, x0=x0)
    out["dense_predict_us"] = _per_call_us(lambda i: dense.predict(u, 0.005), n)
    out["dense_update_aruco_us"] = _per_call_us(
        lambda i: dense.update_aruco(Transform(T_cm.R, T_cm.t + noise[i]), T_wm), n
    )
    out["predict_plus_aruco_us"] = out["predict_us"] + out["update_aruco_us"]
    # the same two in this thread's CPU time (what the EKF costs on a core it shares)
    out["predict_plus_aruco_cpu_us"] = _per_call_cpu_us(lambda i: ekf.predict(u, 0.005), n) + _per_call_cpu_us(
        lambda i: ekf.update_aruco(Transform(T_cm.R, T_cm.t + noise[i]), T_wm), n
    )
    out["dense_predict_plus_aruco_us"] = out["dense_predict_us"] + out["dense_update_aruco_us"]
    out["speedup_predict_plus_aruco"] = out["dense_predict_plus_aruco_us"] / out["predict_plus_aruco_us"]
    return out  # n is the caller's; every value is microseconds per call

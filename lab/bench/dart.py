"""Micro-benchmark of the Dart estimation core: Madgwick update and the four estimators.

``bench_estimation(n)`` feeds ``n`` synthetic, seeded IMU samples and ``n`` marker observations
(a hover 4 m in front of the paper's wall marker) and returns microseconds per call:

- ``madgwick_update_us``: one :meth:`MadgwickFilter.update` (dart eqs 8-13);
- ``complementary_predict_us``: one gyro step of the complementary filter (dart eq 14);
- ``<name>.imu_us``: one ``update_imu`` of estimator <name> (its attitude filter + history);
- ``<name>.vision_us``: one ``update_vision`` (the position step, dart eqs 16-21);
- ``n``: the sample count.
"""

from __future__ import annotations

import logging
import math
import time

import numpy as np

from companion.dart.estimators import (
    ESTIMATORS,
    CameraMarkerObservation,
    DartEstimatorConfig,
    make_estimator,
)
from companion.estimation.complementary import ComplementaryFilter
from companion.estimation.madgwick import MadgwickFilter
from companion.geometry import euler_to_rotmat

logger = logging.getLogger(__name__)

_G = 9.80665


def _synthetic(n: int, seed: int = 0) -> tuple[list[tuple], list[CameraMarkerObservation]]:
    rng = np.random.default_rng(seed)
    cfg = DartEstimatorConfig()
    R_wm = np.array(cfg.R_world_marker)
    R_bc = np.array(cfg.R_body_cam)
    t_bc = np.array(cfg.t_body_cam_m)
    imu = []
    obs = []
    dt = 1.0 / 200.0
    for k in range(n):
        t = k * dt
        roll, pitch, yaw = 0.05 * math.sin(t), 0.04 * math.cos(0.7 * t), 0.1 * math.sin(0.3 * t)
        R_wb = euler_to_rotmat(roll, pitch, yaw)
        f = R_wb.T @ np.array([0.0, 0.0, -_G]) + rng.normal(0.0, 0.05, 3)
        w = rng.normal(0.0, 0.01, 3)
        imu.append((t, (float(w[0]), float(w[1]), float(w[2])), (float(f[0]), float(f[1]), float(f[2]))))
        p_w = np.array([-4.0, 0.1 * math.sin(t), -0.2])
        R_wc = R_wb @ R_bc
        R_cm = R_wc.T @ R_wm
        t_cm = R_wc.T @ (-(p_w + R_wb @ t_bc)) + rng.normal(0.0, 0.005, 3)
        obs.append(CameraMarkerObservation(max(0.0, t - 0.05), R_cm, t_cm))
    return imu, obs


def bench_estimation(n: int = 2000) -> dict[str, float]:
    """Microseconds per Madgwick update and per estimator step (see the module doc)."""
    if n < 10:
        raise ValueError("n must be >= 10")
    imu, obs = _synthetic(n)
    result: dict[str, float] = {"n": float(n)}

    mf = MadgwickFilter()
    upd = mf.update
    t0 = time.perf_counter()
    for t, g, a in imu:
        upd(t, g, a)
    result["madgwick_update_us"] = (time.perf_counter() - t0) / n * 1e6

    cf = ComplementaryFilter()
    cf.reset((0.0, 0.0, 0.0))
    t0 = time.perf_counter()
    for t, g, _ in imu:
        cf.predict(t, g)
    result["complementary_predict_us"] = (time.perf_counter() - t0) / n * 1e6

    for name in ESTIMATORS:
        est = make_estimator(name)
        imu_s = 0.0
        vis_s = 0.0
        for k in range(n):
            t, g, a = imu[k]
            t0 = time.perf_counter()
            est.update_imu(t, g, a)
            t1 = time.perf_counter()
            est.update_vision(obs[k])
            t2 = time.perf_counter()
            imu_s += t1 - t0
            vis_s += t2 - t1
        result[f"{name}.imu_us"] = imu_s / n * 1e6
        result[f"{name}.vision_us"] = vis_s / n * 1e6
        if est.accepted_observations < n // 2:
            logger.warning("bench: %s accepted only %d of %d frames", name, est.accepted_observations, n)
    return result

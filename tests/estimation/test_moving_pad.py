"""The EKF extended to a moving pad (companion.estimation.moving_pad; delivery eq 11 extended by
the pad's velocity): the extended prediction against hand-computed steps, its Jacobians against
central finite differences, and the filter on a pad driving at 2 m/s and turning."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
import pytest

from companion.config import ConfigError, EkfConfig, MovingPadConfig, config_from_dict
from companion.estimation.ekf import DeliveryEkf, propagate
from companion.estimation.moving_pad import N_MOVING, MovingPadEkf, moving_jacobians, propagate_moving
from companion.geometry import Transform

EPS = 1e-6


def _state(seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return np.concatenate(
        [
            rng.uniform(-20, 20, 3),
            [rng.uniform(-0.6, 0.6), rng.uniform(-0.6, 0.6), rng.uniform(-math.pi, math.pi)],
            rng.uniform(-3, 3, 3),
            rng.uniform(-0.05, 0.05, 3),
            rng.uniform(-3, 3, 2),
        ]
    )


def test_the_extended_prediction_is_eq11_plus_the_pads_velocity() -> None:
    x = _state(1)
    u = np.array([1.0, -2.0, 0.3, 0.02, -0.01, 0.05])
    dt = 0.02
    for xi in (0.0, 1.0):
        out = propagate_moving(x, u, dt, xi)
        ref = propagate(x[0:12], u, dt)
        assert out[0] == pytest.approx(ref[0] - xi * x[12] * dt, abs=1e-15)
        assert out[1] == pytest.approx(ref[1] - xi * x[13] * dt, abs=1e-15)
        assert out[2] == ref[2] and np.array_equal(out[3:6], ref[3:6])  # down and attitude: eq 11
        assert out[6] == pytest.approx(x[6] + x[12] * dt, abs=1e-15)  # the bias follows the pad
        assert out[7] == pytest.approx(x[7] + x[13] * dt, abs=1e-15)
        assert out[8] == x[8] and np.array_equal(out[9:14], x[9:14])  # b_p,down, b_w, v constant


@pytest.mark.parametrize("xi", [0.0, 1.0])
@pytest.mark.parametrize("seed", [0, 1, 2])
def test_jacobians_match_finite_differences(xi: float, seed: int) -> None:
    x = _state(seed)
    u = np.random.default_rng(seed + 10).uniform(-1, 1, 6)
    dt = 0.05
    F, G = moving_jacobians(x, u, dt, xi)
    assert F.shape == (N_MOVING, N_MOVING) and G.shape == (N_MOVING, 6)
    f = propagate_moving
    Fn = np.column_stack([(f(x + e, u, dt, xi) - f(x - e, u, dt, xi)) / (2 * EPS) for e in np.eye(14) * EPS])
    Gn = np.column_stack([(f(x, u + e, dt, xi) - f(x, u - e, dt, xi)) / (2 * EPS) for e in np.eye(6) * EPS])
    assert np.allclose(F, Fn, atol=1e-7)
    assert np.allclose(G, Gn, atol=1e-7)


def test_the_process_noise_of_the_pads_velocity_is_its_acceleration() -> None:
    ekf = MovingPadEkf(EkfConfig(), MovingPadConfig(enabled=True, accel_sigma_m_s2=0.4), x0=np.zeros(N_MOVING))
    q = ekf.process_noise_density
    assert np.array_equal(q[0:12], DeliveryEkf(EkfConfig()).process_noise_density)
    assert q[12] == q[13] == pytest.approx(0.16)
    P0 = ekf.P.copy()
    assert ekf.predict(np.zeros(6), 0.01)  # (one sub-step: max_step_s is larger)
    assert ekf.P[12, 12] - P0[12, 12] == pytest.approx(0.16 * 0.01, rel=1e-9)


def test_the_switch_is_refused_without_fusion_or_camera() -> None:
    for landing in ({"fusion": False}, {"use_camera": False}):
        with pytest.raises(ConfigError, match=r"moving_pad\.enabled = true needs fusion = true and use_camera"):
            config_from_dict({"landing": {**landing, "moving_pad": {"enabled": True}}})
    assert not config_from_dict({}).landing.moving_pad.enabled  # off by default


class _Fix(NamedTuple):
    time_s: float
    x_m: float
    y_m: float
    z_m: float
    pdop: float = math.sqrt(3.0)


def _fly(ekf: DeliveryEkf, turn_rate_rad_s: float, seconds: float = 40.0) -> tuple[list[float], list[float]]:
    """The vehicle 5 m over a pad driving at 2 m/s (turning at ``turn_rate_rad_s``), circling 1 m
    around it; GPS with a 1.5 m bias at 10 Hz, the pad-fixed position at 10 Hz (UWB-like, in the
    frame where the pad sits at the origin), the true ground velocity as the input at 50 Hz.
    Returns the position errors (pad-fixed frame) and the pad-velocity errors over time."""
    rng = np.random.default_rng(3)
    speed, dt = 2.0, 0.02
    bias = np.array([1.5, -1.0, 0.0])
    pad = np.zeros(2)
    course = 0.3
    pos_err, vel_err = [], []
    for k in range(round(seconds / dt)):
        t = k * dt
        v_pad = speed * np.array([math.cos(course), math.sin(course)])
        rel = np.array([math.cos(0.5 * t), math.sin(0.5 * t)])
        rel_v = 0.5 * np.array([-math.sin(0.5 * t), math.cos(0.5 * t)])
        x_true = np.array([*(pad + rel), -5.0])
        v_true = np.array([*(v_pad + rel_v), 0.0])
        ekf.predict(np.concatenate([v_true + rng.normal(0.0, 0.05, 3), np.zeros(3)]), dt)
        if k % 5 == 0:
            ekf.update_sdk(x_true + bias + rng.normal(0.0, 0.05, 3), np.zeros(3))
            p_pad = np.array([*rel, -5.0]) + rng.normal(0.0, 0.05, 3)
            ekf.update_uwb(_Fix(t, *p_pad), Transform.identity())
            pos_err.append(float(np.hypot(*(ekf.x[0:2] - rel))))
            if isinstance(ekf, MovingPadEkf):
                vel_err.append(float(np.hypot(*(np.array(ekf.pad_velocity_ne) - v_pad))))
        pad = pad + v_pad * dt
        course += turn_rate_rad_s * dt
    return pos_err, vel_err


@pytest.mark.parametrize("turn_deg_s", [0.0, 6.0])
def test_the_filter_tracks_a_pad_driving_at_2_m_s(turn_deg_s: float) -> None:
    cfg = EkfConfig(uwb_position_sigma_m=0.05, uwb_position_sigma_gain_m_per_m=0.0)
    ekf = MovingPadEkf(cfg, MovingPadConfig(enabled=True))
    pos_err, vel_err = _fly(ekf, math.radians(turn_deg_s))
    settled = len(pos_err) // 2  # after 20 s
    # the pad's velocity to ~0.1 m/s (noisy inputs, 0.05 m/s per 50 Hz sample; turning: 0.2 m/s^2 centripetal)
    assert np.mean(vel_err[settled:]) < 0.15 and max(vel_err[settled:]) < 0.4
    assert np.mean(pos_err[settled:]) < 0.06 and max(pos_err[settled:]) < 0.15
    # the paper's 12-state filter on the same data: carried off between fixes, then gating them out
    base = DeliveryEkf(cfg)
    base_err, _ = _fly(base, math.radians(turn_deg_s))
    assert np.mean(base_err[settled:]) > 10.0 * np.mean(pos_err[settled:])
    assert base.counters["uwb.rejected_gate"] > 100 and ekf.counters["uwb.rejected_gate"] == 0

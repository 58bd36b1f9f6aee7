"""The landing fusion's process input corrected for a biased autopilot velocity
([landing] ekf_velocity_bias_tau_s): the autopilot reports a velocity off by a constant while its
GPS-held position moves at the true one (PX4 v1.16 SIH near the ground)."""

import math

import numpy as np
import pytest

from companion.autopilot.types import Attitude, PositionNed
from companion.config import MovingPadConfig
from companion.delivery.fusion import FusionSetup, LandingFusion
from companion.geometry.mounts import pad_pose_ned
from companion.geometry.se3 import Transform

TRUE_V = (0.4, -0.2, 0.0)  # m/s, NED; the autopilot reports 0


def fly(tau_s: float, seconds: float = 6.0, dt: float = 0.02) -> tuple[LandingFusion, list[float]]:
    """The fusion fed 50 Hz attitude and position samples (GPS-only: no pad data); returns it and
    the horizontal error of its estimate against the autopilot's (true) position per sample."""
    setup = FusionSetup(
        T_world_pad=pad_pose_ned(0.0, 0.0, 0.0),
        T_body_camera=Transform.identity(),
        velocity_bias_tau_s=tau_s,
        velocity_bias_max_m_s=1.0,
    )
    f = LandingFusion(setup, 0.0)
    errs = []
    for k in range(1, int(seconds / dt) + 1):
        t = k * dt
        n, e = TRUE_V[0] * t, TRUE_V[1] * t
        f.on_sample(Attitude(t, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
        f.on_sample(PositionNed(t, n, e, -3.0, 0.0, 0.0, 0.0))
        est = f.estimate()
        if est is not None:
            errs.append(math.hypot(est.north_m - n, est.east_m - e))
    return f, errs


def test_off_by_default_the_reported_velocity_carries_the_estimate():
    assert FusionSetup(T_world_pad=Transform.identity(), T_body_camera=Transform.identity()).velocity_bias_tau_s == 0
    _, errs = fly(0.0)
    # without the correction the EKF predicts with 0 m/s and is pulled along by the position
    # updates alone: it lags the moving vehicle by a steady amount
    assert np.mean(errs[-50:]) > 0.01


def test_the_corrected_input_removes_the_lag_once_the_bias_is_learned():
    f, errs = fly(0.5)
    _, raw = fly(0.0)
    assert f.velocity_bias_correction is not None and f.velocity_bias_correction.active.settled
    # the process input is the true velocity after ~10 tau
    assert f.process_velocity_ned_m_s[:2] == pytest.approx(TRUE_V[:2], abs=1e-3)
    assert np.mean(errs[-50:]) < 0.1 * np.mean(raw[-50:])


def test_the_correction_is_held_to_its_limit():
    setup = FusionSetup(
        T_world_pad=pad_pose_ned(0.0, 0.0, 0.0),
        T_body_camera=Transform.identity(),
        velocity_bias_tau_s=0.2,
        velocity_bias_max_m_s=0.1,
    )
    f = LandingFusion(setup, 0.0)
    for k in range(1, 200):
        t = k * 0.02
        f.on_sample(PositionNed(t, TRUE_V[0] * t, TRUE_V[1] * t, -3.0, 0.0, 0.0, 0.0))
    assert math.hypot(*f.process_velocity_ned_m_s[:2]) == pytest.approx(0.1, abs=1e-6)


def test_a_moving_pads_locked_position_moves_on_by_the_pads_travel():
    """With [landing.moving_pad] the fused position is pad-relative: the position the velocity-bias
    corrections measure against moves on by the pad's estimated travel (its rate a ground velocity)."""
    setup = FusionSetup(
        T_world_pad=pad_pose_ned(0.0, 0.0, 0.0),
        T_body_camera=Transform.identity(),
        moving_pad=MovingPadConfig(enabled=True),
    )
    f = LandingFusion(setup, 0.0)
    f.on_sample(Attitude(0.02, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))
    f.on_sample(PositionNed(0.02, 0.0, 0.0, -3.0, 0.0, 0.0, 0.0))
    f.ekf.xi = 1  # as after the first pad-local datum; the pad at 2 m/s north
    f.ekf.x[12:14] = (2.0, 0.0)
    got = []
    for k in range(2, 12):
        t = k * 0.02
        f._last_uwb_s = t  # pad data fresh
        f.on_sample(PositionNed(t, 0.0, 0.0, -3.0, 0.0, 0.0, 0.0))
        est, locked = f.estimate(), f.locked_position()
        assert est is not None and locked is not None
        got.append((locked[0], locked[1][0] - est.north_m))
    (t0, d0), (t1, d1) = got[0], got[-1]
    assert d1 - d0 == pytest.approx(2.0 * (t1 - t0), rel=1e-6)

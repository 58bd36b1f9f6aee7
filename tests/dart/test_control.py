"""PID with filtered derivative and anti-windup; the Dart controller (dart 3.2.2, sec. 4)."""

from __future__ import annotations

import math
from dataclasses import dataclass

import pytest

from companion.dart.control import (
    DartCommand,
    DartController,
    DartControllerConfig,
    DartSetpoint,
    Pid,
    PidGains,
)


def test_proportional_and_integral_by_hand() -> None:
    pid = Pid(PidGains(kp=2.0, ki=0.5))
    # first step: no dt yet -> P only: 2 * (1 - 0.25) = 1.5
    assert pid.update(0.0, 1.0, 0.25) == pytest.approx(1.5)
    # 0.1 s later, same error 0.75: I = 0.5 * 0.75 * 0.1 = 0.0375 -> 1.5375
    assert pid.update(0.1, 1.0, 0.25) == pytest.approx(1.5375)
    assert pid.integral == pytest.approx(0.0375)


def test_derivative_on_measurement_has_no_setpoint_kick() -> None:
    pid = Pid(PidGains(kp=1.0, kd=10.0, d_filter_tau_s=0.0))
    for k in range(5):
        pid.update(0.1 * k, 0.0, 0.0)
    # a setpoint step of 1: output jumps by kp * 1 only, no derivative spike
    assert pid.update(0.5, 1.0, 0.0) == pytest.approx(1.0)
    # a measurement step of 0.1 in 0.1 s: D = -kd * 0.1 / 0.1 = -10 (unfiltered)
    assert pid.update(0.6, 1.0, 0.1) == pytest.approx(0.9 - 10.0)


def test_derivative_low_pass_by_hand() -> None:
    pid = Pid(PidGains(kp=0.0, kd=1.0, d_filter_tau_s=0.3))
    assert pid.update(0.0, 0.0, 0.0) == 0.0  # first sample after reset: no derivative
    # measurement ramps at 1 m/s -> raw derivative -1 each step; alpha = 0.1 / (0.3 + 0.1)
    alpha = 0.25
    expected = 0.0
    for k in range(1, 6):
        expected += alpha * (-1.0 - expected)
        assert pid.update(0.1 * k, 0.0, 0.1 * k) == pytest.approx(expected)
    # step 1: -0.25, step 2: -0.4375, ... -> towards -1
    assert expected == pytest.approx(-(1 - 0.75**5))


def test_output_clamp_and_conditional_integration() -> None:
    gains = PidGains(kp=1.0, ki=1.0, out_min=-1.0, out_max=1.0)
    pid = Pid(gains)
    for k in range(100):  # error 10 for 10 s, saturated throughout
        u = pid.update(0.1 * k, 10.0, 0.0)
        assert -1.0 <= u <= 1.0
    assert pid.saturated
    # conditional integration: nothing was integrated into the saturation (naive: I = 99)
    assert pid.integral == pytest.approx(0.0)
    # the error reverses: the output leaves saturation at once (no wind-up delay)
    assert pid.update(10.0, -0.5, 0.0) == pytest.approx(-0.5 - 0.05)


def test_integral_limits_and_integration_towards_unsaturation() -> None:
    pid = Pid(PidGains(kp=0.0, ki=1.0, i_min=-0.3, i_max=0.3))
    for k in range(50):
        pid.update(0.1 * k, 1.0, 0.0)
    assert pid.integral == pytest.approx(0.3)
    # saturated high, error negative: integrating is allowed (it leaves saturation)
    pid2 = Pid(PidGains(kp=10.0, ki=1.0, out_min=-1.0, out_max=1.0))
    pid2.reset(integral=0.5)  # as if integrated earlier
    pid2.update(0.0, 0.0, 0.0)
    u = pid2.update(0.1, -0.05, 0.0)  # P = -0.5, candidate I = 0.5 - 0.005
    assert pid2.integral == pytest.approx(0.495)
    assert u == pytest.approx(-0.005)


def test_reset_and_bad_inputs() -> None:
    pid = Pid(PidGains(kp=1.0, ki=1.0, kd=1.0))
    pid.update(0.0, 1.0, 0.0)
    pid.update(1.0, 1.0, 0.0)
    assert pid.integral != 0.0
    pid.reset()
    assert pid.integral == 0.0 and pid.output == 0.0
    last = pid.update(2.0, 1.0, 0.0)
    assert pid.update(3.0, math.nan, 0.0) == last
    assert pid.update(3.0, 1.0, math.inf) == last
    assert pid.update(2.0, 1.0, 0.0) == last  # time did not advance
    assert pid.rejected == 3


def test_angle_error_wraps() -> None:
    pid = Pid(PidGains(kp=1.0, kd=1.0, d_filter_tau_s=0.0, wrap_error=True))
    # setpoint 3.1, measurement -3.1: the short way is -0.0832 rad, not +6.2
    assert pid.update(0.0, 3.1, -3.1) == pytest.approx(-(2 * math.pi - 6.2))
    # measurement crosses +-pi: -3.1 -> 3.1 is a change of -0.0832 rad, derivative +0.832
    u = pid.update(0.1, 3.1, 3.1)
    assert u == pytest.approx(0.0 + (2 * math.pi - 6.2) / 0.1)


def test_gains_validation() -> None:
    with pytest.raises(ValueError):
        PidGains(kp=-1.0)
    with pytest.raises(ValueError):
        PidGains(kp=1.0, out_min=1.0, out_max=-1.0)


# ------------------------------------------------------------------------ DartController
@dataclass(frozen=True)
class Pose:
    time_s: float
    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float = 0.0


SETPOINT = DartSetpoint(x_m=0.0, y_m=0.0, z_m=3.0, yaw_rad=0.0)


def test_integral_only_while_engaged_and_no_jump_on_engagement() -> None:
    cfg = DartControllerConfig()
    ctl = DartController(cfg)
    pose = Pose(0.0, x_m=-0.5, y_m=0.2, z_m=3.4, yaw_rad=0.1)
    # 10 s disengaged with a constant error: no contribution, nothing integrates
    for k in range(220):
        t = k / 22.0
        cmd = ctl.update(t, Pose(t, -0.5, 0.2, 3.4, 0.1), SETPOINT, engaged=False)
        assert (cmd.roll_us, cmd.pitch_us, cmd.thrust_us, cmd.yaw_rate_us) == (0, 0, 0, 0)
        assert not cmd.engaged
    assert all(p.integral == 0.0 for p in ctl.pids)
    # engagement: the first command is the proportional term only, no stored integral
    t = 10.0
    cmd = ctl.update(t, Pose(t, pose.x_m, pose.y_m, pose.z_m, pose.yaw_rad), SETPOINT, engaged=True)
    assert cmd.engaged and cmd.valid
    assert cmd.roll_us == pytest.approx(cfg.x.kp * 0.5)  # error +0.5 m in x -> roll right
    assert cmd.thrust_us == pytest.approx(cfg.y.kp * -0.2)  # 0.2 m too high -> less thrust
    assert cmd.pitch_us == pytest.approx(cfg.z.kp * -0.4)  # 0.4 m too far -> nose down
    assert cmd.yaw_rate_us == pytest.approx(cfg.yaw.kp * -0.1)
    assert ctl.engagements == 1


def test_disengage_resets_integrators_and_reengage_starts_clean() -> None:
    ctl = DartController()
    t = 0.0
    for _ in range(100):  # engaged, the integrators build up
        ctl.update(t, Pose(t, -0.5, 0.2, 3.4), SETPOINT, engaged=True)
        t += 1 / 22.0
    assert ctl.pid_x.integral > 0.0 and ctl.pid_y.integral < 0.0
    cmd = ctl.update(t, Pose(t, -0.5, 0.2, 3.4), SETPOINT, engaged=False)
    assert not cmd.engaged and cmd.roll_us == 0.0
    assert all(p.integral == 0.0 for p in ctl.pids)  # reset within the same call
    t += 1 / 22.0
    cmd = ctl.update(t, Pose(t, -0.5, 0.2, 3.4), SETPOINT, engaged=True)
    assert cmd.roll_us == pytest.approx(ctl.config.x.kp * 0.5)  # no wind-up jump
    assert ctl.engagements == 2


def test_clamps_respected_over_a_long_saturation() -> None:
    ctl = DartController()
    t = 0.0
    for _ in range(300):
        cmd = ctl.update(t, Pose(t, -20.0, -20.0, 30.0, 3.0), SETPOINT, engaged=True)
        assert abs(cmd.roll_us) <= ctl.config.x.out_max
        assert abs(cmd.thrust_us) <= ctl.config.y.out_max
        assert abs(cmd.pitch_us) <= ctl.config.z.out_max
        assert abs(cmd.yaw_rate_us) <= ctl.config.yaw.out_max
        t += 1 / 22.0
    assert cmd.roll_us == ctl.config.x.out_max
    assert ctl.pid_x.integral == 0.0  # saturated from the start: nothing integrated


def test_axis_mapping_and_signs() -> None:
    cfg = DartControllerConfig(axis_channels=("pitch", "roll", "throttle"), axis_signs=(-1.0, 1.0, -1.0), yaw_sign=-1.0)
    ctl = DartController(cfg)
    cmd = ctl.update(0.0, Pose(0.0, -1.0, 0.5, 2.0, 0.2), DartSetpoint(0.0, 0.0, 0.0), True)
    assert cmd.pitch_us == pytest.approx(-cfg.x.kp * 1.0)
    assert cmd.roll_us == pytest.approx(cfg.y.kp * -0.5)
    # C_z: error 0 - 2 = -2 m -> 120 * -2 = -240 us, clamped to -200, sign -1 -> +200 us
    assert cmd.thrust_us == pytest.approx(200.0)
    assert cmd.yaw_rate_us == pytest.approx(cfg.yaw.kp * 0.2)
    with pytest.raises(ValueError):
        DartControllerConfig(axis_channels=("roll", "roll", "pitch"))


def test_stale_or_missing_estimate_gives_no_contribution() -> None:
    ctl = DartController()
    cmd = ctl.update(1.0, None, SETPOINT, engaged=True)
    assert isinstance(cmd, DartCommand) and cmd.engaged and not cmd.valid
    assert cmd.roll_us == cmd.pitch_us == cmd.thrust_us == cmd.yaw_rate_us == 0.0
    cmd = ctl.update(2.0, Pose(1.0, 1.0, 1.0, 1.0), SETPOINT, engaged=True)  # 1 s old
    assert not cmd.valid and ctl.invalid_steps == 2
    cmd = ctl.update(2.1, Pose(2.05, math.nan, 1.0, 1.0), SETPOINT, engaged=True)
    assert not cmd.valid

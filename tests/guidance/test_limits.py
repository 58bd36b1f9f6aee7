import math

from companion.config import LimitsConfig
from companion.guidance import clamp_velocity
from companion.guidance.setpoint import VelocitySetpoint

LIM = LimitsConfig(
    max_horizontal_speed_m_s=5, max_climb_m_s=2, max_descent_m_s=1, geofence_radius_m=100, geofence_max_alt_m=50
)


def test_within_limits_untouched():
    r = clamp_velocity(VelocitySetpoint(1, 2, 0.5, 0.3), LIM)
    assert not r.clamped and r.setpoint == VelocitySetpoint(1, 2, 0.5, 0.3)


def test_speed_climb_descent_clamped():
    r = clamp_velocity(VelocitySetpoint(6, 8, -5, 0.0), LIM)
    assert math.isclose(math.hypot(r.setpoint.north_m_s, r.setpoint.east_m_s), 5.0)
    assert math.isclose(r.setpoint.north_m_s / r.setpoint.east_m_s, 6 / 8)  # direction kept
    assert r.setpoint.down_m_s == -2 and "climb" in r.reason
    assert clamp_velocity(VelocitySetpoint(0, 0, 3, 0), LIM).setpoint.down_m_s == 1


def test_nan_becomes_hover():
    r = clamp_velocity(VelocitySetpoint(float("nan"), 0, 0, 1.0), LIM)
    assert r.clamped and "non-finite" in r.reason
    assert (r.setpoint.north_m_s, r.setpoint.east_m_s, r.setpoint.down_m_s) == (0, 0, 0)


def test_geofence_removes_outward_motion_only():
    out = clamp_velocity(VelocitySetpoint(3, 1, 0, 0), LIM, position_ned=(100.0, 0.0, -10.0)).setpoint
    assert math.isclose(out.north_m_s, 0.0, abs_tol=1e-12) and out.east_m_s == 1
    back = clamp_velocity(VelocitySetpoint(-3, 0, 0, 0), LIM, position_ned=(100.0, 0.0, -10.0))
    assert not back.clamped
    up = clamp_velocity(VelocitySetpoint(0, 0, -1, 0), LIM, position_ned=(0.0, 0.0, -50.0))
    assert up.setpoint.down_m_s == 0 and "altitude" in up.reason


def test_an_acceleration_fed_forward_is_kept_and_held_to_its_limit():
    lim = LimitsConfig(max_horizontal_accel_m_s2=2.0)
    kept = clamp_velocity(VelocitySetpoint(0.1, 0.2, 0.5, 0.0, (0.3, -0.4)), lim)
    assert not kept.clamped and kept.setpoint.accel_ne_m_s2 == (0.3, -0.4)
    held = clamp_velocity(VelocitySetpoint(0.1, 0.2, 0.5, 0.0, (3.0, 4.0)), lim)
    assert held.clamped and "acceleration" in held.reason
    assert held.setpoint.accel_ne_m_s2 is not None
    assert math.isclose(math.hypot(*held.setpoint.accel_ne_m_s2), 2.0)
    assert math.isclose(held.setpoint.accel_ne_m_s2[0] / held.setpoint.accel_ne_m_s2[1], 0.75)  # direction kept


def test_a_non_finite_acceleration_leaves_the_velocity_alone():
    r = clamp_velocity(VelocitySetpoint(1.0, 0.0, 0.5, 0.0, (float("nan"), 0.0)), LIM)
    assert r.clamped and "non-finite acceleration" in r.reason
    assert r.setpoint == VelocitySetpoint(1.0, 0.0, 0.5, 0.0)


def test_no_acceleration_is_fed_forward_at_the_fence():
    out = clamp_velocity(VelocitySetpoint(3, 1, 0, 0, (1.0, 0.0)), LIM, position_ned=(100.0, 0.0, -10.0))
    assert out.setpoint.accel_ne_m_s2 is None and "geofence" in out.reason

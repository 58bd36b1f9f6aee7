"""The velocity setpoint both backends send (SET_POSITION_TARGET_LOCAL_NED) asks the autopilot for
the velocity and the yaw: the type_mask's bits checked against MAVLink's POSITION_TARGET_TYPEMASK
names, not against a number (the mask was once 3527, which also set YAW_IGNORE, and PX4 and
ArduCopter held their take-off heading while the embedded simulator flew the path's)."""

from __future__ import annotations

from pymavlink.dialects.v20 import ardupilotmega as mav2

from companion.autopilot.mavlink_messages import VELOCITY_ACCEL_YAW_MASK, VELOCITY_YAW_MASK, velocity_setpoint_message
from companion.guidance.setpoint import VelocitySetpoint


def test_the_mask_uses_velocity_and_yaw_and_ignores_the_rest():
    ignored = {
        "X": mav2.POSITION_TARGET_TYPEMASK_X_IGNORE,
        "Y": mav2.POSITION_TARGET_TYPEMASK_Y_IGNORE,
        "Z": mav2.POSITION_TARGET_TYPEMASK_Z_IGNORE,
        "AX": mav2.POSITION_TARGET_TYPEMASK_AX_IGNORE,
        "AY": mav2.POSITION_TARGET_TYPEMASK_AY_IGNORE,
        "AZ": mav2.POSITION_TARGET_TYPEMASK_AZ_IGNORE,
        "YAW_RATE": mav2.POSITION_TARGET_TYPEMASK_YAW_RATE_IGNORE,
    }
    used = {
        "VX": mav2.POSITION_TARGET_TYPEMASK_VX_IGNORE,
        "VY": mav2.POSITION_TARGET_TYPEMASK_VY_IGNORE,
        "VZ": mav2.POSITION_TARGET_TYPEMASK_VZ_IGNORE,
        "YAW": mav2.POSITION_TARGET_TYPEMASK_YAW_IGNORE,
        "FORCE_SET": mav2.POSITION_TARGET_TYPEMASK_FORCE_SET,
    }
    for name, bit in ignored.items():
        assert VELOCITY_YAW_MASK & bit, f"{name} should be ignored"
    for name, bit in used.items():
        assert not VELOCITY_YAW_MASK & bit, f"{name} should not be set"
    assert sum(ignored.values()) == VELOCITY_YAW_MASK


def test_the_message_carries_the_yaw_in_local_ned():
    m = velocity_setpoint_message(1234, 1, 1, VelocitySetpoint(1.0, -2.0, 0.5, 0.6435))
    assert m.coordinate_frame == mav2.MAV_FRAME_LOCAL_NED
    assert not m.type_mask & mav2.POSITION_TARGET_TYPEMASK_YAW_IGNORE
    assert (m.vx, m.vy, m.vz, m.yaw) == (1.0, -2.0, 0.5, 0.6435)


def test_an_acceleration_fed_forward_clears_the_acceleration_bits_only():
    m = velocity_setpoint_message(1234, 1, 1, VelocitySetpoint(1.0, -2.0, 0.5, 0.6435, (0.25, -0.5)))
    accel = (
        mav2.POSITION_TARGET_TYPEMASK_AX_IGNORE
        | mav2.POSITION_TARGET_TYPEMASK_AY_IGNORE
        | mav2.POSITION_TARGET_TYPEMASK_AZ_IGNORE
    )
    assert m.type_mask == VELOCITY_ACCEL_YAW_MASK == VELOCITY_YAW_MASK & ~accel
    assert (m.vx, m.vy, m.vz, m.afx, m.afy, m.afz, m.yaw) == (1.0, -2.0, 0.5, 0.25, -0.5, 0.0, 0.6435)
    plain = velocity_setpoint_message(1234, 1, 1, VelocitySetpoint(1.0, -2.0, 0.5, 0.6435))
    assert plain.type_mask == VELOCITY_YAW_MASK and (plain.afx, plain.afy) == (0.0, 0.0)

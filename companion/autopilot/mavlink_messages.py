"""MAVLink messages the companion sends, built in one place for every sender: the pymavlink
backend sends them, the simulator's tlog encoder logs them, the MAVSDK backend uses the mask."""

from __future__ import annotations

import os
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from companion.autopilot.types import VelocitySetpoint

VELOCITY_YAW_MASK = 0b0000_1101_1100_0111  # SET_POSITION_TARGET_LOCAL_NED: use vx, vy, vz and yaw only


def velocity_setpoint_message(
    time_boot_ms: int, target_system: int, target_component: int, sp: VelocitySetpoint
) -> Any:
    """SET_POSITION_TARGET_LOCAL_NED carrying a velocity in local NED and an absolute yaw."""
    return mavlink2.MAVLink_set_position_target_local_ned_message(
        time_boot_ms & 0xFFFFFFFF,
        target_system,
        target_component,
        mavlink2.MAV_FRAME_LOCAL_NED,
        VELOCITY_YAW_MASK,
        0.0,
        0.0,
        0.0,
        sp.north_m_s,
        sp.east_m_s,
        sp.down_m_s,
        0.0,
        0.0,
        0.0,
        sp.yaw_rad,
        0.0,
    )

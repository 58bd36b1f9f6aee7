"""The setpoint guidance produces: a velocity in local NED with an absolute NED yaw.

Guidance computes it, :func:`companion.guidance.limits.clamp_velocity` clamps it, and the
autopilot backends send it (SET_POSITION_TARGET_LOCAL_NED, velocity + yaw).
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class VelocitySetpoint:
    """Offboard velocity setpoint in local NED with an absolute NED yaw."""

    north_m_s: float
    east_m_s: float
    down_m_s: float
    yaw_rad: float

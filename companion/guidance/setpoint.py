"""The setpoint guidance produces: a velocity in local NED with an absolute NED yaw, and in the
final descent optionally a horizontal acceleration fed forward.

Guidance computes it, :func:`companion.guidance.limits.clamp_velocity` clamps it, and the
autopilot backends send it (SET_POSITION_TARGET_LOCAL_NED, velocity + yaw, + acceleration when
given: PX4 adds it to its velocity loop's output, ArduCopter's GUIDED takes velocity and
acceleration together).
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
    # horizontal acceleration fed forward (north, east; m/s^2); None: velocity only
    accel_ne_m_s2: tuple[float, float] | None = None

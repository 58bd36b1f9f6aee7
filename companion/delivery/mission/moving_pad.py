"""Guidance onto a moving pad ([landing.moving_pad], docs/moving-pad.md).

Once the EKF has fused pad-local data (xi = 1) its position is the vehicle's in the pad-fixed
frame, in which the path, the hold and the descent are planned as on a standing pad. A velocity
setpoint is a ground velocity, though: the pad's estimated velocity is fed forward into the
horizontal setpoint of the phases that fly relative to the pad, so the vehicle moves with it and
the controllers only correct the offset; the descent's damping term takes the velocity relative
to the pad (phases.precision_descent). A pad faster than ``max_speed_m_s`` is not landed on.
"""

from __future__ import annotations

import dataclasses
import math

from companion.events import Phase
from companion.guidance.setpoint import VelocitySetpoint

#: the phases that fly relative to the pad (the way out once locked, the holds and searches
#: over it, the final descent): their setpoints get the pad's velocity
TRACKED_PHASES = (Phase.OUTBOUND, Phase.LANDING_PAD, Phase.PAD_HOLD, Phase.PAD_SEARCH, Phase.DROP_ZONE_HOLD)


def with_pad_velocity(
    phase: Phase, setpoint: VelocitySetpoint | None, pad_velocity_ne: tuple[float, float] | None
) -> VelocitySetpoint | None:
    """``setpoint`` with the pad's velocity added to its horizontal part in the phases that fly
    relative to the pad (unchanged elsewhere, or without an estimate of the pad's velocity)."""
    if setpoint is None or pad_velocity_ne is None or phase not in TRACKED_PHASES:
        return setpoint
    vn, ve = pad_velocity_ne
    return dataclasses.replace(setpoint, north_m_s=setpoint.north_m_s + vn, east_m_s=setpoint.east_m_s + ve)


def too_fast(pad_velocity_ne: tuple[float, float] | None, max_speed_m_s: float) -> str | None:
    """Why the pad is not landed on (its estimated speed above the stated limit), or None."""
    if pad_velocity_ne is None:
        return None
    speed = math.hypot(*pad_velocity_ne)
    if speed <= max_speed_m_s:
        return None
    return (
        f"the pad moves at {speed:.2f} m/s, faster than landing.moving_pad.max_speed_m_s = {max_speed_m_s:g} m/s "
        "(docs/moving-pad.md)"
    )

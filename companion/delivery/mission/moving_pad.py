"""Guidance onto a moving pad ([landing.moving_pad], docs/moving-pad.md).

Once the EKF has fused pad-local data (xi = 1) its position is the vehicle's in the pad-fixed
frame, in which the path, the hold and the descent are planned as on a standing pad. A velocity
setpoint is a ground velocity, though: the pad's estimated velocity is fed forward into the
horizontal setpoint of the phases that fly relative to the pad, so the vehicle moves with it and
the controllers only correct the offset; the descent's damping term takes the velocity relative
to the pad (phases.precision_descent). A pad faster than ``max_speed_m_s`` is not landed on.

Once the final descent has stopped sinking at the ground (PrecisionDescent.grounded) the deck, not
the estimate, sets the vehicle's ground velocity: the vehicle's own velocity is fed forward instead
of the pad's estimate. On a moving deck the two agree (the deck carries the vehicle); on a deck that
stops, or on a SITL's ground that cannot carry it, the estimate lags the stop, and a ground velocity
commanded to a vehicle that cannot follow it winds up the autopilot's position controller
(docs/moving-pad.md).
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


def pad_feedforward(
    pad_velocity_ne: tuple[float, float] | None,
    grounded: bool,
    own_velocity_ne: tuple[float, float] | None,
) -> tuple[float, float] | None:
    """The velocity fed forward: the pad's estimate, or once ``grounded`` (the descent stopped
    sinking at the ground) the vehicle's own ground velocity (the deck's, carried by it)."""
    if pad_velocity_ne is None or not grounded or own_velocity_ne is None:
        return pad_velocity_ne
    return own_velocity_ne

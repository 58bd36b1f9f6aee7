"""The autopilot's land detector (PX4's land_detector / ArduCopter's land_complete): on the ground
after ``land_detect_s`` at rest on it (the profile's), a touchdown recorded where a flight ended,
and the auto-disarm ``AUTO_DISARM_AFTER_LAND_S`` after landing in LAND.

:class:`LandDetector` is the part of :class:`~companion_sitl.vehicle.SimVehicle` that holds its
state; it sets the vehicle's ``landed`` and ``armed`` and appends to its ``touchdowns``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Protocol

from companion.autopilot.types import FlightMode, LandedState

AUTO_DISARM_AFTER_LAND_S = 2.0


@dataclass
class Touchdown:
    time_s: float
    north_m: float
    east_m: float
    payload_released: bool
    yaw_rad: float = math.nan  # true heading at touchdown (NED)


class Landing(Protocol):
    """What the detector reads and sets of the vehicle (SimVehicle; a Protocol: no import cycle)."""

    pn: float
    pe: float
    pd: float
    vd: float
    yaw: float
    armed: bool
    mode: FlightMode
    landed: LandedState
    payload_released: bool
    touchdowns: list[Touchdown]

    def _text(self, msg: str) -> None: ...


class LandDetector:
    """``ground_since`` / ``landed_since``: when the vehicle came to rest on the ground / was
    detected landed (None: not); ``airborne``: it flew since the last touchdown."""

    def __init__(self, land_detect_s: float) -> None:
        self.land_detect_s = land_detect_s
        self.ground_since: float | None = 0.0
        self.landed_since: float | None = 0.0
        self.airborne = False

    def update(self, v: Landing, t: float) -> None:
        """One physics step of the detector on the vehicle's truth at time ``t``."""
        on_ground = v.pd >= -0.01 and abs(v.vd) < 0.05
        if on_ground:
            if self.ground_since is None:
                self.ground_since = t
            if t - self.ground_since >= self.land_detect_s and v.landed is not LandedState.ON_GROUND:
                v.landed = LandedState.ON_GROUND
                self.landed_since = t
                if self.airborne:
                    self.airborne = False
                    v.touchdowns.append(Touchdown(t, v.pn, v.pe, v.payload_released, v.yaw))
                    v._text(f"landed at N {v.pn:.2f} E {v.pe:.2f}")
            if (
                v.armed
                and v.mode is FlightMode.LAND
                and v.landed is LandedState.ON_GROUND
                and self.landed_since is not None
                and t - self.landed_since >= AUTO_DISARM_AFTER_LAND_S
            ):
                v.armed = False
                v._text("auto-disarmed after landing")
        else:
            self.ground_since = None
            self.landed_since = None
            if v.pd < -0.3:
                self.airborne = True
                v.landed = LandedState.IN_AIR

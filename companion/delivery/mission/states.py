"""One small state object per phase: what a phase needs lives and dies with it. Entering a
phase makes its state anew (:func:`state_for`), so nothing is reset by hand."""

from __future__ import annotations

import math
from dataclasses import dataclass, field

from companion.config import MissionConfig
from companion.events import Phase
from companion.guidance.descent import PrecisionDescent


@dataclass
class OffboardEntry:
    """Streaming field setpoints before asking for OFFBOARD (PX4 refuses otherwise), and the
    re-entry after a link loss during which the autopilot's failsafe changed the mode."""

    stream_t0: float | None = None  # when the stream before the switch began
    requested: bool = False
    reenter: bool = False  # back from a link loss: OFFBOARD again

    def restart(self) -> None:
        self.reenter = True
        self.requested = False
        self.stream_t0 = None


@dataclass
class PhaseState:
    t0: float  # when the phase began (timeouts count from here)
    offboard: OffboardEntry = field(default_factory=OffboardEntry)


@dataclass
class TakeoffState(PhaseState):
    requested: bool = False
    ground_down_m: float | None = None  # the estimate's down when the phase began, before the climb


@dataclass
class LandingState(PhaseState):
    descent: PrecisionDescent | None = None  # the final descent's controller (its integral, its wait)
    touched_down: bool = False
    touchdown_lock: tuple[bool, str] = (True, "")  # the pad lock judged at touchdown
    # the touchdown was the companion's (its descent, or a LAND it asked for), judged when first seen
    touchdown_ours: bool = True
    touchdown_off_pad_m: float = 0.0  # how far outside the pad the estimate put the touchdown (0: on it)
    contact_ned: tuple[float, float, float] | None = None  # the estimate at the ground contact (descent.contact_time_s)
    sink_stop_ned: tuple[float, float, float] | None = None  # the estimate where the sinking last stopped
    precland_requested: bool = False
    touchdown_land_requested: bool = False  # the last metres handed to the autopilot's LAND
    disarm_not_before: float = -math.inf
    lock_reopened_at: float | None = None  # since when the descent's lock is lost to sigma alone
    drop_zone_blocked: str = ""  # the verdict when the drop zone was judged not clear below the commit height
    touchdown_drop_zone: str = ""  # the drop zone's verdict at touchdown when it was not clear


@dataclass
class PadSearchState(PhaseState):
    corners: list[tuple[float, float]] = field(default_factory=list)  # left to fly (NED north, east)
    corner_t0: float | None = None  # when the current corner was reached


@dataclass
class DropZoneHoldState(PhaseState):
    hold_ned: tuple[float, float, float] | None = None  # where the hold began (held there)
    why: str = ""  # the verdict that stopped the descent


@dataclass
class ReleaseState(PhaseState):
    requested: bool = False
    released_t0: float | None = None  # when the autopilot accepted the release
    error: str = ""  # the release failed: why (said once, then home with the parcel or stay)


@dataclass
class AbortHoldState(PhaseState):
    requested: bool = False
    forever: bool = False  # a commanded hold: until the pilot, a land or an abort command


@dataclass
class AbortLandState(PhaseState):
    requested: bool = False
    disarm_not_before: float = -math.inf


def state_for(phase: Phase, t0: float, cfg: MissionConfig) -> PhaseState:
    if phase in (Phase.TAKEOFF, Phase.TAKEOFF_RETURN):
        return TakeoffState(t0)
    if phase in (Phase.LANDING_PAD, Phase.LANDING_HOME):
        return LandingState(t0, descent=PrecisionDescent(cfg.descent, cfg.land_speed_m_s))
    if phase is Phase.PAD_SEARCH:
        return PadSearchState(t0)
    if phase is Phase.RELEASE:
        return ReleaseState(t0)
    if phase is Phase.DROP_ZONE_HOLD:
        return DropZoneHoldState(t0)
    if phase is Phase.ABORT_HOLD:
        return AbortHoldState(t0)
    if phase is Phase.ABORT_LAND:
        return AbortLandState(t0)
    return PhaseState(t0)

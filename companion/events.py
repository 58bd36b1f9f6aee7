"""Typed mission phases and events (timestamped on the shell's clock), and the commands the mission
takes from the ground."""

from __future__ import annotations

import enum
from dataclasses import dataclass


class Phase(enum.Enum):
    PREFLIGHT = "preflight"  # waiting for a healthy vehicle, computing the path
    ARMING = "arming"
    TAKEOFF = "takeoff"  # autopilot takeoff to takeoff_alt_m
    OUTBOUND = "outbound"  # vector field, s = +1, sectors S1..S5
    LANDING_PAD = "landing_pad"  # final descent on the pad
    RELEASE = "release"  # parcel release on the ground
    PAD_HOLD = "pad_hold"  # no pad lock: hold at the approach height (or fly onto the pad once locked)
    PAD_SEARCH = "pad_search"  # no pad lock: the search pattern around the configured pad
    DIVERT = "divert"  # no pad lock after the tries: vector field, s = +1, to the alternate pad
    DROP_ZONE_HOLD = "drop_zone_hold"  # the pad or its margin is not clear: hold, then divert or home
    WINCH = "winch"  # winch delivery: hover over the locked pad, lower the parcel, release, reel in
    TAKEOFF_RETURN = "takeoff_return"
    INBOUND = "inbound"  # vector field, s = -1, back along the path
    LANDING_HOME = "landing_home"
    DONE = "done"
    ABORT_HOLD = "abort_hold"
    ABORT_LAND = "abort_land"
    PILOT = "pilot"  # the pilot took over; autonomy ended
    FAILED = "failed"

    @property
    def terminal(self) -> bool:
        return self in (Phase.DONE, Phase.FAILED, Phase.PILOT)


class EventKind(enum.Enum):
    PHASE = "phase"  # entered a new phase
    SECTOR = "sector"  # entered a new path sector
    ARMED = "armed"
    TOUCHDOWN = "touchdown"
    RELEASED = "released"
    DELIVERED = "delivered"
    RETURNED = "returned"
    ABORT = "abort"
    PILOT_TAKEOVER = "pilot_takeover"
    LINK_LOST = "link_lost"
    LINK_RESTORED = "link_restored"
    REQUEST_FAILED = "request_failed"
    WARNING = "warning"
    PAD_LOCK = "pad_lock"  # a step of the no-release-off-the-pad policy, with its reason
    GO_NO_GO = "go_no_go"  # a go/no-go check decided (fence, battery, wind): refused, verified, returning
    WINCH = "winch"  # a step of the winch delivery (payout, parcel down, reeled in) or why it failed
    WINCH_JAM = "winch_jam"  # the line will not reel in: the GCS hears it CRITICAL, the vehicle lands where it is
    ORDER = "order"  # a delivery order from the ground: received, accepted or refused (with the reason), flown
    DROP_ZONE = "drop_zone"  # the drop-zone check stopped the descent, the pad cleared, or the hold ended


class CommandKind(enum.Enum):
    """A command to the mission from the ground (Zenoh, :mod:`companion.telemetry.auth`) or the
    operator's GCS (:mod:`companion.delivery.gcs`); its value is the wire's and the logs' name."""

    HOLD = "hold"  # stop and hold position
    RETURN = "return"  # fly back home along the path
    LAND = "land"  # land where the vehicle is
    ABORT = "abort"  # the mission's abort procedure (hold, then land)


@dataclass(frozen=True, slots=True)
class MissionEvent:
    time_s: float
    kind: EventKind
    phase: Phase
    detail: str = ""

"""What the delivery mission takes and gives: inputs, outputs, requests to the autopilot, the
summary with its failure kind, and the named result of a phase handler."""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, field

from companion.autopilot.types import HomePosition, RangefinderReading, VehicleStatus, Wind
from companion.autopilot.winch import WinchCommand, WinchStatus
from companion.delivery.padlock import PadLock
from companion.estimation.types import StateEstimate
from companion.events import MissionEvent, Phase
from companion.guidance.setpoint import VelocitySetpoint
from companion.vision.drop_zone import DropZoneVerdict
from companion.vision.parcel_tag import ParcelSighting


class RequestKind(enum.Enum):
    ARM = "arm"
    DISARM = "disarm"
    TAKEOFF = "takeoff"
    START_OFFBOARD = "start_offboard"
    HOLD = "hold"
    LAND = "land"
    PRECISION_LAND = "precision_land"
    RELEASE = "release"
    WINCH = "winch"  # one MAV_CMD_DO_WINCH (Request.winch)


class Leg(enum.IntEnum):
    """The sense a leg is flown along its path: delivery's s, +1 towards the pad, -1 home."""

    OUT = 1
    HOME = -1


class FailureKind(enum.Enum):
    """Why a mission ended without finishing as planned; ``MissionSummary.failure`` says the detail."""

    NONE = "none"
    PATH_PLANNING = "path_planning"  # no path from home to the pad
    NOT_READY = "not_ready"  # the vehicle was not ready (healthy, home, estimate) in time
    REFUSED = "refused"  # a go/no-go check refused the delivery before take-off
    ABORTED = "aborted"  # an abort (a check, a ground command): held, landed
    OPERATOR_ABORT = "operator_abort"  # the operator's signal (Ctrl-C, SIGTERM): held, landed
    ABORT_FAILED = "abort_failed"  # the autopilot refused the abort's HOLD or LAND
    LANDED_ARMED = "landed_armed"  # on the ground after an abort, the DISARM refused
    PILOT_TAKEOVER = "pilot_takeover"
    RETURNED_ON_COMMAND = "returned_on_command"  # a ground command sent it home with the parcel
    RETURNED_GO_NO_GO = "returned_go_no_go"  # battery or wind sent it home with the parcel
    NOT_DELIVERED = "not_delivered"  # the pad policy or the winch kept the parcel aboard
    NOT_RELEASED = "not_released"  # the release was refused or the parcel is still attached
    TIMED_OUT = "timed_out"  # the shell's time limit for the whole mission ran out
    # the autopilot landed on the way out while the companion was not in control (its failsafe
    # after a stall or a link loss, a pilot's LAND): the parcel stays aboard, autonomy ends
    AUTOPILOT_LANDED = "autopilot_landed"


@dataclass(frozen=True, slots=True)
class Request:
    id: int
    kind: RequestKind
    alt_rel_m: float = 0.0
    winch: WinchCommand | None = None


@dataclass(frozen=True, slots=True)
class RequestResult:
    """What became of a request. ``permanent``: the autopilot will give the same answer to the
    same request (UNSUPPORTED, DENIED, FAILED, never answered): the mission does not resend it."""

    id: int
    ok: bool
    error: str = ""
    permanent: bool = False


@dataclass(frozen=True, slots=True)
class MissionInputs:
    time_s: float
    estimate: StateEstimate | None
    status: VehicleStatus | None
    home: HomePosition | None
    link_ok: bool = True
    # the pad's lock (camera/UWB observation age, EKF 1-sigma), measured by the shell; None: the
    # mission runs without the no-release-off-the-pad policy's inputs (judged as no lock)
    pad_lock: PadLock | None = None
    wind: Wind | None = None  # the autopilot's wind estimate (the wind go / no-go)
    # the heading of the pad landed on (NED rad: measured, else configured); None: no alignment
    pad_heading_rad: float | None = None
    # age of the camera's newest pad heading observation (s; inf: none): the heading is in sight
    pad_heading_age_s: float = math.inf
    autopilot_yaw_rad: float | None = None  # the autopilot's own yaw (ATTITUDE); None: not known
    winch: WinchStatus | None = None  # the winch's newest report (mission.delivery = "winch")
    rangefinder: RangefinderReading | None = None  # the newest downward DISTANCE_SENSOR ([mission.rangefinder])
    # the drop-zone check's verdict on the pad and its margin ([landing.drop_zone]); None: no check
    drop_zone: DropZoneVerdict | None = None
    # the pad's estimated velocity (north, east; m/s) with [landing.moving_pad] on and the pad
    # locked (delivery.fusion.LandingFusion.pad_velocity_ne); None: the pad stands
    pad_velocity_ne: tuple[float, float] | None = None
    # the camera's newest sighting of the parcel on its line ([winch.camera]); None: none
    parcel: ParcelSighting | None = None


@dataclass(frozen=True, slots=True)
class MissionOutput:
    phase: Phase
    setpoint: VelocitySetpoint | None = None
    request: Request | None = None
    events: tuple[MissionEvent, ...] = ()
    sector: int = 0
    lyapunov: float = math.nan


@dataclass(frozen=True, slots=True)
class Step:
    """What a phase handler decided this tick: the setpoint, at most one request, and V of the
    vector field where it was evaluated (delivery eq 17; NaN elsewhere)."""

    setpoint: VelocitySetpoint | None = None
    request: Request | None = None
    lyapunov: float = math.nan


NOTHING = Step()


@dataclass
class MissionSummary:
    delivered: bool = False
    returned: bool = False
    takeoff_time_s: float | None = None
    end_time_s: float | None = None
    pad_touchdown_ned: tuple[float, float, float] | None = None
    home_touchdown_ned: tuple[float, float, float] | None = None
    failure: str = ""  # the detail, for people; decisions read failure_kind
    events: list[MissionEvent] = field(default_factory=list)
    home_with_parcel: bool = False  # landed at home with the parcel still aboard
    pad_tries: int = 0  # descents onto the pad that the no-release-off-the-pad policy stopped
    diverted: bool = False  # flew to the alternate pad (landing.policy.fallback = "alternate")
    failure_kind: FailureKind = FailureKind.NONE

    def fail(self, kind: FailureKind, detail: str) -> None:
        self.failure_kind, self.failure = kind, detail

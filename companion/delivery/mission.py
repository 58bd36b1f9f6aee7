"""The delivery mission state machine (delivery Algorithm 1, made complete).

Pure and synchronous: :meth:`DeliveryMission.step` takes timestamped inputs and returns what
to do (a velocity setpoint, at most one autopilot request, events). The asyncio shell executes
requests and feeds their results back with :meth:`DeliveryMission.on_result`.

Phases: preflight -> arming -> takeoff -> outbound (s = +1) -> landing on the pad -> release
-> (arming -> takeoff -> inbound (s = -1) -> landing at home) -> done. Abort: hold, then land.
No pad lock: pad_hold, pad_search, then home with the parcel or divert (s = +1) to the alternate
pad and the same policy there (docs/delivery-policy.md, docs/divert.md).
Winch delivery (mission.delivery = "winch"): the descent onto the pad becomes phase winch: hover
over the locked pad, lower, release, reel in (delivery.winch), then inbound (docs/winch.md).
The pilot always wins: a mode switch away from offboard that we did not ask for ends autonomy.
"""

from __future__ import annotations

import enum
import logging
import math
from dataclasses import dataclass, field, replace

import numpy as np

from companion.autopilot.types import FlightMode, HomePosition, LandedState, VehicleStatus, Wind
from companion.autopilot.winch import WinchCommand, WinchStatus
from companion.config import (
    FenceConfig,
    GoNoGoConfig,
    LimitsConfig,
    MissionConfig,
    PadLockPolicyConfig,
    WinchConfig,
)
from companion.delivery.gonogo import (
    BatteryMonitor,
    WayHome,
    WindMonitor,
    round_trip_problem,
    time_home_s,
    way_home,
)
from companion.delivery.padlock import PAD_DATA_FRESH_S, PadLock, expanding_square, judge_pad_lock, pad_in_sight
from companion.delivery.planning import pad_config_ned, plan_delivery, plan_leg
from companion.delivery.winch import WinchSequence, WindCorrection
from companion.estimation.types import StateEstimate
from companion.events import EventKind, MissionEvent, Phase
from companion.geometry.earth import GeoPoint
from companion.geometry.heading import heading_difference_rad, yaw_toward
from companion.geometry.mission_frame import MissionFrame
from companion.geometry.rotations import wrap_angle
from companion.guidance.geofence import FenceNed, fence_in_ned, legs_problem
from companion.guidance.path import DeliveryPath, PathGeometryError
from companion.guidance.setpoint import VelocitySetpoint
from companion.guidance.speed_schedule import speed_scale as schedule_speed
from companion.guidance.vector_field import VectorField

log = logging.getLogger(__name__)

FOLLOW_PHASES = (
    Phase.OUTBOUND,
    Phase.LANDING_PAD,
    Phase.INBOUND,
    Phase.LANDING_HOME,
    Phase.PAD_HOLD,
    Phase.PAD_SEARCH,
    Phase.DIVERT,
    Phase.WINCH,
)
PAD_POSITION_GAIN_1_S = 1.0  # hold and search: speed per metre off the target (then capped)
# an autopilot's land detector after contact (PX4 SIH: ON_GROUND 3-7 s after it; ArduCopter ~2 s):
# what the final descent's hold leaves before the touchdown timeout, besides the descent itself
TOUCHDOWN_REPORT_MARGIN_S = 5.0
# landing_settle_s: the descent ramps to zero over the height it covers in this long at land speed
# above the floor, about what an autopilot's vertical velocity loop needs to stop (PX4, ArduCopter:
# 0.3-0.5 s)
SETTLE_BAND_S = 0.4
PAD_CORNER_TOLERANCE_M = 0.5  # a search corner is reached this close
PAD_HEIGHT_TOLERANCE_M = 0.3  # the approach height is reached this close
PAD_HOVER_SPEED_M_S = 0.3  # winch: the payout starts only below this horizontal speed
WINCH_APPROACH_LEAD_S = 0.5  # winch: the hover takes over this long of the S5 descent before its height
OFFBOARD_STREAM_BEFORE_SWITCH_S = 0.5  # PX4 wants setpoints at > 2 Hz before OFFBOARD
MAX_REQUEST_TRIES = 3
REQUEST_RETRY_DELAY_S = 1.0  # between tries of a request the autopilot refused for now
DISARM_REPEAT_S = 2.0  # after an accepted DISARM, the status may show armed for a moment
ALIGNED_RAD = math.radians(1.0)  # pad heading: the yaw setpoint has finished its turn this close


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


@dataclass(frozen=True, slots=True)
class MissionOutput:
    phase: Phase
    setpoint: VelocitySetpoint | None = None
    request: Request | None = None
    events: tuple[MissionEvent, ...] = ()
    sector: int = 0
    lyapunov: float = math.nan


@dataclass
class _Pending:
    request: Request
    tries: int = 1


@dataclass
class MissionSummary:
    delivered: bool = False
    returned: bool = False
    takeoff_time_s: float | None = None
    end_time_s: float | None = None
    pad_touchdown_ned: tuple[float, float, float] | None = None
    home_touchdown_ned: tuple[float, float, float] | None = None
    failure: str = ""
    events: list[MissionEvent] = field(default_factory=list)
    home_with_parcel: bool = False  # landed at home with the parcel still aboard
    pad_tries: int = 0  # descents onto the pad that the no-release-off-the-pad policy stopped
    diverted: bool = False  # flew to the alternate pad (landing.policy.fallback = "alternate")


class DeliveryMission:
    def __init__(
        self,
        cfg: MissionConfig,
        landing_controller: str = "companion",
        pad_policy: PadLockPolicyConfig | None = None,
        fence: FenceConfig | None = None,
        limits: LimitsConfig | None = None,
        go_no_go: GoNoGoConfig | None = None,
        winch: WinchConfig | None = None,
    ):
        """``landing_controller``: "companion" flies the descent onto the pad with velocity
        setpoints; "autopilot" hands it to the autopilot's own precision landing (fed
        LANDING_TARGET by the shell) and only watches for the touchdown. ``pad_policy``: no
        release off the pad (docs/delivery-policy.md); None or require_pad_lock = false: the
        parcel is released wherever the vehicle lands on the way out. ``fence`` (when enabled)
        and ``limits`` (the setpoint clamp): the planned legs must lie inside, or the delivery is
        refused before take-off (guidance.geofence). ``go_no_go`` (battery_check): the charge
        must cover the round trip before take-off and the way home in flight (delivery.gonogo)."""
        if landing_controller not in ("companion", "autopilot"):
            raise ValueError(f"landing_controller {landing_controller!r}: expected 'companion' or 'autopilot'")
        self.cfg = cfg
        self.landing_controller = landing_controller
        self.phase = Phase.PREFLIGHT
        self.frame: MissionFrame | None = None
        self.path: DeliveryPath | None = None
        self.field: VectorField | None = None
        self.speed_ref_m_s: float | None = None  # v_r of the last field evaluation (this tick), else None
        self.sense = 0  # s of that evaluation (+1 towards the pad, -1 home), else 0
        self.z_start = 0.0
        self._start_ned: np.ndarray | None = None  # where the outbound started (home, on the ground)
        self.pad_ned: np.ndarray | None = None  # the configured pad (NED), once planned
        self._return_planned = False
        self.summary = MissionSummary()
        self._next_id = 1
        self._pending: _Pending | None = None
        self._retry: tuple[RequestKind, float, float] | None = None  # kind, alt, not-before time
        self._phase_t0 = 0.0
        self._stream_t0: float | None = None  # when we started streaming before offboard
        self._offboard_requested = False
        self._expect_mode_change = False
        self._sector = 0
        self._link_lost = False
        self._link_lost_mode: FlightMode | None = None
        self._abort_reason = ""
        self._release_t0: float | None = None
        self._events: list[MissionEvent] = []
        self._now = 0.0
        self._low_since: float | None = None
        self._precland_requested = False
        self.pad_policy = pad_policy if pad_policy is not None and pad_policy.require_pad_lock else None
        self._pad_target_ne: tuple[float, float] | None = None  # PAD_HOLD: where to hold while not locked
        self._search: list[tuple[float, float]] = []  # PAD_SEARCH: corners left (NED north, east)
        self._corner_t0: float | None = None  # PAD_SEARCH: when the current corner was reached
        self._touchdown_lock: tuple[bool, str] = (True, "")
        self._lock_reopened_at: float | None = None  # since when the descent's lock is lost to sigma alone
        self._takeoff_ground_down_m: float | None = None  # the estimate's down when a take-off phase began
        self.fence_cfg = fence if fence is not None and fence.enabled else None
        self.limits = limits
        self._yaw_sp: tuple[float, float] | None = None  # (time, yaw) of the last setpoint (pad heading)
        self._fence_ned: FenceNed | None = None
        self._home_geo: GeoPoint | None = None
        self._home_ned = (0.0, 0.0, 0.0)
        g = go_no_go
        self.battery = (
            BatteryMonitor(g.battery_reserve_pct, g.battery_use_pct_per_s, g.battery_measure_s)
            if g is not None and g.battery_check
            else None
        )
        self.wind = (
            WindMonitor(g.wind_limit_m_s, g.wind_exceed_s, g.wind_max_age_s)
            if g is not None and g.wind_limit_m_s > 0
            else None
        )
        # winch delivery (docs/winch.md): the descent onto the pad becomes a hover and a winch sequence
        self.winch_cfg = (winch or WinchConfig()) if cfg.delivery == "winch" else None
        self.winch: WinchSequence | None = None
        self._winch_wind = WindCorrection(self.winch_cfg or WinchConfig())

    # ------------------------------------------------------------------ public API
    def abort(self, time_s: float, reason: str) -> None:
        """Hold position, then land (an abort is never a mid-air disarm)."""
        if self.phase is Phase.ABORT_HOLD and self._hold_forever:
            self._hold_forever = False  # an abort during a commanded hold: land after abort_hold_s
            self._phase_t0 = time_s
            self._emit(EventKind.ABORT, reason)
            return
        if self.phase.terminal or self.phase in (Phase.ABORT_HOLD, Phase.ABORT_LAND):
            return
        self._now = time_s
        self._abort_reason = reason
        self._emit(EventKind.ABORT, reason)
        if self._on_ground_phase():
            self.summary.failure = f"aborted on the ground: {reason}"
            self._goto(Phase.FAILED)
        else:
            self._goto(Phase.ABORT_HOLD)

    def refuse(self, time_s: float, reason: str) -> None:
        """Refuse the delivery before take-off (a go/no-go check failed): nothing is armed."""
        if not self._on_ground_phase() or self._left_pad or self.phase.terminal:
            return
        self._now = time_s
        self.summary.failure = f"refused before take-off: {reason}"
        self._emit(EventKind.GO_NO_GO, self.summary.failure)
        self._goto(Phase.FAILED)

    def go_no_go(self, time_s: float, detail: str) -> None:
        """Report a go/no-go check's verdict that changes nothing (e.g. the fence verified)."""
        self._now = time_s
        self._emit(EventKind.GO_NO_GO, detail)

    def waiting_for(self) -> str:
        """The request the mission waits on, if any (for a mission that ends without finishing)."""
        if self._pending is not None:
            r = self._pending.request
            return f"waiting for the answer to {r.kind.value} #{r.id} (try {self._pending.tries})"
        if self._retry is not None:
            return f"{self._retry[0].value} to be retried at t = {self._retry[2]:.1f} s"
        return "no request in flight"

    @property
    def returning(self) -> bool:
        """Flying (or landing) back home: guidance targets the GPS-surveyed home."""
        return self.phase in (Phase.TAKEOFF_RETURN, Phase.INBOUND, Phase.LANDING_HOME)

    @property
    def fused_estimate_steers(self) -> bool:
        """Guidance flies on the fused estimate (the way out and the landing on the pad); the way
        back flies on the GPS-frame estimate (home is a GPS point). A winch delivery keeps the
        fused one over the pad until the line is in."""
        return (not self.summary.delivered or self.phase is Phase.WINCH) and not self.returning

    def guidance_estimate(
        self, gps_frame: StateEstimate | None, fused: StateEstimate | None, time_s: float
    ) -> StateEstimate | None:
        """The estimate this tick flies: the fused one while it steers (and exists), else the
        autopilot's GPS-frame one, carried forward to ``time_s`` (StateEstimate.predicted,
        estimate_predict_max_s). The shell and its replay both take it from here."""
        est = fused if fused is not None and self.fused_estimate_steers else gps_frame
        return est.predicted(time_s, self.cfg.estimate_predict_max_s) if est is not None else None

    def command(self, time_s: float, kind: str, sender: str = "ground") -> str:
        """A ground command (hold, return, land, abort). The mission decides; the safety contract
        (clamps, pilot priority) is untouched because every setpoint still goes through the shell.
        Returns what was done, for the reply and the log."""
        self._now = time_s
        if self.phase.terminal:
            return f"ignored: mission already {self.phase.value}"
        if kind == "abort":
            self.abort(time_s, f"ground command from {sender}: abort")
            return "aborting: hold, then land"
        if kind == "land":
            self._emit(EventKind.ABORT, f"ground command from {sender}: land here")
            if self._on_ground_phase():
                self.summary.failure = f"ground command from {sender}: land (on the ground)"
                self._goto(Phase.FAILED)
                return "on the ground: mission ended"
            self._abort_reason = f"ground command from {sender}: land"
            self._goto(Phase.ABORT_LAND)
            self._land_requested = False
            return "landing where the vehicle is"
        if kind == "hold":
            if self._on_ground_phase():
                return "ignored: on the ground"
            self._abort_reason = f"ground command from {sender}: hold"
            self._emit(EventKind.ABORT, self._abort_reason)
            self._hold_forever = True
            self._goto(Phase.ABORT_HOLD)
            return "holding position until the pilot takes over or a land/abort command"
        if kind == "return":
            if self.phase is Phase.WINCH and self.winch is not None:
                # the line comes in first (a parcel on the line would be dragged home); then inbound
                if self.winch.stop(time_s, f"ground command from {sender}: return"):
                    self._emit(EventKind.WARNING, f"ground command from {sender}: reel in, then return home")
                    return "reeling in, then returning home along the path"
                return "ignored: the winch sequence is already ending (reel in, then home)"
            if self.phase in (Phase.OUTBOUND, Phase.LANDING_PAD, Phase.PAD_HOLD, Phase.PAD_SEARCH, Phase.DIVERT):
                self._emit(EventKind.WARNING, f"ground command from {sender}: return home without delivering")
                self.summary.failure = "returned on ground command"
                self._goto(Phase.INBOUND)
                return "returning home along the path"
            return f"ignored: cannot return from {self.phase.value}"
        return f"ignored: unknown command {kind!r}"

    def on_result(self, result: RequestResult) -> None:
        p = self._pending
        if p is None or p.request.id != result.id:
            log.warning("result for unknown request %s ignored", result)
            return
        self._pending = None
        if (
            self.phase is Phase.WINCH
            and self.winch is not None
            and p.request.kind
            in (
                RequestKind.WINCH,
                RequestKind.RELEASE,
            )
        ):
            # the winch sequence decides what a refusal means (reel in, home with the parcel): no retries
            if not result.ok:
                self._emit(EventKind.REQUEST_FAILED, f"{p.request.kind.value}: {result.error}")
            elif p.request.kind is RequestKind.RELEASE:
                self._emit(EventKind.RELEASED, "release commanded over the pad (winch)")
            self.winch.on_result(self._now, result.ok, result.error)
            return
        if result.ok:
            self._on_request_ok(p.request)
            return
        final = result.permanent or p.tries >= MAX_REQUEST_TRIES
        self._emit(
            EventKind.REQUEST_FAILED,
            f"{p.request.kind.value} (try {p.tries} of {MAX_REQUEST_TRIES}"
            + (", not retried: the autopilot will answer the same" if result.permanent else "")
            + f"): {result.error}",
        )
        if not final:
            # the one retry path: phase handlers issue nothing while a retry is scheduled
            self._retry = (p.request.kind, p.request.alt_rel_m, self._now + REQUEST_RETRY_DELAY_S)
            self._retry_tries = p.tries + 1
            return
        reason = (
            f"{p.request.kind.value} refused: {result.error}"
            if result.permanent
            else f"{p.request.kind.value} failed {p.tries} times: {result.error}"
        )
        if p.request.kind is RequestKind.RELEASE and self.phase is Phase.RELEASE:
            self._release_error = reason
        elif p.request.kind in (RequestKind.HOLD, RequestKind.LAND) and self.phase in (
            Phase.ABORT_HOLD,
            Phase.ABORT_LAND,
        ):
            self.summary.failure = reason
            self._goto(Phase.FAILED)
        elif p.request.kind is RequestKind.DISARM and self.phase is Phase.ABORT_LAND:
            # on the ground after an abort: say it and end, rather than ask again for ever
            self.summary.failure = f"aborted: {self._abort_reason}; landed but still armed ({reason})"
            self.summary.end_time_s = self._now
            self._goto(Phase.FAILED)
        else:
            self.abort(self._now, reason)

    def step(self, inp: MissionInputs) -> MissionOutput:
        if not self._started:
            self._started = True
            self._phase_t0 = inp.time_s  # timeouts count from the first tick, on the caller's clock
        self._now = inp.time_s
        setpoint: VelocitySetpoint | None = None
        request: Request | None = None
        lyap = math.nan
        # what the field is evaluated with this tick (telemetry): absent outside the vector field
        self.speed_ref_m_s = None
        self.sense = 0

        if not self._check_link(inp):
            return self._out(None, None, lyap)

        if self.phase in FOLLOW_PHASES or self.phase in (Phase.TAKEOFF, Phase.TAKEOFF_RETURN):
            self._check_estimate(inp)
        if self.phase in FOLLOW_PHASES:
            self._check_pilot(inp)

        if self.battery is not None:
            self._check_battery(inp)
        if self.wind is not None and self.phase in (Phase.OUTBOUND, Phase.LANDING_PAD, Phase.DIVERT):
            why = self.wind.update(inp.time_s, inp.wind)
            if why:
                self._emit(EventKind.GO_NO_GO, f"abandoning the delivery, flying home: {why}")
                self.summary.failure = f"returned without delivering: {why}"
                self._goto(Phase.INBOUND)

        handler = getattr(self, f"_do_{self.phase.value}", None)
        if handler is not None:
            setpoint, request, lyap = handler(inp)
        setpoint = self._align_with_pad(inp, setpoint)
        if request is None and self._retry is not None and self._pending is None:
            # (a phase change drops the retry: see _goto)
            kind, alt, not_before = self._retry
            if inp.time_s >= not_before:
                self._retry = None
                request = self._make_request(kind, alt, tries=getattr(self, "_retry_tries", 2))
        return self._out(setpoint, request, lyap)

    # ------------------------------------------------------------------ phases
    def _do_preflight(self, inp: MissionInputs) -> tuple:
        st, home, est = inp.status, inp.home, inp.estimate
        if self.frame is None and home is not None and est is not None:
            try:
                self.frame, self.path, self.z_start = plan_delivery(
                    self.cfg,
                    GeoPoint(home.lat_deg, home.lon_deg, home.alt_amsl_m),
                    np.array(est.position_ned),
                    (home.north_m, home.east_m, home.down_m),
                )
            except (PathGeometryError, ValueError) as err:
                self.summary.failure = f"path planning failed: {err}"
                self._emit(EventKind.WARNING, self.summary.failure)
                self._goto(Phase.FAILED)
                return None, None, math.nan
            self._start_ned = np.array(est.position_ned, dtype=float)
            self.pad_ned = np.array(self.frame.pad_ned, dtype=float)  # kept when the way home is replanned
            self._home_geo = GeoPoint(home.lat_deg, home.lon_deg, home.alt_amsl_m)
            self._home_ned = (home.north_m, home.east_m, home.down_m)
            violation = self._fence_violation(self._start_ned, self.pad_ned)
            if violation:
                self.refuse(inp.time_s, violation)
                return None, None, math.nan
            self.field = VectorField(self.path, self.cfg.sector_speed_m_s, self.cfg.convergence_gain)
            self._emit(
                EventKind.PHASE,
                f"path planned: d = {self.path.d:.2f} m, h = {self.path.h} m, r = {self.path.r} m, "
                f"heading {math.degrees(self.frame.heading_rad):.1f} deg",
            )
        ready = st is not None and st.healthy and self.frame is not None
        wind_ok = self.wind is None or self._left_pad or self.wind.fresh(inp.time_s, inp.wind)
        if ready and wind_ok and self.wind is not None and not self._left_pad:
            why = self.wind.take_off_problem(inp.time_s, inp.wind)
            if why:
                self.refuse(inp.time_s, why)
                return None, None, math.nan
        ready = ready and wind_ok
        if ready and st is not None and self.battery is not None and not self._left_pad:
            why = self._battery_round_trip(st.battery_pct)
            if why:
                self.refuse(inp.time_s, why)
                return None, None, math.nan
        if ready and st is not None and st.armed is False and self._idle():
            self._goto(Phase.ARMING)
            return None, self._make_request(RequestKind.ARM), math.nan
        if inp.time_s - self._phase_t0 > self.cfg.ready_timeout_s:
            why = "no status" if st is None else ("not healthy" if not st.healthy else "no home/estimate")
            if st is not None and st.healthy and self.frame is not None and not wind_ok:
                why = "no wind estimate from the autopilot (go_no_go.wind_limit_m_s is set)"
            self.summary.failure = f"vehicle not ready after {self.cfg.ready_timeout_s} s: {why}"
            self._goto(Phase.FAILED)
        return None, None, math.nan

    def _do_arming(self, inp: MissionInputs) -> tuple:
        return None, None, math.nan  # waits for the ARM result (see _on_request_ok)

    def _do_takeoff(self, inp: MissionInputs) -> tuple:
        return self._takeoff_common(inp, Phase.OUTBOUND, s=1)

    def _do_takeoff_return(self, inp: MissionInputs) -> tuple:
        return self._takeoff_common(inp, Phase.INBOUND, s=-1)

    def _takeoff_common(self, inp: MissionInputs, nxt: Phase, s: int) -> tuple:
        est = inp.estimate
        if est is None or self.field is None or self.frame is None:
            return None, None, math.nan
        if s == -1 and self._divert_after_takeoff:
            # took off again from the first pad after a touchdown without lock: to the alternate
            reason, self._divert_after_takeoff = self._divert_after_takeoff, ""
            self._divert_takeoff = self._plan_divert(est, reason)
            if not self._divert_takeoff:
                self.summary.failure = f"parcel not delivered: {reason}"
        if self._divert_takeoff:
            s, nxt = 1, Phase.DIVERT
        elif s == -1 and not self._return_planned:
            self._plan_return(est)
        if inp.time_s - self._phase_t0 > self.cfg.takeoff_timeout_s:
            self.abort(inp.time_s, f"takeoff did not reach {self.cfg.takeoff_alt_m} m in time")
            return None, None, math.nan
        if self._takeoff_ground_down_m is None:
            self._takeoff_ground_down_m = est.position_ned[2]  # where it stands, before the climb
        if not self._takeoff_requested:
            if self._idle():
                self._takeoff_requested = True
                self._expect_mode_change = True
                return None, self._make_request(RequestKind.TAKEOFF), math.nan
            return None, None, math.nan
        # judged until the field's stream starts (_stream_t0 set), then never again: the stream must
        # not stop when the mode leaves HOLD for OFFBOARD (the HOLD test lapses with the switch while
        # our height may still read below the take-off height), or the autopilot's offboard-loss
        # failsafe lands the vehicle
        if self._stream_t0 is None and not self._takeoff_done(inp, est):
            return None, None, math.nan
        sp, lyap = self._field_setpoint(est, s)
        req = self._enter_offboard(inp)
        if self._offboard_requested and req is None and self._pending is None and self._in_offboard(inp):
            self._divert_takeoff = False
            self._goto(nxt)
        return sp, req, lyap

    def _plan_return(self, est: StateEstimate) -> None:
        """The way home starts where the vehicle stands (the pad as it was found, which can lie metres
        from the configured one: GPS bias, a displaced pad), not at the configured pad: otherwise the
        vector field pulls the climb sideways onto the outbound path. Same h and r, home as before."""
        self._return_planned = self._home_planned = True
        # after a divert the path flown last starts at the first pad, not home: always replanned
        if not (self.cfg.return_from_landing_point or self.pad_index) or self._start_ned is None or self.frame is None:
            return
        # horizontally where the vehicle is (it has just armed there); the ground at the pad's level
        land = np.array([est.position_ned[0], est.position_ned[1], self.frame.pad_ned[2]], dtype=float)
        try:
            frame = MissionFrame.from_start_and_pad(self._start_ned, land)
            path = DeliveryPath(
                h=self.cfg.height_m, r=self.cfg.arc_radius_m, d=math.hypot(*(land - self._start_ned)[:2])
            )
            z_start = float(frame.point_from_ned(self._start_ned)[2])
            if z_start >= self.cfg.height_m - self.cfg.arc_radius_m:
                raise PathGeometryError(f"home is {z_start:.1f} m above the landing point, at or above the arcs")
            violation = self._fence_violation(land, self._start_ned, legs=("return",))
            if violation:
                raise PathGeometryError(violation)
        except (PathGeometryError, ValueError) as err:
            if self.pad_index:
                self.abort(self._now, f"no way home from the alternate pad: {err}")
                return
            self._emit(
                EventKind.WARNING, f"return path from the landing point failed ({err}): flying the outbound path back"
            )
            return
        moved = math.hypot(*(land[:2] - self.frame.pad_ned[:2]))
        self.frame, self.path, self.z_start = frame, path, z_start
        self.field = VectorField(path, self.cfg.sector_speed_m_s, self.cfg.convergence_gain)
        self._emit(
            EventKind.PHASE,
            f"return path planned from the landing point ({moved:.2f} m from the planned pad): d = {path.d:.2f} m, "
            f"heading {math.degrees(frame.heading_rad):.1f} deg",
        )

    def _takeoff_done(self, inp: MissionInputs, est: StateEstimate) -> bool:
        """At 90 % of the takeoff height by our estimate, or once the autopilot has finished its
        takeoff (holding in the air) above half of it: the autopilot climbs to the height by *its*
        altitude, which can sit 0.2-0.3 m off ours (on PX4 SIH a fused estimate may never reach
        90 % of a 2.5 m takeoff that PX4 has completed)."""
        h = self._height_above_ground(est)
        if h >= 0.9 * self.cfg.takeoff_alt_m:
            return True
        st = inp.status
        # the climb since the phase began counts too: an autopilot's height can read a metre off on
        # the ground after a landing (PX4 SIH: 1.27 m below home on the pad), and it takes off by
        # the takeoff height from where it stands
        ground = self._takeoff_ground_down_m
        climbed = ground - est.position_ned[2] if ground is not None else -math.inf
        return (
            st is not None
            and st.mode is FlightMode.HOLD
            and st.landed is LandedState.IN_AIR
            and max(h, climbed) >= 0.5 * self.cfg.takeoff_alt_m
        )

    def _enter_offboard(self, inp: MissionInputs) -> Request | None:
        """Stream field setpoints for a while, then ask for OFFBOARD (PX4 refuses otherwise).

        The caller returns the setpoint alongside; this only times the switch request.
        """
        if self._stream_t0 is None:
            self._stream_t0 = inp.time_s
        if (
            not self._offboard_requested
            and self._idle()
            and inp.time_s - self._stream_t0 >= OFFBOARD_STREAM_BEFORE_SWITCH_S
        ):
            self._offboard_requested = True
            self._expect_mode_change = True
            return self._make_request(RequestKind.START_OFFBOARD)
        return None

    @staticmethod
    def _in_offboard(inp: MissionInputs) -> bool:
        return inp.status is not None and inp.status.mode is FlightMode.OFFBOARD

    def _do_outbound(self, inp: MissionInputs) -> tuple:
        return self._follow(inp, s=1, landing=Phase.LANDING_PAD)

    def _do_inbound(self, inp: MissionInputs) -> tuple:
        if self.pad_index and not self._home_planned and inp.estimate is not None:
            self._plan_home_from(inp.estimate)  # the divert's path starts at the first pad, not home
            if self.phase is not Phase.INBOUND:
                return None, None, math.nan
        return self._follow(inp, s=-1, landing=Phase.LANDING_HOME)

    def _follow(self, inp: MissionInputs, s: int, landing: Phase) -> tuple:
        est = inp.estimate
        if est is None:
            return None, None, math.nan
        sp, lyap = self._field_setpoint(est, s)
        if self._reenter:
            # back from a link loss during which the autopilot's failsafe switched to HOLD
            req = self._enter_offboard(inp)
            if self._offboard_requested and req is None and self._pending is None and self._in_offboard(inp):
                self._reenter = False
                self._expect_mode_change = False
                self._offboard_requested = False
                self._stream_t0 = None
            return sp, req, lyap
        target_sector = 5 if s == 1 else 1
        approach_m = self.cfg.final_descent_alt_m
        if s == 1 and self.winch_cfg is not None:
            # the hover starts on the way down, one velocity-loop lag above its height: the descent at
            # v5 then slows onto it instead of sinking ~v5 x lag below (1.6 m on ArduCopter SITL)
            lead_m = self.cfg.sector_speed_m_s[4] * WINCH_APPROACH_LEAD_S
            approach_m = max(approach_m, self.winch_cfg.hover_height_m + lead_m)
        if self._sector == target_sector and self._height_above_ground(est) < approach_m:
            if s == 1 and self.pad_policy is not None:
                ok, why = judge_pad_lock(inp.pad_lock, self.pad_policy)
                if not ok:
                    return self._pad_try_failed(inp, f"no pad lock at the approach height: {why}"), None, lyap
            self._goto(landing)
        return sp, None, lyap

    def _do_landing_pad(self, inp: MissionInputs) -> tuple:
        return self._landing(inp, s=1)

    def _do_landing_home(self, inp: MissionInputs) -> tuple:
        return self._landing(inp, s=-1)

    def _landing(self, inp: MissionInputs, s: int) -> tuple:
        est, st = inp.estimate, inp.status
        if st is not None and st.landed is LandedState.ON_GROUND:
            if not self._touched_down:
                self._touched_down = True
                if s == 1 and self.pad_policy is not None:
                    self._touchdown_lock = judge_pad_lock(inp.pad_lock, self.pad_policy)
                if est is not None:
                    if s == 1:
                        self.summary.pad_touchdown_ned = est.position_ned
                    else:
                        self.summary.home_touchdown_ned = est.position_ned
                self._emit(EventKind.TOUCHDOWN, "pad" if s == 1 else "home")
            if not st.armed:
                if s == 1 and not self._touchdown_lock[0]:
                    return (
                        None,
                        self._home_with_parcel(f"no pad lock at touchdown: {self._touchdown_lock[1]}"),
                        math.nan,
                    )
                self._after_touchdown(s)
                return None, None, math.nan
            return None, self._ask_to_disarm(inp), math.nan
        if est is None:
            return None, None, math.nan
        if self._touchdown_land_requested:
            return None, None, math.nan  # the autopilot's LAND flies the rest; we wait for the touchdown
        if inp.time_s - self._phase_t0 > self.cfg.touchdown_timeout_s and self._idle():
            self._expect_mode_change = True
            self._touchdown_land_requested = True
            self._emit(EventKind.WARNING, "no touchdown in time: handing the last metres to the autopilot's LAND")
            return None, self._make_request(RequestKind.LAND), math.nan
        if s == 1 and self.landing_controller == "autopilot":
            # the autopilot's precision landing flies the descent; we only wait for the touchdown
            if not self._precland_requested and self._idle():
                self._precland_requested = True
                self._expect_mode_change = True
                return None, self._make_request(RequestKind.PRECISION_LAND), math.nan
            return None, None, math.nan
        if self._expect_mode_change:
            return None, None, math.nan
        if s == 1 and self.pad_policy is not None:
            h = self._height_above_ground(est)
            ok, why = judge_pad_lock(inp.pad_lock, self.pad_policy)
            if ok:
                self._lock_reopened_at = None
            elif h > self.pad_policy.commit_height_m and not self._lock_reopening(inp.pad_lock, inp.time_s):
                return self._pad_try_failed(inp, f"pad lock lost in the descent at {h:.1f} m: {why}"), None, math.nan
        in_sight = s == 1 and pad_in_sight(inp.pad_lock)
        return self._precision_descent(est, s, inp.time_s, in_sight), None, math.nan

    def _lock_reopening(self, lock: PadLock | None, time_s: float) -> bool:
        """The lock is lost only to the EKF's 1-sigma while the pad is still observed (the EKF
        re-opened its covariance after a run of gate rejections, and the next accepted observation
        closes it), for less than the policy's reopen_grace_s: a descent try is not failed on the
        tick of a re-opening (docs/delivery-policy.md)."""
        pol = self.pad_policy
        assert pol is not None
        # the pad in sight and young enough for the lock: what is missing is the 1-sigma
        if lock is None or not pad_in_sight(lock) or lock.observation_age_s >= pol.max_observation_age_s:
            self._lock_reopened_at = None
            return False
        if self._lock_reopened_at is None:
            self._lock_reopened_at = time_s
        return time_s - self._lock_reopened_at < pol.reopen_grace_s

    def _precision_descent(self, est: StateEstimate, s: int, time_s: float, in_sight: bool) -> VelocitySetpoint:
        """Final descent onto the target (the pad for s = +1, home for s = -1), in F_I.

        The vector field's convergence term scales with v_r, so at land speed it corrects only a
        few cm/s; here the horizontal error is closed proportionally (landing_xy_gain_1_s: firm,
        3 1/s by default, so the part of a gust the autopilot's velocity loop lets through is
        taken back within a fraction of a second), plus an integral term when
        landing_xy_integral_gain_1_s2 > 0 (:meth:`_landing_integral`), and with
        landing_xy_accel_feedforward > 0 a share of that command's rate sent as an acceleration, so
        an autopilot whose velocity loop answers slowly (PX4 SIH: ~1 s) does not make the loop
        circle the pad (docs/flying.md). The descent slows while the
        vehicle is off-centre and holds height at twice the tolerance (like PX4's precision
        landing) down to landing_hold_min_height_m, while the target is in sight (a camera or UWB
        observation of the pad within padlock.PAD_DATA_FRESH_S); with landing_settle_s it waits
        at that height until settled (:meth:`_settle_slow`). Blind (GPS only, at home, or the
        pad lost) it does not hold: holding cannot improve the estimate, and on an autopilot's
        estimate drifting near the ground it can sit on the ground until the touchdown timeout
        (docs/firmware-px4.md).
        """
        assert self.frame is not None and self.path is not None
        c = self.cfg
        p_i = self.frame.point_from_ned(est.position_ned)
        ex = float(p_i[0]) if s == 1 else float(p_i[0]) + self.path.d
        ey = float(p_i[1])
        e = math.hypot(ex, ey)
        height = self._height_above_ground(est)
        zeroed = height < c.landing_touchdown_height_m
        vx, vy = -c.landing_xy_gain_1_s * ex, -c.landing_xy_gain_1_s * ey
        if c.landing_xy_integral_gain_1_s2 > 0.0:
            ix, iy = self._landing_integral(ex, ey, time_s, frozen=zeroed, p_cmd=(vx, vy))
            vx -= ix
            vy -= iy
        vh = math.hypot(vx, vy)
        saturated = vh > c.landing_max_xy_speed_m_s
        if saturated:
            vx, vy = vx * c.landing_max_xy_speed_m_s / vh, vy * c.landing_max_xy_speed_m_s / vh
        tol = c.landing_xy_tolerance_m
        if zeroed:
            # touching down: a sideways command on the ground keeps the autopilot's land detector
            # from ever firing (ArduCopter), so only the descent remains
            vx = vy = 0.0
        # no hold that would run into the touchdown timeout: the autopilot's LAND after it flies the
        # autopilot's own estimate (PX4 SIH: 77 cm off), worse than going on down mid-swing (a loop
        # short of phase margin, e.g. a CPU-starved companion, can circle wider than the hold's gate)
        time_left_s = c.touchdown_timeout_s - (time_s - self._phase_t0)
        in_time = time_left_s > max(height, 0.0) / c.land_speed_m_s + TOUCHDOWN_REPORT_MARGIN_S
        gated = in_sight and height > c.landing_hold_min_height_m and in_time
        slow = min(1.0, max(0.0, 1.0 - (e - tol) / tol)) if gated else 1.0
        if c.landing_settle_s > 0.0 and not self._settle_released:
            slow = min(slow, self._settle_slow(e, height, time_s, in_sight and in_time))
        vz = -c.land_speed_m_s * slow
        v_ned = self.frame.vector_to_ned((vx, vy, vz))
        acc = None
        if c.landing_xy_accel_feedforward > 0.0 and not zeroed and not saturated:
            # the command's rate: d/dt(-k_p e - k_i int e) = -k_p v - k_i e, v the estimated velocity
            v_i = self.frame.vector_from_ned((est.north_m_s, est.east_m_s, est.down_m_s))
            k = c.landing_xy_accel_feedforward
            ax = -k * (c.landing_xy_gain_1_s * float(v_i[0]) + c.landing_xy_integral_gain_1_s2 * ex)
            ay = -k * (c.landing_xy_gain_1_s * float(v_i[1]) + c.landing_xy_integral_gain_1_s2 * ey)
            a_ned = self.frame.vector_to_ned((ax, ay, 0.0))
            acc = (float(a_ned[0]), float(a_ned[1]))
        return VelocitySetpoint(float(v_ned[0]), float(v_ned[1]), float(v_ned[2]), self.frame.yaw_to_ned(0.0), acc)

    def _settle_slow(self, e: float, height: float, time_s: float, may_wait: bool) -> float:
        """The descent's speed factor from landing_settle_s: 1 while the error has stayed within
        the tolerance for landing_settle_s (and from then on, once the vehicle is down to the
        floor's band), else proportional to the height above landing_hold_min_height_m over
        SETTLE_BAND_S x land speed (negative below it: climbs back), so the vehicle waits at the
        floor. No wait without the pad in sight or time left before the touchdown timeout (as the
        hold)."""
        c = self.cfg
        if not may_wait:
            self._settle_since = None
            return 1.0
        if e > c.landing_xy_tolerance_m:
            self._settle_since = None
        elif self._settle_since is None:
            self._settle_since = time_s
        settled = self._settle_since is not None and time_s - self._settle_since >= c.landing_settle_s
        above_m = height - c.landing_hold_min_height_m
        band_m = SETTLE_BAND_S * c.land_speed_m_s
        if settled:
            if above_m <= band_m:
                self._settle_released = True  # on down; the last part is not waited in again
            return 1.0
        # held at the floor on the fused height: the autopilot's own drifts near the ground (under
        # a zero vertical command the px4-sih profile's vehicle sank from 0.3 m to the ground)
        return min(1.0, max(-1.0, above_m / band_m))

    def _landing_integral(
        self, ex: float, ey: float, time_s: float, frozen: bool, p_cmd: tuple[float, float]
    ) -> tuple[float, float]:
        """The final descent's integral term, k_i * integral of the error (m/s, F_I): an autopilot
        flying our velocity on a biased estimate of its own moves at setpoint - bias, so the
        proportional law alone settles bias / k_p off the target (PX4 SIH: 0.2-0.4 m/s of bias near
        the ground, 4-8 cm at 5 1/s; docs/notes.md). Off by default and in
        params/ardupilot_quad.toml; params/px4_sih_quad.toml turns it on. Rectangle rule per
        guidance tick; the sum is held to landing_xy_integral_max_m_s and frozen once only the
        descent is commanded. Anti-windup by conditional integration: no sum while the command
        (``p_cmd``, the proportional part, minus the sum) is beyond landing_max_xy_speed_m_s and
        the step would take it further, so a descent that starts far off (GPS only: 0.8 m) does
        not carry a full sum past the target. Reset by every phase change (_goto)."""
        c = self.cfg
        last = self._landing_int_t
        self._landing_int_t = time_s
        if last is None:
            return self._landing_int
        dt = time_s - last
        ix0, iy0 = self._landing_int
        if not frozen and 0.0 < dt <= 1.0:  # a longer gap (link loss) adds nothing
            ki = c.landing_xy_integral_gain_1_s2
            ix, iy = ix0 + ki * ex * dt, iy0 + ki * ey * dt
            n = math.hypot(ix, iy)
            lim = c.landing_xy_integral_max_m_s
            if n > lim:
                ix, iy = ix * lim / n, iy * lim / n
            was = math.hypot(p_cmd[0] - ix0, p_cmd[1] - iy0)
            now = math.hypot(p_cmd[0] - ix, p_cmd[1] - iy)
            if not (now > c.landing_max_xy_speed_m_s and now > was):
                self._landing_int = (ix, iy)
        return self._landing_int

    # ------------------------------------------------------------------ no release off the pad
    def _pad_try_failed(self, inp: MissionInputs, reason: str) -> VelocitySetpoint | None:
        """A descent onto the pad cannot go on, or a hold and search found no lock: the policy's
        next step (docs/delivery-policy.md). Returns the setpoint of this tick (None: none)."""
        pol = self.pad_policy
        assert pol is not None
        self.summary.pad_tries += 1
        n, total = self.summary.pad_tries - self._tries_before_pad, pol.descent_tries
        lock = inp.pad_lock
        if lock is None or not lock.sensors:
            self._emit(EventKind.PAD_LOCK, reason)
            self._pad_fallback("no pad sensor: no pad lock can come", None)
            return None
        if n >= total:
            self._emit(EventKind.PAD_LOCK, f"try {n} of {total} failed: {reason}")
            where = " on the alternate pad" if self.pad_index else ""
            self._pad_fallback(f"{total} tries without a pad lock{where}", inp.estimate)
            return None
        self._emit(
            EventKind.PAD_LOCK,
            f"try {n} of {total} failed: {reason}; holding at the approach height "
            f"({self.cfg.final_descent_alt_m} m) for up to {pol.hold_s} s",
        )
        self._searched = False
        self._goto(Phase.PAD_HOLD)
        return None

    def _pad_fallback(self, reason: str, est: StateEstimate | None) -> None:
        """The last step: divert to the alternate pad (fallback = "alternate", from the first pad, with
        an estimate), else fly home with the parcel, in the air from here (on the ground after a
        touchdown without lock: :meth:`_home_with_parcel`)."""
        if est is not None and self._can_divert() and self._plan_divert(est, reason):
            self._goto(Phase.DIVERT)
            return
        self.summary.failure = f"parcel not delivered: {reason}"
        self._emit(EventKind.PAD_LOCK, f"{reason}: flying home with the parcel, to land there without releasing it")
        self._goto(Phase.INBOUND)

    def _home_with_parcel(self, reason: str) -> Request | None:
        """Landed on the way out without a pad lock: nothing is released; take off and fly home."""
        if not self._idle():
            return None
        if self._can_divert() and self._home_geo is not None:
            self._divert_after_takeoff = reason  # planned from where it stands once armed (_takeoff_common)
            self._emit(EventKind.PAD_LOCK, f"{reason}: parcel not released; taking off to divert to the alternate pad")
            self._left_pad = True
            self._goto(Phase.ARMING)
            return self._make_request(RequestKind.ARM)
        self.summary.failure = f"parcel not delivered: {reason}"
        self._emit(EventKind.PAD_LOCK, f"{reason}: parcel not released; taking off to fly home with it")
        self._left_pad = True  # the next ARM is for the way home
        self._goto(Phase.ARMING)
        return self._make_request(RequestKind.ARM)

    def _pad_setpoint(
        self, est: StateEstimate, north_m: float, east_m: float, down_m: float, speed_m_s: float
    ) -> VelocitySetpoint:
        """Hold and search: towards a point (NED), horizontally at most ``speed_m_s``, vertically at
        most the S5 descent speed."""
        assert self.frame is not None
        k = PAD_POSITION_GAIN_1_S
        vn, ve = k * (north_m - est.north_m), k * (east_m - est.east_m)
        vh = math.hypot(vn, ve)
        if vh > speed_m_s:
            vn, ve = vn * speed_m_s / vh, ve * speed_m_s / vh
        vz_max = self.cfg.sector_speed_m_s[4]
        vd = min(vz_max, max(-vz_max, k * (down_m - est.down_m)))
        return VelocitySetpoint(vn, ve, vd, self.frame.yaw_to_ned(0.0))

    def _pad_reentry(self, inp: MissionInputs) -> Request | None:
        """Back from a link loss in a hold or search: OFFBOARD again (as _follow does)."""
        if not self._reenter:
            return None
        req = self._enter_offboard(inp)
        if self._offboard_requested and req is None and self._pending is None and self._in_offboard(inp):
            self._reenter = False
            self._expect_mode_change = False
            self._offboard_requested = False
            self._stream_t0 = None
        return req

    def _do_pad_hold(self, inp: MissionInputs) -> tuple:
        """Step 1: at the approach height over the configured pad until locked (then onto the pad
        as the lock puts it, and the descent again), for up to hold_s."""
        est, pol = inp.estimate, self.pad_policy
        if est is None or self.frame is None or pol is None:
            return None, None, math.nan
        pad = self.frame.pad_ned
        down = float(pad[2]) - self.cfg.final_descent_alt_m
        sp = self._pad_setpoint(est, float(pad[0]), float(pad[1]), down, pol.search_speed_m_s)
        req = self._pad_reentry(inp)
        if req is not None or self._reenter:
            return sp, req, math.nan
        ok, why = judge_pad_lock(inp.pad_lock, pol)
        if ok:
            off = math.hypot(est.north_m - float(pad[0]), est.east_m - float(pad[1]))
            if off < pol.approach_tolerance_m and abs(est.down_m - down) < PAD_HEIGHT_TOLERANCE_M:
                try_n = self.summary.pad_tries - self._tries_before_pad + 1
                self._emit(
                    EventKind.PAD_LOCK,
                    f"pad locked ({why}), {off:.2f} m off it: descent try {try_n} of {pol.descent_tries}",
                )
                self._goto(Phase.LANDING_PAD)
            return sp, None, math.nan
        if inp.time_s - self._phase_t0 < pol.hold_s:
            return sp, None, math.nan
        if pol.search_radius_m > 0.0 and not self._searched:
            self._searched = True
            pts = expanding_square(pol.search_radius_m, pol.search_spacing_m)
            self._search = [(float(pad[0]) + n, float(pad[1]) + e) for n, e in pts]
            self._corner_t0 = None
            self._emit(
                EventKind.PAD_LOCK,
                f"no pad lock after holding {pol.hold_s} s ({why}): searching within {pol.search_radius_m} m of the "
                f"configured pad at {pol.search_height_m} m, {len(pts)} corners at {pol.search_speed_m_s} m/s",
            )
            self._goto(Phase.PAD_SEARCH)
            return sp, None, math.nan
        return self._pad_try_failed(inp, f"no pad lock after holding {pol.hold_s} s: {why}"), None, math.nan

    def _do_pad_search(self, inp: MissionInputs) -> tuple:
        """Step 2: the expanding square at the search height until the pad is locked."""
        est, pol = inp.estimate, self.pad_policy
        if est is None or self.frame is None or pol is None:
            return None, None, math.nan
        down = float(self.frame.pad_ned[2]) - pol.search_height_m
        if not self._search:
            reason = f"search pattern flown within {pol.search_radius_m} m: pad not found"
            return self._pad_try_failed(inp, reason), None, math.nan
        n, e = self._search[0]
        sp = self._pad_setpoint(est, n, e, down, pol.search_speed_m_s)
        req = self._pad_reentry(inp)
        if req is not None or self._reenter:
            return sp, req, math.nan
        ok, why = judge_pad_lock(inp.pad_lock, pol)
        if ok:
            self._emit(EventKind.PAD_LOCK, f"pad found in the search ({why}): flying onto it")
            self._goto(Phase.PAD_HOLD)
            return sp, None, math.nan
        if math.hypot(est.north_m - n, est.east_m - e) < PAD_CORNER_TOLERANCE_M and abs(est.down_m - down) < 1.0:
            if self._corner_t0 is None:
                self._corner_t0 = inp.time_s
            if inp.time_s - self._corner_t0 >= pol.search_dwell_s:
                self._search.pop(0)
                self._corner_t0 = None
        return sp, None, math.nan

    # ------------------------------------------------------------------ divert to the alternate pad
    def _can_divert(self) -> bool:
        pol = self.pad_policy
        return (
            pol is not None
            and pol.fallback == "alternate"
            and self.cfg.alternate_pad is not None
            and self.pad_index == 0
            and self.pad_ned is not None
        )

    def _plan_divert(self, est: StateEstimate, reason: str) -> bool:
        """Plan the path from where the vehicle is (over the first pad's ground) to the alternate pad,
        with the mission's height and arcs, inside the fence both ways; on success the mission's frame,
        path, field and pad are the alternate's (the shell points the landing fusion at it) and its
        tries count from one again. False (said in an event) when it cannot be flown."""
        assert self.cfg.alternate_pad is not None and self.pad_ned is not None
        if self._home_geo is None or self._start_ned is None:
            return False
        alt_ned = np.asarray(self._home_ned, dtype=float) + pad_config_ned(self.cfg.alternate_pad, self._home_geo)
        start = np.array([est.north_m, est.east_m, float(self.pad_ned[2])], dtype=float)
        try:
            frame, path, z_start = plan_leg(self.cfg, start, alt_ned)
            violation = self._fence_violation(start, alt_ned, legs=("outbound",)) or self._fence_violation(
                self._start_ned, alt_ned, legs=("return",)
            )
            if violation:
                raise PathGeometryError(violation)
        except (PathGeometryError, ValueError) as err:
            self._emit(EventKind.PAD_LOCK, f"{reason}: cannot divert to the alternate pad ({err})")
            return False
        self.frame, self.path, self.z_start = frame, path, z_start
        self.field = VectorField(path, self.cfg.sector_speed_m_s, self.cfg.convergence_gain)
        self.pad_ned = np.array(frame.pad_ned, dtype=float)
        self.pad_index = 1
        self.summary.diverted = True
        self._tries_before_pad = self.summary.pad_tries
        self._home_planned = self._return_planned = False  # the way home starts at the alternate
        self._emit(
            EventKind.PAD_LOCK,
            f"{reason}: diverting to the alternate pad, {path.d:.1f} m away at {self.cfg.height_m} m, "
            "to land there under the same policy",
        )
        self._emit(
            EventKind.PHASE,
            f"divert path planned: d = {path.d:.2f} m, h = {path.h} m, r = {path.r} m, "
            f"heading {math.degrees(frame.heading_rad):.1f} deg",
        )
        return True

    def _plan_home_from(self, est: StateEstimate) -> None:
        """After a divert, the way home in the air: from the ground under the vehicle to where the
        outbound started (the divert's path starts at the first pad). No path: hold, then land."""
        self._home_planned = True
        assert self.frame is not None and self._start_ned is not None
        below = np.array([est.north_m, est.east_m, float(self.frame.pad_ned[2])], dtype=float)
        try:
            # the leg flown backwards (s = -1): from home (its start) to the ground under the vehicle
            frame, path, z_start = plan_leg(self.cfg, self._start_ned, below)
            violation = self._fence_violation(below, self._start_ned, legs=("return",))
            if violation:
                raise PathGeometryError(violation)
        except (PathGeometryError, ValueError) as err:
            self.abort(self._now, f"no way home from the alternate pad: {err}")
            return
        self.frame, self.path, self.z_start = frame, path, z_start
        self.field = VectorField(path, self.cfg.sector_speed_m_s, self.cfg.convergence_gain)
        self._emit(EventKind.PHASE, f"return path planned from the divert: d = {path.d:.2f} m")

    def _do_divert(self, inp: MissionInputs) -> tuple:
        """The vector field to the alternate pad; at its approach height the same lock check as the
        outbound's, then the descent, hold, search and tries there."""
        return self._follow(inp, s=1, landing=Phase.LANDING_PAD)

    def _after_touchdown(self, s: int) -> None:
        if s == 1:
            self._left_pad = True  # the next ARM is for the return leg
            self._goto(Phase.RELEASE)
        else:
            self.summary.returned = True
            self.summary.home_with_parcel = not self.summary.delivered
            self.summary.end_time_s = self._now
            self._emit(EventKind.RETURNED, "landed at home")
            self._goto(Phase.DONE)

    def _do_winch(self, inp: MissionInputs) -> tuple:
        """Winch delivery: hold over the pad (on the fused estimate) at the hover height and step the
        winch sequence (delivery.winch). Until the payout starts, the pad-required policy holds as in
        a descent: a lost lock is a failed try (hold, search, tries). Once the line may be out the
        hover holds on the estimate whatever the lock. The sequence's end: fly home."""
        est, wc, seq = inp.estimate, self.winch_cfg, self.winch
        if est is None or self.frame is None or wc is None or seq is None:
            return None, None, math.nan
        dn, de = self._winch_wind.offset_ne_m(inp.time_s, inp.wind)
        hover_n, hover_e = float(self.frame.pad_ned[0]) + dn, float(self.frame.pad_ned[1]) + de
        sp = self._winch_hover_setpoint(est, wc, hover_n, hover_e)
        req = self._pad_reentry(inp)
        if req is not None or self._reenter:
            return sp, req, math.nan
        locked, why = (True, "") if self.pad_policy is None else judge_pad_lock(inp.pad_lock, self.pad_policy)
        if not locked and not seq.paid_out:
            h = self._height_above_ground(est)
            return self._pad_try_failed(inp, f"pad lock lost in the winch hover at {h:.1f} m: {why}"), None, math.nan
        off = math.hypot(est.north_m - hover_n, est.east_m - hover_e)
        down = float(self.frame.pad_ned[2]) - wc.hover_height_m
        ready = (
            locked
            and off < wc.xy_tolerance_m
            and abs(est.down_m - down) < PAD_HEIGHT_TOLERANCE_M
            and math.hypot(est.north_m_s, est.east_m_s) < PAD_HOVER_SPEED_M_S
        )
        tick = seq.step(inp.time_s, ready, inp.winch, self._idle())
        for detail in tick.say:
            self._emit(EventKind.WINCH, detail)
        if tick.command is not None:
            req = self._make_request(RequestKind.WINCH, winch=tick.command)
        elif tick.release:
            req = self._make_request(RequestKind.RELEASE)
        if seq.delivered and not self.summary.delivered:
            self.summary.delivered = True
            self._emit(
                EventKind.DELIVERED,
                "parcel lowered and released on the alternate pad"
                if self.pad_index
                else "parcel lowered and released on the pad",
            )
        if tick.done:
            self._left_pad = True
            if seq.failure and not seq.delivered:
                self.summary.failure = f"parcel not delivered: {seq.failure}"
            self._goto(Phase.INBOUND)
        return sp, req, math.nan

    def _winch_hover_setpoint(
        self, est: StateEstimate, wc: WinchConfig, north_m: float, east_m: float
    ) -> VelocitySetpoint:
        """Towards the hover point (NED north, east; hover_height_m over the pad): horizontally as the
        final descent closes its error (landing_xy_gain_1_s, at most landing_max_xy_speed_m_s),
        vertically at 1/s up to the S5 speed."""
        assert self.frame is not None
        c = self.cfg
        pad = self.frame.pad_ned
        vn = c.landing_xy_gain_1_s * (north_m - est.north_m)
        ve = c.landing_xy_gain_1_s * (east_m - est.east_m)
        vh = math.hypot(vn, ve)
        if vh > c.landing_max_xy_speed_m_s:
            vn, ve = vn * c.landing_max_xy_speed_m_s / vh, ve * c.landing_max_xy_speed_m_s / vh
        vz_max = c.sector_speed_m_s[4]
        vd = min(vz_max, max(-vz_max, PAD_POSITION_GAIN_1_S * (float(pad[2]) - wc.hover_height_m - est.down_m)))
        return VelocitySetpoint(vn, ve, vd, self.frame.yaw_to_ned(0.0))

    def _do_release(self, inp: MissionInputs) -> tuple:
        st = inp.status
        if self._release_error:
            return self._release_failed(inp)
        if self._release_t0 is None:
            if self._idle() and not self._release_requested:  # later tries come from the retry path
                self._release_requested = True
                return None, self._make_request(RequestKind.RELEASE), math.nan
            return None, None, math.nan
        if inp.time_s - self._release_t0 < self.cfg.release_time_s:
            return None, None, math.nan
        if st is not None and not st.payload_released:
            self._release_error = "the payload actuator reports the parcel still attached"
            return self._release_failed(inp)
        if not self.summary.delivered:
            self.summary.delivered = True
            self._emit(
                EventKind.DELIVERED,
                "parcel released on the alternate pad" if self.pad_index else "parcel released on the pad",
            )
        if not self.cfg.return_home:
            self.summary.end_time_s = inp.time_s
            self._goto(Phase.DONE)
            return None, None, math.nan
        self._goto(Phase.ARMING)
        return None, self._make_request(RequestKind.ARM), math.nan

    def _release_failed(self, inp: MissionInputs) -> tuple:
        """The autopilot refused or failed the release (or never answered): the parcel is still
        attached. Say so once, then fly home with it or stay on the pad (mission.on_release_failure)."""
        reason, self._release_error = self._release_error, ""
        self.summary.failure = f"parcel not released: {reason}"
        stay = self.cfg.on_release_failure == "stay" or not self.cfg.return_home
        self._emit(
            EventKind.WARNING,
            f"parcel not released ({reason}); "
            + ("staying disarmed on the pad" if stay else "flying home with the parcel"),
        )
        if stay:
            self.summary.end_time_s = inp.time_s
            self._goto(Phase.FAILED)
            return None, None, math.nan
        self._goto(Phase.ARMING)
        return None, self._make_request(RequestKind.ARM), math.nan

    def _do_abort_hold(self, inp: MissionInputs) -> tuple:
        if not self._abort_hold_requested:
            if self._idle():
                self._abort_hold_requested = True
                self._expect_mode_change = True
                return None, self._make_request(RequestKind.HOLD), math.nan
            return None, None, math.nan
        if not self._hold_forever and inp.time_s - self._phase_t0 >= self.cfg.abort_hold_s and self._idle():
            self._goto(Phase.ABORT_LAND)
            self._land_requested = True
            return None, self._make_request(RequestKind.LAND), math.nan
        return None, None, math.nan

    def _do_abort_land(self, inp: MissionInputs) -> tuple:
        if not self._land_requested and self._idle():
            self._land_requested = True
            self._expect_mode_change = True
            return None, self._make_request(RequestKind.LAND), math.nan
        st = inp.status
        if st is not None and st.landed is LandedState.ON_GROUND:
            if not st.armed:
                self.summary.failure = f"aborted: {self._abort_reason}"
                self.summary.end_time_s = inp.time_s
                self._goto(Phase.FAILED)
            else:
                # as after a landing on the pad: waiting for the autopilot's own disarm would wait
                # forever where it is turned off (PX4 COM_DISARM_LAND < 0, ArduPilot DISARM_DELAY = 0)
                return None, self._ask_to_disarm(inp), math.nan
        return None, None, math.nan

    def _ask_to_disarm(self, inp: MissionInputs) -> Request | None:
        """On the ground and still armed: the DISARM request, at once and again only every
        DISARM_REPEAT_S while the status shows armed (the autopilot usually disarms by itself)."""
        if not self._idle() or inp.time_s < self._disarm_not_before:
            return None
        self._disarm_not_before = inp.time_s + DISARM_REPEAT_S
        return self._make_request(RequestKind.DISARM)

    # ------------------------------------------------------------------ helpers
    _abort_hold_requested = False
    _takeoff_requested = False
    _touched_down = False
    _started = False
    _hold_forever = False
    _land_requested = False
    _reenter = False
    _link_restored_at = -math.inf
    _restore_undecided = False  # the link is back, no status from after the loss yet
    _status_t_at_loss = -math.inf  # the time of the last status before the link was lost
    _retry_tries = 2
    _touchdown_land_requested = False
    _landing_int: tuple[float, float] = (0.0, 0.0)
    _landing_int_t: float | None = None
    _settle_since: float | None = None  # the error within the tolerance since (landing_settle_s)
    _settle_released = False
    _disarm_not_before = -math.inf
    _left_pad = False
    _release_requested = False
    _release_error = ""
    _searched = False  # the search was flown in this try
    pad_index = 0  # the pad landed on: 0 mission.pad, 1 mission.alternate_pad (after a divert)
    _tries_before_pad = 0  # summary.pad_tries when the current pad's tries began
    _home_planned = False  # after a divert: the way home has been planned
    _divert_after_takeoff = ""  # touchdown without lock on the first pad: divert once airborne (the reason)
    _divert_takeoff = False  # that take-off flies the divert's field

    def _way_home(self) -> WayHome:
        return way_home(self.cfg)

    def _battery_round_trip(self, battery_pct: float) -> str:
        """Before take-off, with a configured use: why the charge cannot cover out and back ("" if it can)."""
        assert self.battery is not None and self.path is not None
        return round_trip_problem(self.battery, self._way_home(), self.path.d, battery_pct)

    def _check_battery(self, inp: MissionInputs) -> None:
        """Abandon the delivery and fly home once the charge left covers no more than the way home
        plus the reserve (outbound and on the pad descent, with the parcel)."""
        st, est = inp.status, inp.estimate
        assert self.battery is not None
        if st is None:
            return
        self.battery.update(inp.time_s, st.battery_pct, st.landed is LandedState.IN_AIR)
        if (
            self.phase not in (Phase.OUTBOUND, Phase.LANDING_PAD, Phase.DIVERT)
            or est is None
            or self._start_ned is None
        ):
            return
        p = np.asarray(est.position_ned, dtype=float)
        dist = math.hypot(p[0] - self._start_ned[0], p[1] - self._start_ned[1])
        height = self._home_ned[2] - float(p[2])
        v = self.battery.verdict(st.battery_pct, time_home_s(self._way_home(), dist, height))
        if v is None or not v.go_home:
            return
        self._emit(EventKind.GO_NO_GO, f"abandoning the delivery, flying home: {v.reason()}")
        self.summary.failure = f"returned without delivering: {v.reason()}"
        self._goto(Phase.INBOUND)

    def _fence_violation(
        self, start_ned: np.ndarray, pad_ned: np.ndarray, legs: tuple[str, ...] = ("outbound", "return")
    ) -> str:
        """Why the legs between ``start_ned`` (home) and ``pad_ned`` leave the fence or the
        setpoint clamp ("" when they stay inside)."""
        if self.limits is None or self._home_geo is None:
            return ""
        if self.fence_cfg is not None and self._fence_ned is None:
            self._fence_ned = fence_in_ned(self.fence_cfg, self._home_geo, self._home_ned)
        return legs_problem(
            self._fence_ned, self.limits, self._home_geo, self._home_ned, start_ned, pad_ned, self.cfg, legs
        )

    def _idle(self) -> bool:
        """No request in flight and none waiting for its retry: a phase may issue a new one."""
        return self._pending is None and self._retry is None

    def _on_request_ok(self, req: Request) -> None:
        k = req.kind
        if k is RequestKind.ARM:
            self._emit(EventKind.ARMED, "")
            if self.summary.takeoff_time_s is None:
                self.summary.takeoff_time_s = self._now
            self._goto(Phase.TAKEOFF_RETURN if self._left_pad else Phase.TAKEOFF)
        elif k is RequestKind.RELEASE:
            self._release_t0 = self._now
            self._emit(EventKind.RELEASED, "release commanded")
        elif k is RequestKind.START_OFFBOARD:
            pass  # the phase changes once the status shows OFFBOARD
        elif k is RequestKind.DISARM:
            pass  # the landing phase sees disarmed and moves on

    def _make_request(
        self, kind: RequestKind, alt: float = 0.0, tries: int = 1, winch: WinchCommand | None = None
    ) -> Request:
        if kind is RequestKind.TAKEOFF:
            alt = self.cfg.takeoff_alt_m
        req = Request(self._next_id, kind, alt, winch)
        self._next_id += 1
        self._pending = _Pending(req, tries)
        return req

    def _goto(self, phase: Phase) -> None:
        if phase is Phase.LANDING_PAD and self.winch_cfg is not None:
            phase = Phase.WINCH  # a winch delivery never lands on the pad: it hovers over it
            self.winch = WinchSequence(self.winch_cfg, self.cfg.release_time_s)
            self._winch_wind = WindCorrection(self.winch_cfg)
        if phase is self.phase:
            return
        log.info("mission phase %s -> %s", self.phase.value, phase.value)
        self.phase = phase
        self._phase_t0 = self._now
        self._stream_t0 = None
        self._offboard_requested = False
        self._abort_hold_requested = False
        self._takeoff_requested = False
        self._takeoff_ground_down_m = None
        self._touched_down = False
        self._reenter = False
        self._release_t0 = None if phase is not Phase.RELEASE else self._release_t0
        self._precland_requested = False
        self._touchdown_land_requested = False
        self._disarm_not_before = -math.inf
        self._landing_int = (0.0, 0.0)  # the final descent's integral term starts again
        self._lock_reopened_at = None
        self._landing_int_t = None
        self._settle_since = None
        self._settle_released = False
        self._release_requested = False
        self._retry = None  # a retry belongs to the phase that asked
        if phase in (Phase.OUTBOUND, Phase.INBOUND):
            self._expect_mode_change = False
        self._emit(EventKind.PHASE, phase.value)

    def _emit(self, kind: EventKind, detail: str) -> None:
        ev = MissionEvent(self._now, kind, self.phase, detail)
        self._events.append(ev)
        self.summary.events.append(ev)

    def _out(self, sp: VelocitySetpoint | None, req: Request | None, lyap: float) -> MissionOutput:
        # events raised between ticks (abort, request results) go out with this tick's output
        events, self._events = tuple(self._events), []
        return MissionOutput(self.phase, sp, req, events, self._sector, lyap)

    def _on_ground_phase(self) -> bool:
        return self.phase in (Phase.PREFLIGHT, Phase.ARMING, Phase.RELEASE)

    def _height_above_ground(self, est: StateEstimate) -> float:
        """Height above the ground under the vehicle: the pad's level near the pad (s = +1
        landing), home's level elsewhere; both from the configured geometry."""
        assert self.frame is not None
        z_i = float(self.frame.point_from_ned(est.position_ned)[2])
        if self.path is not None and self._sector_of(est) == 1:
            return z_i - self.z_start
        return z_i

    def _sector_of(self, est: StateEstimate) -> int:
        assert self.frame is not None and self.path is not None
        return self.path.sector(self.frame.point_from_ned(est.position_ned))

    def _field_setpoint(
        self, est: StateEstimate, s: int, speed_scale: float = 1.0, force_descent: bool = False
    ) -> tuple[VelocitySetpoint, float]:
        assert self.frame is not None and self.field is not None and self.path is not None
        p_i = self.frame.point_from_ned(est.position_ned)
        s_dir = s if not force_descent else (1 if self._sector_of(est) == 5 else -1)
        c = self.cfg
        if c.autopilot_accel_xy_m_s2 > 0.0 or c.autopilot_accel_z_m_s2 > 0.0:
            # not in the paper: keep v_r within the autopilot's acceleration limits (speed_schedule)
            speed_scale *= schedule_speed(
                self.path,
                float(p_i[0]),
                float(p_i[2]),
                self.path.sector(p_i),
                s_dir,
                tuple(c.sector_speed_m_s),
                c.autopilot_accel_xy_m_s2,
                c.autopilot_accel_z_m_s2,
                c.land_speed_m_s,
                (c.final_descent_alt_m, self.z_start + c.final_descent_alt_m),
            )
        la = self.cfg.field_lookahead_s
        if la > 0.0:
            # Not in the paper: the autopilot's velocity loop lags the setpoint by about 1/k_v
            # (0.5 s on PX4 and ArduCopter), so at an arc the vehicle follows the field of where
            # it was and overshoots by v * lag (1.8 m at r = 2 m and 3 m/s). Evaluating F at
            # the position predicted one lag ahead (still a function of the state, not of time)
            # turns the vehicle in time; V is still reported at the current position.
            p_ahead = np.asarray(est.position_ned) + la * np.array([est.north_m_s, est.east_m_s, est.down_m_s])
            fs = self.field(self.frame.point_from_ned(p_ahead), s_dir, speed_scale)
            lyap = self.path.lyapunov(p_i)
        else:
            fs = self.field(p_i, s_dir, speed_scale)  # delivery eq 19
            lyap = fs.lyapunov
        self.speed_ref_m_s = fs.speed_ref_m_s
        self.sense = s_dir
        if fs.sector != self._sector:
            self._sector = fs.sector
            self._emit(EventKind.SECTOR, f"S{fs.sector}")
        v_ned = self.frame.vector_to_ned(fs.velocity)
        yaw = self.frame.yaw_to_ned(0.0)  # psi_r = 0 in F_I (delivery 4.3)
        return VelocitySetpoint(float(v_ned[0]), float(v_ned[1]), float(v_ned[2]), yaw), lyap

    def _align_with_pad(self, inp: MissionInputs, sp: VelocitySetpoint | None) -> VelocitySetpoint | None:
        """A pad with a heading: at the approach height (hold, search) and in the final descent
        onto it, the yaw setpoint turns from where it was to the pad's heading the shortest way,
        at most limits.max_yaw_rate_deg_s, so the vehicle touches down aligned (docs/pad-heading.md).
        Elsewhere the path's heading (delivery 4.3) is kept.

        Once turned, below landing_hold_min_height_m with the pad's heading out of sight (no
        camera observation within PAD_DATA_FRESH_S: the camera too close), the setpoint is the
        autopilot's own yaw: its yaw estimate drifts against the truth, and a held setpoint (or
        the fusion's yaw, which converges on the autopilot's once blind) would turn the vehicle
        by that drift, in the last metre and on the ground until the land detector fires (PX4 SIH)."""
        target = inp.pad_heading_rad
        if sp is None or target is None or self.phase not in (Phase.LANDING_PAD, Phase.PAD_HOLD, Phase.PAD_SEARCH):
            self._yaw_sp = (inp.time_s, sp.yaw_rad) if sp is not None else None
            return sp
        rate = math.radians(self.limits.max_yaw_rate_deg_s if self.limits is not None else 60.0)
        prev = self._yaw_sp
        est, ap_yaw = inp.estimate, inp.autopilot_yaw_rad
        if (
            self.phase is Phase.LANDING_PAD
            and est is not None
            and ap_yaw is not None
            and math.isfinite(ap_yaw)
            and self.frame is not None
            and prev is not None
            and abs(heading_difference_rad(prev[1], target)) <= ALIGNED_RAD
            and inp.pad_heading_age_s > PAD_DATA_FRESH_S
            and self._height_above_ground(est) < self.cfg.landing_hold_min_height_m
        ):
            self._yaw_sp = (inp.time_s, target)  # still turned: the test above holds on the next tick
            return replace(sp, yaw_rad=wrap_angle(ap_yaw))
        if prev is None:
            est = inp.estimate
            start = est.yaw_rad if est is not None else sp.yaw_rad
            step = 0.0
        else:
            start = prev[1]
            step = rate * min(max(inp.time_s - prev[0], 0.0), 1.0)
        yaw = yaw_toward(start, target, step)
        self._yaw_sp = (inp.time_s, yaw)
        return replace(sp, yaw_rad=yaw)

    def _check_link(self, inp: MissionInputs) -> bool:
        st = inp.status
        if not inp.link_ok:
            if not self._link_lost:
                self._link_lost = True
                self._link_lost_mode = st.mode if st is not None else None
                self._status_t_at_loss = st.time_s if st is not None else -math.inf
                self._emit(EventKind.LINK_LOST, "no heartbeat: stopped commanding, autopilot failsafe acts")
            return False
        if self._link_lost:
            self._link_lost = False
            self._link_restored_at = inp.time_s
            self._restore_undecided = True
            self._emit(EventKind.LINK_RESTORED, "resuming from where the vehicle is")
        if self._restore_undecided:
            # The autopilot's offboard-loss failsafe will have switched to its failsafe mode (HOLD;
            # POSCTL on PX4 v1.16 with COM_OBL_RC_ACT = 0): that is not the pilot, so
            # re-enter offboard and let the (path-based) field resume. Decided on a status the
            # autopilot sent after the link came back: the link can return (a heartbeat) before
            # the mode does, and the last status from before the loss still says OFFBOARD.
            if st is None or st.time_s <= self._status_t_at_loss:
                return True
            self._restore_undecided = False
            if (
                self.phase in FOLLOW_PHASES
                and st.mode is not FlightMode.OFFBOARD
                and st.mode.value in self.cfg.link_loss_resume_modes
            ):
                self._reenter = True
                self._expect_mode_change = True
                self._offboard_requested = False
                self._stream_t0 = None
        return True

    def _check_pilot(self, inp: MissionInputs) -> None:
        st = inp.status
        if st is None or self._expect_mode_change or self._pending is not None or self._restore_undecided:
            return
        if st.mode is not FlightMode.OFFBOARD and st.armed:
            self._emit(EventKind.PILOT_TAKEOVER, f"mode switched to {st.mode.value}: autonomy ended")
            self.summary.failure = f"pilot took over ({st.mode.value})"
            self.summary.end_time_s = inp.time_s
            self._goto(Phase.PILOT)

    def _check_estimate(self, inp: MissionInputs) -> None:
        est = inp.estimate
        if est is None:
            return
        if inp.time_s - self._link_restored_at < self.cfg.estimate_timeout_s:
            return  # fresh telemetry is still arriving after a reconnect
        age = inp.time_s - est.time_s
        if age > self.cfg.estimate_timeout_s:
            self.abort(inp.time_s, f"state estimate is {age:.2f} s old (limit {self.cfg.estimate_timeout_s} s)")

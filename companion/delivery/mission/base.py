"""What every part of the delivery mission shares: the phase and its state, the route flown,
the requests, the events and the summary, and the moves every part makes (go to a phase, emit an
event, ask the autopilot, abort). The parts (phases, padpolicy, routes, winch_phase, commands) see
the mission as a :class:`MissionBase`; ``core.DeliveryMission`` wires them together."""

from __future__ import annotations

import logging
import math
from typing import Protocol, TypeVar

import numpy as np

from companion.autopilot.types import HomePosition, RangefinderReading
from companion.autopilot.winch import WinchCommand
from companion.config import (
    FenceConfig,
    GoNoGoConfig,
    LimitsConfig,
    MissionConfig,
    PadLockPolicyConfig,
    WinchConfig,
)
from companion.delivery.gonogo import BatteryMonitor, WindMonitor, round_trip_problem, way_home
from companion.delivery.mission.linkwatch import LinkWatch
from companion.delivery.mission.requests import RequestBook
from companion.delivery.mission.states import (
    AbortHoldState,
    LandingState,
    PhaseState,
    state_for,
)
from companion.delivery.mission.types import (
    FailureKind,
    Leg,
    MissionInputs,
    MissionSummary,
    Request,
    RequestKind,
    Step,
)
from companion.delivery.mission.yaw import PadYawAlignment
from companion.delivery.padlock import PadLock
from companion.delivery.winch import WinchSequence, WindCorrection
from companion.estimation.rangefinder import RangefinderGate
from companion.estimation.types import StateEstimate
from companion.events import EventKind, MissionEvent, Phase
from companion.geometry.earth import GeoPoint
from companion.geometry.mission_frame import MissionFrame
from companion.guidance.path import DeliveryPath
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
    Phase.DROP_ZONE_HOLD,
)
ON_GROUND_PHASES = (Phase.PREFLIGHT, Phase.ARMING, Phase.RELEASE)
DELIVERY_LEG_PHASES = (
    Phase.OUTBOUND,
    Phase.LANDING_PAD,
    Phase.DIVERT,
    Phase.DROP_ZONE_HOLD,
)  # with the parcel, towards a pad

S = TypeVar("S", bound=PhaseState)


class Routes(Protocol):
    """The legs planned in flight (routes.RoutePlanner)."""

    start_ned: np.ndarray | None
    home_geo: GeoPoint | None
    home_ned: tuple[float, float, float]
    return_planned: bool
    home_planned: bool

    def plan_delivery(self, home: HomePosition, est: StateEstimate) -> bool: ...
    def plan_return(self, est: StateEstimate) -> None: ...
    def plan_home_from(self, est: StateEstimate) -> None: ...
    def plan_divert(self, est: StateEstimate, reason: str) -> bool: ...


class Pads(Protocol):
    """The no-release-off-the-pad policy (padpolicy.PadPolicy)."""

    divert_after_takeoff: str
    divert_takeoff: bool

    def judge(self, lock: PadLock | None) -> tuple[bool, str]: ...
    def lock_reopening(self, st: LandingState, lock: PadLock | None, time_s: float) -> bool: ...
    def try_failed(self, inp: MissionInputs, reason: str) -> VelocitySetpoint | None: ...
    def home_with_parcel(self, reason: str) -> Request | None: ...
    def plan_divert(self, est: StateEstimate, reason: str) -> bool: ...
    def hold(self, inp: MissionInputs) -> Step: ...
    def search(self, inp: MissionInputs) -> Step: ...
    def fallback(self, reason: str, est: StateEstimate | None) -> None: ...
    def setpoint_to(
        self, est: StateEstimate, north_m: float, east_m: float, down_m: float, speed_m_s: float
    ) -> VelocitySetpoint: ...


class DropZones(Protocol):
    """Never release onto an occupied pad (dropzone.DropZonePolicy)."""

    def blocked(self, inp: MissionInputs) -> bool: ...
    def may_start_descent(self, inp: MissionInputs) -> bool: ...
    def stop(self, inp: MissionInputs, where: str) -> None: ...
    def hold(self, inp: MissionInputs) -> Step: ...


class MissionBase:
    routes: Routes
    pads: Pads
    drop_zones: DropZones

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
        self.state: PhaseState = state_for(Phase.PREFLIGHT, 0.0, cfg)
        # the route flown now (replaced by a replan: the way home, a divert)
        self.frame: MissionFrame | None = None
        self.path: DeliveryPath | None = None
        self.field: VectorField | None = None
        self.z_start = 0.0
        self.pad_ned: np.ndarray | None = None  # the pad of this delivery (NED), once planned
        self.pad_index = 0  # the pad landed on: 0 mission.pad, 1 mission.alternate_pad (after a divert)
        self.speed_ref_m_s: float | None = None  # v_r of the last field evaluation (this tick), else None
        self.sense = 0  # s of that evaluation (+1 towards the pad, -1 home), else 0
        self.sector = 0  # the path sector of the last field evaluation
        self.summary = MissionSummary()
        self.requests = RequestBook()
        self.link = LinkWatch(cfg.link_loss_resume_modes)
        self.limits = limits
        self.fence_cfg = fence if fence is not None and fence.enabled else None
        self.pad_policy = pad_policy if pad_policy is not None and pad_policy.require_pad_lock else None
        # the final descent's height from the autopilot's rangefinder ([mission.rangefinder]); None: off
        self.rangefinder = RangefinderGate(cfg.rangefinder) if cfg.rangefinder.enabled else None
        rate = math.radians(limits.max_yaw_rate_deg_s if limits is not None else 60.0)
        self.yaw = PadYawAlignment(rate, cfg.descent.hold_min_height_m)
        self.expect_mode_change = False  # a mode change we asked for is under way: not the pilot
        self.left_pad = False  # the next ARM is for the way home (or a divert)
        self._started = False
        # since when the companion may not have been in control (a stall of its own, a link loss):
        # what the vehicle did from then on was not on its commands, until a status from after it
        # shows the vehicle in the air in OFFBOARD again; None: in control
        self.control_lost_s: float | None = None
        self._abort_reason = ""
        self._abort_kind = FailureKind.ABORTED
        self._events: list[MissionEvent] = []
        self.now = 0.0
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
        self.winch_wind = WindCorrection(self.winch_cfg or WinchConfig())

    # ------------------------------------------------------------------ public API
    def abort(self, time_s: float, reason: str, kind: FailureKind = FailureKind.ABORTED) -> None:
        """Hold position, then land (an abort is never a mid-air disarm). ``kind``: what the
        summary's failure will say it was (OPERATOR_ABORT for the operator's signal)."""
        st = self.state
        if isinstance(st, AbortHoldState) and st.forever:
            st.forever = False  # an abort during a commanded hold: land after abort_hold_s
            st.t0 = time_s
            self.emit(EventKind.ABORT, reason)
            return
        if self.phase.terminal or self.phase in (Phase.ABORT_HOLD, Phase.ABORT_LAND):
            return
        self.now = time_s
        self._abort_reason = reason
        self._abort_kind = kind
        self.emit(EventKind.ABORT, reason)
        if self.on_ground():
            self.summary.fail(kind, f"aborted on the ground: {reason}")
            self.goto(Phase.FAILED)
        else:
            self.goto(Phase.ABORT_HOLD)

    def refuse(self, time_s: float, reason: str) -> None:
        """Refuse the delivery before take-off (a go/no-go check failed): nothing is armed."""
        if not self.on_ground() or self.left_pad or self.phase.terminal:
            return
        self.now = time_s
        self.summary.fail(FailureKind.REFUSED, f"refused before take-off: {reason}")
        self.emit(EventKind.GO_NO_GO, self.summary.failure)
        self.goto(Phase.FAILED)

    def go_no_go(self, time_s: float, detail: str) -> None:
        """Report a go/no-go check's verdict that changes nothing (e.g. the fence verified)."""
        self.now = time_s
        self.emit(EventKind.GO_NO_GO, detail)

    def waiting_for(self) -> str:
        """The request the mission waits on, if any (for a mission that ends without finishing)."""
        return self.requests.waiting_for()

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

    # ------------------------------------------------------------------ shared by the parts
    def goto(self, phase: Phase) -> None:
        if phase is Phase.LANDING_PAD and self.winch_cfg is not None:
            phase = Phase.WINCH  # a winch delivery never lands on the pad: it hovers over it
            self.winch = WinchSequence(self.winch_cfg, self.cfg.release_time_s)
            self.winch_wind = WindCorrection(self.winch_cfg)
        if phase is self.phase:
            return
        log.info("mission phase %s -> %s", self.phase.value, phase.value)
        self.phase = phase
        self.state = state_for(phase, self.now, self.cfg)
        self.requests.retry = None  # a retry belongs to the phase that asked
        if phase in (Phase.OUTBOUND, Phase.INBOUND):
            self.expect_mode_change = False
        self.emit(EventKind.PHASE, phase.value)

    def state_as(self, kind: type[S]) -> S:
        st = self.state
        assert isinstance(st, kind), f"phase {self.phase.value} has {type(st).__name__}, not {kind.__name__}"
        return st

    def emit(self, kind: EventKind, detail: str) -> None:
        ev = MissionEvent(self.now, kind, self.phase, detail)
        self._events.append(ev)
        self.summary.events.append(ev)

    def idle(self) -> bool:
        """No request in flight and none waiting for its retry: a phase may issue a new one."""
        return self.requests.idle()

    def make_request(
        self, kind: RequestKind, alt: float = 0.0, tries: int = 1, winch: WinchCommand | None = None
    ) -> Request:
        if kind is RequestKind.TAKEOFF:
            alt = self.cfg.takeoff_alt_m
        return self.requests.make(kind, alt, tries, winch)

    def on_ground(self) -> bool:
        return self.phase in ON_GROUND_PHASES

    def set_route(self, frame: MissionFrame, path: DeliveryPath, z_start: float) -> None:
        self.frame, self.path, self.z_start = frame, path, z_start
        self.field = VectorField(path, self.cfg.sector_speed_m_s, self.cfg.convergence_gain)

    def height_above_ground(self, est: StateEstimate | None) -> float:
        """Height above the ground under the vehicle: the pad's level near the pad (s = +1
        landing), home's level elsewhere; both from the configured geometry."""
        assert self.frame is not None and est is not None
        z_i = float(self.frame.point_from_ned(est.position_ned)[2])
        if self.path is not None and self.sector_of(est) == 1:
            return z_i - self.z_start
        return z_i

    def descent_height(self, est: StateEstimate, reading: RangefinderReading | None, time_s: float) -> float:
        """The final descent's height above the ground: the rangefinder's (tilt-corrected) where
        its gate passes, else the estimate's corrected by the last reading used within hold_s, else
        the estimate's. GPS only, PX4 SIH's height estimate drifted 0.3-1.7 m in one 20 s flight,
        and the contact and the sideways command's end were judged on it (docs/rangefinder.md)."""
        h = self.height_above_ground(est)
        if self.rangefinder is None:
            return h
        return self.rangefinder.height(reading, time_s, h, est.roll_rad, est.pitch_rad)

    def sector_of(self, est: StateEstimate) -> int:
        assert self.frame is not None and self.path is not None
        return self.path.sector(self.frame.point_from_ned(est.position_ned))

    def field_setpoint(
        self, est: StateEstimate, leg: Leg, speed_scale: float = 1.0, force_descent: bool = False
    ) -> tuple[VelocitySetpoint, float]:
        """The vector field's velocity at the estimate (delivery eq 19) along ``leg``, and V there."""
        assert self.frame is not None and self.field is not None and self.path is not None
        p_i = self.frame.point_from_ned(est.position_ned)
        s_dir = int(leg) if not force_descent else (1 if self.sector_of(est) == 5 else -1)
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
        if fs.sector != self.sector:
            self.sector = fs.sector
            self.emit(EventKind.SECTOR, f"S{fs.sector}")
        v_ned = self.frame.vector_to_ned(fs.velocity)
        yaw = self.frame.yaw_to_ned(0.0)  # psi_r = 0 in F_I (delivery 4.3)
        return VelocitySetpoint(float(v_ned[0]), float(v_ned[1]), float(v_ned[2]), yaw), lyap

    @property
    def start_ned(self) -> np.ndarray | None:
        """Where the outbound started (home, on the ground), once planned."""
        return self.routes.start_ned

    def battery_round_trip_problem(self, battery_pct: float) -> str:
        """Before take-off, with a configured use: why the charge cannot cover out and back ("" if it can)."""
        assert self.battery is not None and self.path is not None
        return round_trip_problem(self.battery, way_home(self.cfg), self.path.d, battery_pct)

    def abort_summary(self, detail: str) -> None:
        """The failure an abort ends with, of the kind the abort was asked with."""
        self.summary.fail(self._abort_kind, detail)

    @property
    def abort_reason(self) -> str:
        return self._abort_reason

    def set_abort_reason(self, reason: str) -> None:
        self._abort_reason = reason
        self._abort_kind = FailureKind.ABORTED

"""The delivery mission state machine (delivery Algorithm 1, made complete): the step, the phase
table and what every phase shares (the route, the requests, the events, the summary).

Pure and synchronous: :meth:`DeliveryMission.step` takes timestamped inputs and returns what
to do (a velocity setpoint, at most one autopilot request, events). The asyncio shell executes
requests and feeds their results back with :meth:`DeliveryMission.on_result`. The parts of the
mission are in this package: ``phases`` (a handler per phase), ``states`` (a state per phase),
``requests``, ``linkwatch``, ``padpolicy`` (lock, hold, search, tries, divert), ``routes`` (the
legs planned in flight), ``winch_phase`` and ``yaw``; the final descent's controller is
:mod:`companion.guidance.descent`.
"""

from __future__ import annotations

import dataclasses
import logging
import math

import numpy as np

from companion.autopilot.types import FlightMode, LandedState
from companion.config import (
    DropZoneConfig,
    FenceConfig,
    GoNoGoConfig,
    LimitsConfig,
    MissionConfig,
    MovingPadConfig,
    PadLockPolicyConfig,
    WinchConfig,
)
from companion.delivery.gonogo import time_home_s, way_home
from companion.delivery.mission.base import DELIVERY_LEG_PHASES, FOLLOW_PHASES, MissionBase
from companion.delivery.mission.commands import CommandReply, ground_command
from companion.delivery.mission.dropzone import DropZonePolicy
from companion.delivery.mission.linkwatch import LinkCheck
from companion.delivery.mission.moving_pad import TRACKED_PHASES, pad_feedforward, too_fast, with_pad_velocity
from companion.delivery.mission.padpolicy import PadPolicy
from companion.delivery.mission.phases import HANDLERS
from companion.delivery.mission.requests import MAX_REQUEST_TRIES
from companion.delivery.mission.routes import RoutePlanner
from companion.delivery.mission.states import (
    LandingState,
    PhaseState,
    ReleaseState,
)
from companion.delivery.mission.types import (
    FailureKind,
    MissionInputs,
    MissionOutput,
    Request,
    RequestKind,
    RequestResult,
    Step,
)
from companion.events import CommandKind, EventKind, Phase
from companion.guidance.setpoint import VelocitySetpoint

log = logging.getLogger(__name__)

# after a stall or a link loss: how long the vehicle must be seen flying in OFFBOARD before the
# companion counts itself in control again (longer than the link's buffered backlog takes to drain)
CONTROL_REGAINED_S = 1.0
# a stall of its own longer than this (PX4's COM_OF_LOSS_T default; ArduCopter's GUID_TIMEOUT is
# longer) gave the autopilot's failsafe time to act: PX4 hands OFFBOARD back when the setpoints
# resume, even to a vehicle its LAND has already brought down, so control is not regained
STALL_FORFEITS_CONTROL_S = 1.0


class DeliveryMission(MissionBase):
    def __init__(
        self,
        cfg: MissionConfig,
        landing_controller: str = "companion",
        pad_policy: PadLockPolicyConfig | None = None,
        fence: FenceConfig | None = None,
        limits: LimitsConfig | None = None,
        go_no_go: GoNoGoConfig | None = None,
        winch: WinchConfig | None = None,
        stall_s: float = math.inf,
        drop_zone: DropZoneConfig | None = None,
        moving_pad: MovingPadConfig | None = None,
    ):
        """The parts of the mission (MissionBase has the rest). ``stall_s``: a gap between two
        steps longer than this is a stall of the companion (runtime.loop_stall_s: its watchdog
        stopped the heartbeats and setpoints, so the autopilot's failsafe may have acted).
        ``drop_zone`` (enabled): never release onto an occupied pad (dropzone.DropZonePolicy).
        ``moving_pad`` (enabled): the setpoints relative to the pad carry its estimated velocity,
        and a pad faster than its max_speed_m_s is not landed on (mission.moving_pad)."""
        super().__init__(cfg, landing_controller, pad_policy, fence, limits, go_no_go, winch)
        self.stall_s = stall_s
        self._last_step_s: float | None = None
        self._regaining_s: float | None = None  # flying in OFFBOARD since, after a loss of control
        self._control_forfeit = False  # a long stall: out of control for the rest of the mission
        self.routes = RoutePlanner(self, self.fence_cfg, limits)
        self.pads = PadPolicy(self, self.pad_policy)
        self.drop_zones = DropZonePolicy(self, drop_zone)
        self.moving_pad = moving_pad if moving_pad is not None and moving_pad.enabled else None

    def command(self, time_s: float, kind: CommandKind, sender: str = "ground") -> CommandReply:
        """A ground command (hold, return, land, abort). The mission decides; the safety contract
        (clamps, pilot priority) is untouched because every setpoint still goes through the shell.
        Returns what was done, for the reply and the log."""
        return ground_command(self, time_s, kind, sender)

    def on_result(self, result: RequestResult) -> None:
        p = self.requests.take(result)
        if p is None:
            return
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
                self.emit(EventKind.REQUEST_FAILED, f"{p.request.kind.value}: {result.error}")
            elif p.request.kind is RequestKind.RELEASE:
                self.emit(EventKind.RELEASED, "release commanded over the pad (winch)")
            self.winch.on_result(self.now, result.ok, result.error)
            return
        if result.ok:
            self._on_request_ok(p.request)
            return
        self.emit(
            EventKind.REQUEST_FAILED,
            f"{p.request.kind.value} (try {p.tries} of {MAX_REQUEST_TRIES}"
            + (", not retried: the autopilot will answer the same" if result.permanent else "")
            + f"): {result.error}",
        )
        if not self.requests.final(p, result):
            # the one retry path: phase handlers issue nothing while a retry is scheduled
            self.requests.schedule_retry(p, self.now)
            return
        reason = (
            f"{p.request.kind.value} refused: {result.error}"
            if result.permanent
            else f"{p.request.kind.value} failed {p.tries} times: {result.error}"
        )
        kind, st = p.request.kind, self.state
        if kind is RequestKind.RELEASE and isinstance(st, ReleaseState):
            st.error = reason
        elif kind in (RequestKind.HOLD, RequestKind.LAND) and self.phase in (Phase.ABORT_HOLD, Phase.ABORT_LAND):
            self.summary.fail(FailureKind.ABORT_FAILED, reason)
            self.goto(Phase.FAILED)
        elif kind is RequestKind.DISARM and self.phase is Phase.ABORT_LAND:
            # on the ground after an abort: say it and end, rather than ask again for ever
            self.summary.fail(
                FailureKind.LANDED_ARMED, f"aborted: {self._abort_reason}; landed but still armed ({reason})"
            )
            self.summary.end_time_s = self.now
            self.goto(Phase.FAILED)
        else:
            self.abort(self.now, reason)

    def step(self, inp: MissionInputs) -> MissionOutput:
        if not self._started:
            self._started = True
            self.state.t0 = inp.time_s  # timeouts count from the first tick, on the caller's clock
        self.now = inp.time_s
        # what the field is evaluated with this tick (telemetry): absent outside the vector field
        self.speed_ref_m_s = None
        self.sense = 0
        self._check_stall(inp.time_s)

        if not self._check_link(inp):
            return self._out(None, None, math.nan)
        self._check_control(inp)
        if self.phase in FOLLOW_PHASES or self.phase in (Phase.TAKEOFF, Phase.TAKEOFF_RETURN):
            self._check_estimate(inp)
        if self.phase in FOLLOW_PHASES:
            self._check_pilot(inp)
        if self.battery is not None:
            self._check_battery(inp)
        if self.wind is not None and self.phase in DELIVERY_LEG_PHASES:
            why = self.wind.update(inp.time_s, inp.wind)
            if why:
                self.emit(EventKind.GO_NO_GO, f"abandoning the delivery, flying home: {why}")
                self.summary.fail(FailureKind.RETURNED_GO_NO_GO, f"returned without delivering: {why}")
                self.goto(Phase.INBOUND)

        if self.moving_pad is not None and self.phase in TRACKED_PHASES:
            why = too_fast(inp.pad_velocity_ne, self.moving_pad.max_speed_m_s)
            if why:  # nothing is released on it: the parcel goes home
                self.emit(EventKind.PAD_LOCK, f"not landing on the pad, flying home with the parcel: {why}")
                self.summary.fail(FailureKind.NOT_DELIVERED, f"parcel not delivered: {why}")
                self.goto(Phase.INBOUND)
        handler = HANDLERS.get(self.phase)
        step = handler(self, inp) if handler is not None else Step()
        if self.moving_pad is not None:
            pad_v = self._pad_feedforward(inp)
            step = dataclasses.replace(step, setpoint=with_pad_velocity(self.phase, step.setpoint, pad_v))
        setpoint = self.yaw.apply(self.phase, inp, step.setpoint, lambda: self.height_above_ground(inp.estimate))
        request = step.request
        if request is None:
            retry = self.requests.due_retry(inp.time_s)
            if retry is not None:
                request = self.make_request(retry.kind, retry.alt_rel_m, tries=retry.tries)
        return self._out(setpoint, request, step.lyapunov)

    def _pad_feedforward(self, inp: MissionInputs) -> tuple[float, float] | None:
        """The moving pad's velocity to feed forward (moving_pad.pad_feedforward): the estimate's,
        or the vehicle's own once the final descent onto the pad has stopped sinking at the ground."""
        st, est = self.state, inp.estimate
        grounded = (
            self.phase is Phase.LANDING_PAD
            and isinstance(st, LandingState)
            and st.descent is not None
            and st.descent.grounded
        )
        own = (float(est.north_m_s), float(est.east_m_s)) if est is not None else None
        return pad_feedforward(inp.pad_velocity_ne, grounded, own)

    def enter(self, phase: Phase) -> PhaseState:
        """Put the mission in ``phase`` now, as a transition would (tests and tools start a
        mission mid-flight with it); returns the phase's fresh state."""
        self.goto(phase)
        return self.state

    # ------------------------------------------------------------------ checks every tick
    def _on_request_ok(self, req: Request) -> None:
        k = req.kind
        if k is RequestKind.ARM:
            self.emit(EventKind.ARMED, "")
            if self.summary.takeoff_time_s is None:
                self.summary.takeoff_time_s = self.now
            self.goto(Phase.TAKEOFF_RETURN if self.left_pad else Phase.TAKEOFF)
        elif k is RequestKind.RELEASE:
            if isinstance(self.state, ReleaseState):
                self.state.released_t0 = self.now
            self.emit(EventKind.RELEASED, "release commanded")
        # START_OFFBOARD: the phase changes once the status shows OFFBOARD; DISARM: the landing
        # phase sees disarmed and moves on

    def _out(self, sp: VelocitySetpoint | None, req: Request | None, lyap: float) -> MissionOutput:
        # events raised between ticks (abort, request results) go out with this tick's output
        events, self._events = tuple(self._events), []
        return MissionOutput(self.phase, sp, req, events, self.sector, lyap)

    def _check_stall(self, time_s: float) -> None:
        last, self._last_step_s = self._last_step_s, time_s
        if last is not None and time_s - last > self.stall_s and not self.phase.terminal:
            self._lose_control(last)
            if time_s - last > STALL_FORFEITS_CONTROL_S:
                self._control_forfeit = True
            self.emit(
                EventKind.WARNING,
                f"the companion did not step for {time_s - last:.2f} s (limit {self.stall_s} s): "
                "the autopilot's failsafe may have acted",
            )

    def _check_link(self, inp: MissionInputs) -> bool:
        verdict = self.link.check(inp, self.phase in FOLLOW_PHASES, self.emit)
        if verdict is LinkCheck.LOST:
            self._lose_control(inp.time_s)
            return False
        if verdict is LinkCheck.REENTER:
            self.state.offboard.restart()
            self.expect_mode_change = True
        return True

    def _lose_control(self, since_s: float) -> None:
        if self.control_lost_s is None:
            self.control_lost_s = since_s

    def _check_control(self, inp: MissionInputs) -> None:
        """Back in control once the statuses sent after the loss have shown the vehicle flying in
        OFFBOARD for CONTROL_REGAINED_S on end: after a freeze the link's buffered, older
        messages arrive stamped anew, and one of them can still say OFFBOARD in the air. A
        touchdown meanwhile was not the companion's: it stays lost."""
        st = inp.status
        if self.control_lost_s is None or st is None or st.time_s <= self.control_lost_s or self._control_forfeit:
            return
        if st.mode is not FlightMode.OFFBOARD or st.landed is not LandedState.IN_AIR:
            self._regaining_s = None
        elif self._regaining_s is None:
            self._regaining_s = inp.time_s
        elif inp.time_s - self._regaining_s >= CONTROL_REGAINED_S:
            self.control_lost_s = self._regaining_s = None

    def _check_pilot(self, inp: MissionInputs) -> None:
        st = inp.status
        if st is None or self.expect_mode_change or self.requests.pending is not None or self.link.undecided:
            return
        if st.mode is not FlightMode.OFFBOARD and st.armed:
            self.emit(EventKind.PILOT_TAKEOVER, f"mode switched to {st.mode.value}: autonomy ended")
            self.summary.fail(FailureKind.PILOT_TAKEOVER, f"pilot took over ({st.mode.value})")
            self.summary.end_time_s = inp.time_s
            self.goto(Phase.PILOT)

    def _check_estimate(self, inp: MissionInputs) -> None:
        est = inp.estimate
        if est is None:
            return
        if inp.time_s - self.link.restored_at_s < self.cfg.estimate_timeout_s:
            return  # fresh telemetry is still arriving after a reconnect
        age = inp.time_s - est.time_s
        if age > self.cfg.estimate_timeout_s:
            self.abort(inp.time_s, f"state estimate is {age:.2f} s old (limit {self.cfg.estimate_timeout_s} s)")

    def _check_battery(self, inp: MissionInputs) -> None:
        """Abandon the delivery and fly home once the charge left covers no more than the way home
        plus the reserve (outbound and on the pad descent, with the parcel)."""
        st, est = inp.status, inp.estimate
        assert self.battery is not None
        if st is None:
            return
        self.battery.update(inp.time_s, st.battery_pct, st.landed is LandedState.IN_AIR)
        start = self.routes.start_ned
        if self.phase not in DELIVERY_LEG_PHASES or est is None or start is None:
            return
        p = np.asarray(est.position_ned, dtype=float)
        dist = math.hypot(p[0] - start[0], p[1] - start[1])
        height = self.routes.home_ned[2] - float(p[2])
        v = self.battery.verdict(st.battery_pct, time_home_s(way_home(self.cfg), dist, height))
        if v is None or not v.go_home:
            return
        self.emit(EventKind.GO_NO_GO, f"abandoning the delivery, flying home: {v.reason()}")
        self.summary.fail(FailureKind.RETURNED_GO_NO_GO, f"returned without delivering: {v.reason()}")
        self.goto(Phase.INBOUND)

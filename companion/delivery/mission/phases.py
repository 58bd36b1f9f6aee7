"""The phase handlers and the table the step dispatches on: each takes the mission and this
tick's inputs, and returns a :class:`Step`.

Phases: preflight -> arming -> takeoff -> outbound (Leg.OUT) -> landing on the pad -> release
-> (arming -> takeoff -> inbound (Leg.HOME) -> landing at home) -> done. Abort: hold, then land.
No pad lock: pad_hold, pad_search, then home with the parcel or divert (Leg.OUT) to the alternate
pad and the same policy there (padpolicy). Winch delivery: the descent onto the pad becomes phase
winch (winch_phase). The pilot always wins: a mode switch away from offboard that we did not ask
for ends autonomy (core).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import TYPE_CHECKING

from companion.autopilot.types import FlightMode, LandedState, RangefinderReading
from companion.delivery.mission.offboard import enter_offboard, in_offboard, offboard_reentry
from companion.delivery.mission.states import (
    AbortHoldState,
    AbortLandState,
    LandingState,
    ReleaseState,
    TakeoffState,
)
from companion.delivery.mission.types import NOTHING, FailureKind, Leg, MissionInputs, Request, RequestKind, Step
from companion.delivery.mission.winch_phase import winch
from companion.delivery.padlock import pad_in_sight
from companion.events import EventKind, Phase
from companion.guidance.setpoint import VelocitySetpoint

if TYPE_CHECKING:
    from companion.delivery.mission.base import MissionBase
    from companion.estimation.types import StateEstimate

log = logging.getLogger(__name__)

# an autopilot's land detector after contact (PX4 SIH: ON_GROUND 3-7 s after it; ArduCopter ~2 s):
# without a pad-lock policy (require_pad_lock = false), the drop zone stops a descent above this (m)
DROP_ZONE_COMMIT_M = 1.0
# what the final descent's hold leaves before the touchdown timeout, besides the descent itself
TOUCHDOWN_REPORT_MARGIN_S = 5.0
WINCH_APPROACH_LEAD_S = 0.5  # winch: the hover takes over this long of the S5 descent before its height
DISARM_REPEAT_S = 2.0  # after an accepted DISARM, the status may show armed for a moment


# ------------------------------------------------------------------ on the ground, before take-off
def preflight(m: MissionBase, inp: MissionInputs) -> Step:
    st, home, est = inp.status, inp.home, inp.estimate
    if m.frame is None and home is not None and est is not None and not m.routes.plan_delivery(home, est):
        return NOTHING
    ready = st is not None and st.healthy and m.frame is not None
    wind_ok = m.wind is None or m.left_pad or m.wind.fresh(inp.time_s, inp.wind)
    if ready and wind_ok and m.wind is not None and not m.left_pad:
        why = m.wind.take_off_problem(inp.time_s, inp.wind)
        if why:
            m.refuse(inp.time_s, why)
            return NOTHING
    ready = ready and wind_ok
    if ready and st is not None and m.battery is not None and not m.left_pad:
        why = m.battery_round_trip_problem(st.battery_pct)
        if why:
            m.refuse(inp.time_s, why)
            return NOTHING
    if ready and st is not None and st.armed is False and m.idle():
        m.goto(Phase.ARMING)
        return Step(request=m.make_request(RequestKind.ARM))
    if inp.time_s - m.state.t0 > m.cfg.ready_timeout_s:
        why = "no status" if st is None else ("not healthy" if not st.healthy else "no home/estimate")
        if st is not None and st.healthy and m.frame is not None and not wind_ok:
            why = "no wind estimate from the autopilot (go_no_go.wind_limit_m_s is set)"
        m.summary.fail(FailureKind.NOT_READY, f"vehicle not ready after {m.cfg.ready_timeout_s} s: {why}")
        m.goto(Phase.FAILED)
    return NOTHING


def arming(m: MissionBase, inp: MissionInputs) -> Step:
    return NOTHING  # waits for the ARM result (MissionBase.on_result)


# ------------------------------------------------------------------ take-off and offboard
def takeoff(m: MissionBase, inp: MissionInputs) -> Step:
    return _takeoff(m, inp, Phase.OUTBOUND, Leg.OUT)


def takeoff_return(m: MissionBase, inp: MissionInputs) -> Step:
    return _takeoff(m, inp, Phase.INBOUND, Leg.HOME)


def _takeoff(m: MissionBase, inp: MissionInputs, nxt: Phase, leg: Leg) -> Step:
    est, pads = inp.estimate, m.pads
    if est is None or m.field is None or m.frame is None:
        return NOTHING
    st = m.state_as(TakeoffState)
    if leg is Leg.HOME and pads.divert_after_takeoff:
        # took off again from the first pad after a touchdown without lock: to the alternate
        reason, pads.divert_after_takeoff = pads.divert_after_takeoff, ""
        pads.divert_takeoff = pads.plan_divert(est, reason)
        if not pads.divert_takeoff:
            m.summary.fail(FailureKind.NOT_DELIVERED, f"parcel not delivered: {reason}")
    if pads.divert_takeoff:
        leg, nxt = Leg.OUT, Phase.DIVERT
    elif leg is Leg.HOME and not m.routes.return_planned:
        m.routes.plan_return(est)
    if inp.time_s - st.t0 > m.cfg.takeoff_timeout_s:
        m.abort(inp.time_s, f"takeoff did not reach {m.cfg.takeoff_alt_m} m in time")
        return NOTHING
    if st.ground_down_m is None:
        st.ground_down_m = est.position_ned[2]  # where it stands, before the climb
    if not st.requested:
        if m.idle():
            st.requested = True
            m.expect_mode_change = True
            return Step(request=m.make_request(RequestKind.TAKEOFF))
        return NOTHING
    # judged until the field's stream starts (stream_t0 set), then never again: the stream must
    # not stop when the mode leaves HOLD for OFFBOARD (the HOLD test lapses with the switch while
    # our height may still read below the take-off height), or the autopilot's offboard-loss
    # failsafe lands the vehicle
    if st.offboard.stream_t0 is None and not _takeoff_done(m, st, inp, est):
        return NOTHING
    sp, lyap = m.field_setpoint(est, leg)
    req = enter_offboard(m, inp)
    if st.offboard.requested and req is None and m.requests.pending is None and in_offboard(inp):
        pads.divert_takeoff = False
        m.goto(nxt)
    return Step(sp, req, lyap)


def _takeoff_done(m: MissionBase, st: TakeoffState, inp: MissionInputs, est: StateEstimate) -> bool:
    """At 90 % of the takeoff height by our estimate, or once the autopilot has finished its
    takeoff (holding in the air) above half of it: the autopilot climbs to the height by *its*
    altitude, which can sit 0.2-0.3 m off ours (on PX4 SIH a fused estimate may never reach
    90 % of a 2.5 m takeoff that PX4 has completed)."""
    h = m.height_above_ground(est)
    if h >= 0.9 * m.cfg.takeoff_alt_m:
        return True
    status = inp.status
    # the climb since the phase began counts too: an autopilot's height can read a metre off on
    # the ground after a landing (PX4 SIH: 1.27 m below home on the pad), and it takes off by
    # the takeoff height from where it stands
    ground = st.ground_down_m
    climbed = ground - est.position_ned[2] if ground is not None else -math.inf
    return (
        status is not None
        and status.mode is FlightMode.HOLD
        and status.landed is LandedState.IN_AIR
        and max(h, climbed) >= 0.5 * m.cfg.takeoff_alt_m
    )


# ------------------------------------------------------------------ the vector field
def outbound(m: MissionBase, inp: MissionInputs) -> Step:
    return _follow(m, inp, Leg.OUT, Phase.LANDING_PAD)


def divert(m: MissionBase, inp: MissionInputs) -> Step:
    """The vector field to the alternate pad; at its approach height the same lock check as the
    outbound's, then the descent, hold, search and tries there."""
    return _follow(m, inp, Leg.OUT, Phase.LANDING_PAD)


def inbound(m: MissionBase, inp: MissionInputs) -> Step:
    if m.pad_index and not m.routes.home_planned and inp.estimate is not None:
        m.routes.plan_home_from(inp.estimate)  # the divert's path starts at the first pad, not home
        if m.phase is not Phase.INBOUND:
            return NOTHING
    return _follow(m, inp, Leg.HOME, Phase.LANDING_HOME)


def _follow(m: MissionBase, inp: MissionInputs, leg: Leg, landing: Phase) -> Step:
    est = inp.estimate
    if est is None:
        return NOTHING
    sp, lyap = m.field_setpoint(est, leg)
    if m.state.offboard.reenter:
        return Step(sp, offboard_reentry(m, inp), lyap)
    target_sector = 5 if leg is Leg.OUT else 1
    approach_m = m.cfg.final_descent_alt_m
    if leg is Leg.OUT and m.winch_cfg is not None:
        # the hover starts on the way down, one velocity-loop lag above its height: the descent at
        # v5 then slows onto it instead of sinking ~v5 x lag below (1.6 m on ArduCopter SITL)
        lead_m = m.cfg.sector_speed_m_s[4] * WINCH_APPROACH_LEAD_S
        approach_m = max(approach_m, m.winch_cfg.hover_height_m + lead_m)
    # the approach height by the rangefinder where it is on and passes (MissionBase.descent_height):
    # on an estimate reading 1.2 m high the final descent began below a metre, at v5
    if m.sector == target_sector and m.descent_height(est, inp.rangefinder, inp.time_s) < approach_m:
        if leg is Leg.OUT and m.pad_policy is not None:
            ok, why = m.pads.judge(inp.pad_lock)
            if not ok:
                return Step(m.pads.try_failed(inp, f"no pad lock at the approach height: {why}"), None, lyap)
        if leg is Leg.OUT and not m.drop_zones.may_start_descent(inp):
            m.drop_zones.stop(inp, "at the approach height")
            return Step(sp, None, lyap)
        m.goto(landing)
    return Step(sp, None, lyap)


# ------------------------------------------------------------------ the landings
def landing_pad(m: MissionBase, inp: MissionInputs) -> Step:
    return _landing(m, inp, Leg.OUT)


def landing_home(m: MissionBase, inp: MissionInputs) -> Step:
    return _landing(m, inp, Leg.HOME)


def _landing(m: MissionBase, inp: MissionInputs, leg: Leg) -> Step:
    est, status, st = inp.estimate, inp.status, m.state_as(LandingState)
    if status is not None and status.landed is LandedState.ON_GROUND:
        return _on_the_ground(m, inp, leg, st)
    if est is None:
        return NOTHING
    if st.touchdown_land_requested:
        return NOTHING  # the autopilot's LAND flies the rest; we wait for the touchdown
    if inp.time_s - st.t0 > m.cfg.touchdown_timeout_s and m.idle():
        m.expect_mode_change = True
        st.touchdown_land_requested = True
        m.emit(EventKind.WARNING, "no touchdown in time: handing the last metres to the autopilot's LAND")
        return Step(request=m.make_request(RequestKind.LAND))
    if leg is Leg.OUT and m.landing_controller == "autopilot":
        # the autopilot's precision landing flies the descent; we only wait for the touchdown
        if not st.precland_requested and m.idle():
            st.precland_requested = True
            m.expect_mode_change = True
            return Step(request=m.make_request(RequestKind.PRECISION_LAND))
        return NOTHING
    if m.expect_mode_change:
        return NOTHING
    if leg is Leg.OUT and m.pad_policy is not None:
        h = m.height_above_ground(est)
        ok, why = m.pads.judge(inp.pad_lock)
        if ok:
            st.lock_reopened_at = None
        elif h > m.pad_policy.commit_height_m and not m.pads.lock_reopening(st, inp.pad_lock, inp.time_s):
            return Step(m.pads.try_failed(inp, f"pad lock lost in the descent at {h:.1f} m: {why}"))
    if leg is Leg.OUT and m.drop_zones.blocked(inp):
        h = m.height_above_ground(est)
        commit_m = m.pad_policy.commit_height_m if m.pad_policy is not None else DROP_ZONE_COMMIT_M
        if h > commit_m:
            m.drop_zones.stop(inp, f"in the descent at {h:.1f} m")
            return NOTHING
        st.drop_zone_blocked = inp.drop_zone.value if inp.drop_zone is not None else ""  # judged at touchdown
    in_sight = leg is Leg.OUT and pad_in_sight(inp.pad_lock)
    pad_v = inp.pad_velocity_ne if leg is Leg.OUT else None
    return Step(precision_descent(m, est, leg, inp.time_s, in_sight, inp.rangefinder, pad_v))


def _on_the_ground(m: MissionBase, inp: MissionInputs, leg: Leg, st: LandingState) -> Step:
    est, status = inp.estimate, inp.status
    assert status is not None
    if not st.touched_down:
        st.touched_down = True
        st.touchdown_ours = m.control_lost_s is None and (
            status.mode is FlightMode.OFFBOARD or st.precland_requested or st.touchdown_land_requested
        )
        if leg is Leg.OUT and m.pad_policy is not None:
            st.touchdown_lock = m.pads.judge(inp.pad_lock)
        if leg is Leg.OUT and m.drop_zones.blocked(inp) and inp.drop_zone is not None:
            st.touchdown_drop_zone = inp.drop_zone.value
        elif leg is Leg.OUT and st.drop_zone_blocked:
            st.touchdown_drop_zone = st.drop_zone_blocked
        if est is not None:
            if leg is Leg.OUT:
                m.summary.pad_touchdown_ned = est.position_ned
                # judged where the descent felt the ground, if it did (descent.contact_time_s)
                st.touchdown_off_pad_m = _off_the_pad_m(m, st.contact_ned or est.position_ned)
            else:
                m.summary.home_touchdown_ned = est.position_ned
        m.emit(EventKind.TOUCHDOWN, "pad" if leg is Leg.OUT else "home")
    if leg is Leg.OUT and not st.touchdown_ours:
        # the autopilot landed it (its failsafe while the companion stalled or lost the link, or a
        # pilot's LAND): nothing is released and nothing commanded, armed or not
        detail = (
            f"the vehicle touched down (mode {status.mode.value}) while the companion was not in control "
            "(the autopilot's failsafe, a pilot's LAND): the parcel stays aboard, autonomy ended"
        )
        m.emit(EventKind.PILOT_TAKEOVER, detail)
        m.summary.fail(FailureKind.AUTOPILOT_LANDED, detail)
        m.summary.end_time_s = inp.time_s
        m.goto(Phase.FAILED)
        return NOTHING
    if not status.armed:
        if leg is Leg.OUT and not st.touchdown_lock[0]:
            return Step(request=m.pads.home_with_parcel(f"no pad lock at touchdown: {st.touchdown_lock[1]}"))
        if leg is Leg.OUT and st.touchdown_drop_zone:
            why = f"drop zone {st.touchdown_drop_zone} at touchdown"
            return Step(request=m.pads.home_with_parcel(why))
        if leg is Leg.OUT and st.touchdown_off_pad_m > 0.0:
            off = st.touchdown_off_pad_m
            return Step(request=m.pads.home_with_parcel(f"touched down {off:.2f} m outside the pad (by the estimate)"))
        after_touchdown(m, leg)
        return NOTHING
    return Step(request=_ask_to_disarm(m, inp, st))


def _off_the_pad_m(m: MissionBase, ned: tuple[float, float, float]) -> float:
    """How far the estimate puts the vehicle outside the pad it lands on (0 on it): its distance
    from the pad's centre beyond half the pad's side (mission.pad.size_m; the circle within the
    square). A parcel is never released where the mission's own estimate says it is off the pad,
    lock or no lock (a GPS-only delivery that came down late after a stall, 2 m off)."""
    assert m.pad_ned is not None
    pad = m.cfg.alternate_pad if m.pad_index and m.cfg.alternate_pad is not None else m.cfg.pad
    off = math.hypot(ned[0] - float(m.pad_ned[0]), ned[1] - float(m.pad_ned[1])) - 0.5 * pad.size_m
    return max(0.0, off)


def precision_descent(
    m: MissionBase,
    est: StateEstimate,
    leg: Leg,
    time_s: float,
    in_sight: bool,
    rangefinder: RangefinderReading | None = None,
    pad_velocity_ne: tuple[float, float] | None = None,
) -> VelocitySetpoint:
    """The final descent onto the target (the pad for Leg.OUT, home for Leg.HOME) by the
    landing phase's controller (guidance.descent), in F_I. It holds and waits only while the
    target is in sight (a camera or UWB observation of the pad within padlock.PAD_DATA_FRESH_S)
    and there is time left before the touchdown timeout: the autopilot's LAND after it flies the
    autopilot's own estimate (PX4 SIH: 77 cm off), worse than going on down mid-swing. Blind (GPS
    only, at home, or the pad lost) it does not hold: holding cannot improve the estimate, and on
    an autopilot's estimate drifting near the ground it can sit on the ground until the touchdown
    timeout (docs/firmware-px4.md). The height above the ground is the rangefinder's where
    [mission.rangefinder] is on and its gate passes (MissionBase.descent_height). ``pad_velocity_ne``:
    a moving pad's estimated velocity ([landing.moving_pad]): the controller's damping takes the
    velocity relative to the pad (the mission adds the pad's velocity to the setpoint)."""
    assert m.frame is not None and m.path is not None
    frame, c, st = m.frame, m.cfg, m.state_as(LandingState)
    assert st.descent is not None
    p_i = frame.point_from_ned(est.position_ned)
    ex = float(p_i[0]) if leg is Leg.OUT else float(p_i[0]) + m.path.d
    ey = float(p_i[1])
    height = m.descent_height(est, rangefinder, time_s)
    time_left_s = c.touchdown_timeout_s - (time_s - st.t0)
    in_time = time_left_s > max(height, 0.0) / c.land_speed_m_s + TOUCHDOWN_REPORT_MARGIN_S

    def velocity_xy() -> tuple[float, float]:
        vn, ve = pad_velocity_ne if pad_velocity_ne is not None else (0.0, 0.0)
        v_i = frame.vector_from_ned((est.north_m_s - vn, est.east_m_s - ve, est.down_m_s))
        return float(v_i[0]), float(v_i[1])

    cmd = st.descent.command(ex, ey, height, time_s, in_sight and in_time, velocity_xy, est.down_m_s)
    if st.descent.contact and st.contact_ned is None:
        # where the sinking stopped: by the confirmation the estimate has drifted under the
        # sideways command (real PX4 SIH under load: 0.2 m in 1.2 s)
        st.contact_ned = st.sink_stop_ned or est.position_ned
        log.info("ground contact at %.2f m height: only the descent from here", height)
    elif st.descent.sinking_stopped:
        st.sink_stop_ned = st.sink_stop_ned or est.position_ned
    else:
        st.sink_stop_ned = None
    v_ned = frame.vector_to_ned((cmd.x_m_s, cmd.y_m_s, cmd.z_m_s))
    acc = None
    if cmd.accel_xy_m_s2 is not None:
        a_ned = frame.vector_to_ned((cmd.accel_xy_m_s2[0], cmd.accel_xy_m_s2[1], 0.0))
        acc = (float(a_ned[0]), float(a_ned[1]))
    return VelocitySetpoint(float(v_ned[0]), float(v_ned[1]), float(v_ned[2]), frame.yaw_to_ned(0.0), acc)


def after_touchdown(m: MissionBase, leg: Leg) -> None:
    if leg is Leg.OUT:
        m.left_pad = True  # the next ARM is for the return leg
        m.goto(Phase.RELEASE)
    else:
        m.summary.returned = True
        m.summary.home_with_parcel = not m.summary.delivered
        m.summary.end_time_s = m.now
        m.emit(EventKind.RETURNED, "landed at home")
        m.goto(Phase.DONE)


def _ask_to_disarm(m: MissionBase, inp: MissionInputs, st: LandingState | AbortLandState) -> Request | None:
    """On the ground and still armed: the DISARM request, at once and again only every
    DISARM_REPEAT_S while the status shows armed (the autopilot usually disarms by itself)."""
    if not m.idle() or inp.time_s < st.disarm_not_before:
        return None
    st.disarm_not_before = inp.time_s + DISARM_REPEAT_S
    return m.make_request(RequestKind.DISARM)


# ------------------------------------------------------------------ no pad lock (padpolicy)
def pad_hold(m: MissionBase, inp: MissionInputs) -> Step:
    return m.pads.hold(inp)


def pad_search(m: MissionBase, inp: MissionInputs) -> Step:
    return m.pads.search(inp)


def drop_zone_hold(m: MissionBase, inp: MissionInputs) -> Step:
    return m.drop_zones.hold(inp)


# ------------------------------------------------------------------ the release on the pad
def release(m: MissionBase, inp: MissionInputs) -> Step:
    status, st = inp.status, m.state_as(ReleaseState)
    if st.error:
        return _release_failed(m, inp, st)
    if st.released_t0 is None:
        if m.idle() and not st.requested:  # later tries come from the retry path
            st.requested = True
            return Step(request=m.make_request(RequestKind.RELEASE))
        return NOTHING
    if inp.time_s - st.released_t0 < m.cfg.release_time_s:
        return NOTHING
    if status is not None and not status.payload_released:
        st.error = "the payload actuator reports the parcel still attached"
        return _release_failed(m, inp, st)
    if not m.summary.delivered:
        m.summary.delivered = True
        m.emit(
            EventKind.DELIVERED,
            "parcel released on the alternate pad" if m.pad_index else "parcel released on the pad",
        )
    if not m.cfg.return_home:
        m.summary.end_time_s = inp.time_s
        m.goto(Phase.DONE)
        return NOTHING
    m.goto(Phase.ARMING)
    return Step(request=m.make_request(RequestKind.ARM))


def _release_failed(m: MissionBase, inp: MissionInputs, st: ReleaseState) -> Step:
    """The autopilot refused or failed the release (or never answered): the parcel is still
    attached. Say so once, then fly home with it or stay on the pad (mission.on_release_failure)."""
    reason, st.error = st.error, ""
    m.summary.fail(FailureKind.NOT_RELEASED, f"parcel not released: {reason}")
    stay = m.cfg.on_release_failure == "stay" or not m.cfg.return_home
    m.emit(
        EventKind.WARNING,
        f"parcel not released ({reason}); "
        + ("staying disarmed on the pad" if stay else "flying home with the parcel"),
    )
    if stay:
        m.summary.end_time_s = inp.time_s
        m.goto(Phase.FAILED)
        return NOTHING
    m.goto(Phase.ARMING)
    return Step(request=m.make_request(RequestKind.ARM))


# ------------------------------------------------------------------ the abort: hold, then land
def abort_hold(m: MissionBase, inp: MissionInputs) -> Step:
    st = m.state_as(AbortHoldState)
    if not st.requested:
        if m.idle():
            st.requested = True
            m.expect_mode_change = True
            return Step(request=m.make_request(RequestKind.HOLD))
        return NOTHING
    if not st.forever and inp.time_s - st.t0 >= m.cfg.abort_hold_s and m.idle():
        m.goto(Phase.ABORT_LAND)
        m.state_as(AbortLandState).requested = True
        return Step(request=m.make_request(RequestKind.LAND))
    return NOTHING


def abort_land(m: MissionBase, inp: MissionInputs) -> Step:
    st = m.state_as(AbortLandState)
    if not st.requested and m.idle():
        st.requested = True
        m.expect_mode_change = True
        return Step(request=m.make_request(RequestKind.LAND))
    status = inp.status
    if status is not None and status.landed is LandedState.ON_GROUND:
        if not status.armed:
            m.abort_summary(f"aborted: {m.abort_reason}")
            m.summary.end_time_s = inp.time_s
            m.goto(Phase.FAILED)
        else:
            # as after a landing on the pad: waiting for the autopilot's own disarm would wait
            # forever where it is turned off (PX4 COM_DISARM_LAND < 0, ArduPilot DISARM_DELAY = 0)
            return Step(request=_ask_to_disarm(m, inp, st))
    return NOTHING


HANDLERS: dict[Phase, Callable[[MissionBase, MissionInputs], Step]] = {
    Phase.PREFLIGHT: preflight,
    Phase.ARMING: arming,
    Phase.TAKEOFF: takeoff,
    Phase.OUTBOUND: outbound,
    Phase.LANDING_PAD: landing_pad,
    Phase.RELEASE: release,
    Phase.PAD_HOLD: pad_hold,
    Phase.PAD_SEARCH: pad_search,
    Phase.DROP_ZONE_HOLD: drop_zone_hold,
    Phase.DIVERT: divert,
    Phase.WINCH: winch,
    Phase.TAKEOFF_RETURN: takeoff_return,
    Phase.INBOUND: inbound,
    Phase.LANDING_HOME: landing_home,
    Phase.ABORT_HOLD: abort_hold,
    Phase.ABORT_LAND: abort_land,
}

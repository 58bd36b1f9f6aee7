"""The mission core alone: synthetic, timestamped inputs in; requests and events out."""

import math

import pytest

from companion.autopilot.types import FlightMode, HomePosition, LandedState, VehicleStatus
from companion.config import DescentConfig, MissionConfig, PadConfig
from companion.delivery.mission import DeliveryMission, FailureKind, Leg, MissionInputs, RequestKind, RequestResult
from companion.delivery.mission.phases import precision_descent
from companion.estimation.types import StateEstimate
from companion.events import CommandKind, EventKind, Phase

HOME = HomePosition(0.0, -19.869, -43.9638, 850.0)


def est(t, n=0.0, e=0.0, d=0.0):
    return StateEstimate(t, n, e, d, 0, 0, 0, 0, 0, 0)


def status(t, healthy=True, armed=False, mode=FlightMode.HOLD, landed=LandedState.ON_GROUND):
    return VehicleStatus(t, armed, mode, landed, healthy, 90.0, False)


def cfg(**kw):
    return MissionConfig(pad=PadConfig(north_m=60.0, east_m=80.0), **kw)


def test_arm_refused_three_times_fails_on_the_ground_with_the_reason():
    m = DeliveryMission(cfg())
    t = 0.0
    out = m.step(MissionInputs(t, est(t), status(t), HOME))
    assert out.request is not None and out.request.kind is RequestKind.ARM
    assert m.path is not None and abs(m.path.d - 100.0) < 1e-9
    tries = 0
    req = out.request
    while m.phase is not Phase.FAILED and t < 30:
        if req is not None:
            tries += 1
            m.on_result(RequestResult(req.id, False, "arming denied: battery low"))
        t += 0.05
        req = m.step(MissionInputs(t, est(t), status(t), HOME)).request
    assert tries == 3
    assert m.phase is Phase.FAILED and "arm failed 3 times: arming denied: battery low" in m.summary.failure
    assert sum(e.kind is EventKind.REQUEST_FAILED for e in m.summary.events) == 3


def test_preflight_times_out_when_the_vehicle_never_becomes_healthy():
    m = DeliveryMission(cfg(ready_timeout_s=5.0))
    t = 0.0
    while t < 6.0:
        out = m.step(MissionInputs(t, est(t), status(t, healthy=False), HOME))
        assert out.request is None
        t += 0.05
    assert m.phase is Phase.FAILED and "not healthy" in m.summary.failure


def test_takeoff_then_offboard_only_after_streaming():
    m = DeliveryMission(cfg())
    t = 0.0
    req = m.step(MissionInputs(t, est(t), status(t), HOME)).request
    m.on_result(RequestResult(req.id, True))
    out = m.step(MissionInputs(t, est(t), status(t, armed=True), HOME))
    assert m.phase is Phase.TAKEOFF and out.request.kind is RequestKind.TAKEOFF
    m.on_result(RequestResult(out.request.id, True))
    first_sp = None
    offboard_t = None
    alt = 0.0
    while t < 20 and offboard_t is None:
        t += 0.05
        alt = min(3.0, alt + 0.075)
        out = m.step(
            MissionInputs(
                t, est(t, d=-alt), status(t, armed=True, mode=FlightMode.TAKEOFF, landed=LandedState.IN_AIR), HOME
            )
        )
        if out.setpoint is not None and first_sp is None:
            first_sp = t
        if out.request is not None:
            assert out.request.kind is RequestKind.START_OFFBOARD
            offboard_t = t
            m.on_result(RequestResult(out.request.id, True))
    assert first_sp is not None and offboard_t - first_sp >= 0.5 - 1e-9  # PX4: stream first
    out = m.step(
        MissionInputs(
            t + 0.05, est(t, d=-3.0), status(t, armed=True, mode=FlightMode.OFFBOARD, landed=LandedState.IN_AIR), HOME
        )
    )
    assert m.phase is Phase.OUTBOUND
    assert out.setpoint.down_m_s < -1.9  # climbing along S1 at v1 = 2 m/s


def _climb_in_hold(ground_d, top_d, timeout_s=10.0):
    """The path planned with the ground at d = 0, then the estimate on the ground reading
    ``ground_d`` (as after a landing, where the return's ground is the pad's configured level):
    arm, take off, climb to ``top_d`` and hold there in the air. The requests the mission makes,
    and the mission."""
    m = DeliveryMission(cfg(takeoff_alt_m=2.5, takeoff_timeout_s=timeout_s))
    t = 0.0
    m.on_result(RequestResult(m.step(MissionInputs(t, est(t), status(t), HOME)).request.id, True))
    out = m.step(MissionInputs(t, est(t, d=ground_d), status(t, armed=True), HOME))
    m.on_result(RequestResult(out.request.id, True))
    kinds = []
    d = ground_d
    while t < timeout_s + 1.0 and m.phase is Phase.TAKEOFF:
        t += 0.05
        d = max(top_d, d - 0.075)
        mode = FlightMode.TAKEOFF if d > top_d else FlightMode.HOLD
        out = m.step(MissionInputs(t, est(t, d=d), status(t, armed=True, mode=mode, landed=LandedState.IN_AIR), HOME))
        if out.request is not None:
            kinds.append(out.request.kind)
            m.on_result(RequestResult(out.request.id, True))
    return kinds, m


def test_a_takeoff_is_judged_by_the_climb_too_when_the_height_reads_low_on_the_ground():
    """Real PX4 SIH after a landing: its height read 1.27 m below home on the ground, it climbed
    2.34 m and held; by height above home (1.07 m) the take-off never ended and timed out."""
    kinds, _ = _climb_in_hold(ground_d=1.27, top_d=-1.07)
    assert RequestKind.START_OFFBOARD in kinds  # done: the field's stream started
    # the climb alone is not enough while the autopilot is still taking off, nor a short one in HOLD
    kinds, m = _climb_in_hold(ground_d=1.27, top_d=0.2, timeout_s=3.0)
    assert RequestKind.START_OFFBOARD not in kinds and m.phase is Phase.ABORT_HOLD
    assert any("takeoff did not reach 2.5 m" in e.detail for e in m.summary.events)


def test_field_lookahead_evaluates_the_field_one_lag_ahead_and_reports_v_where_the_vehicle_is():
    import numpy as np

    m = DeliveryMission(cfg(field_lookahead_s=0.5))
    m.step(MissionInputs(0.0, est(0.0), status(0.0), HOME))  # plans the path from home
    assert m.frame is not None and m.path is not None and m.field is not None
    e = StateEstimate(1.0, 1.0, 2.0, -10.0, 4.0, -2.0, -1.0, 0, 0, 0)
    sp, lyap = m.field_setpoint(e, Leg.OUT)
    ahead = np.array([1.0 + 0.5 * 4.0, 2.0 + 0.5 * -2.0, -10.0 + 0.5 * -1.0])
    f = m.field(m.frame.point_from_ned(ahead), 1)
    v = m.frame.vector_to_ned(f.velocity)
    assert (sp.north_m_s, sp.east_m_s, sp.down_m_s) == tuple(float(x) for x in v)
    assert lyap == m.path.lyapunov(m.frame.point_from_ned(np.array([1.0, 2.0, -10.0])))
    # without lookahead: the paper's field at the current position
    m0 = DeliveryMission(cfg())
    m0.step(MissionInputs(0.0, est(0.0), status(0.0), HOME))
    sp0, _ = m0.field_setpoint(e, Leg.OUT)
    f0 = m0.field(m0.frame.point_from_ned(np.array([1.0, 2.0, -10.0])), 1)
    assert (sp0.north_m_s, sp0.east_m_s, sp0.down_m_s) == tuple(float(x) for x in m0.frame.vector_to_ned(f0.velocity))


def _outbound_mission(resume_modes=("hold", "position")):
    """A mission driven into OUTBOUND (offboard accepted) at t = 1.0 s."""
    m = DeliveryMission(cfg(link_loss_resume_modes=list(resume_modes)))
    t = 0.0
    m.on_result(RequestResult(m.step(MissionInputs(t, est(t), status(t), HOME)).request.id, True))
    out = m.step(MissionInputs(t, est(t), status(t, armed=True), HOME))
    m.on_result(RequestResult(out.request.id, True))
    flying = dict(armed=True, landed=LandedState.IN_AIR)
    mode = FlightMode.TAKEOFF
    while m.phase is not Phase.OUTBOUND:
        t += 0.05
        out = m.step(MissionInputs(t, est(t, d=-3.0), status(t, mode=mode, **flying), HOME))
        if out.request is not None:
            assert out.request.kind is RequestKind.START_OFFBOARD
            m.on_result(RequestResult(out.request.id, True))
            mode = FlightMode.OFFBOARD
        assert t < 30
    return m, t


def test_a_reconnect_is_decided_on_a_status_sent_after_the_link_came_back():
    """The link returns (a heartbeat) before a fresh status does: the last status from before the
    loss still says OFFBOARD. The mission must not decide on it, or the failsafe's HOLD that the
    next status shows looks like the pilot's switch and ends the mission."""
    m, t = _outbound_mission()
    flying = dict(armed=True, landed=LandedState.IN_AIR)
    last = status(t, mode=FlightMode.OFFBOARD, **flying)
    m.step(MissionInputs(t + 0.05, est(t), last, HOME, link_ok=False))  # lost; status frozen
    t += 3.0
    out = m.step(MissionInputs(t, est(t), last, HOME, link_ok=True))  # back, status still stale
    assert m.phase is Phase.OUTBOUND and EventKind.LINK_RESTORED in [e.kind for e in out.events]
    assert out.request is None
    t += 0.05
    hold = status(t, mode=FlightMode.HOLD, **flying)  # the autopilot's failsafe mode, now reported
    reqs = []
    for _ in range(40):
        out = m.step(MissionInputs(t, est(t, d=-3.0), hold, HOME))
        if out.request is not None:
            reqs.append(out.request.kind)
            m.on_result(RequestResult(out.request.id, True))
            break
        t += 0.05
        hold = status(t, mode=FlightMode.HOLD, **flying)
    assert m.phase is Phase.OUTBOUND, m.summary.failure
    assert reqs == [RequestKind.START_OFFBOARD]


def test_a_reconnect_into_a_mode_the_failsafe_does_not_pick_is_the_pilot():
    m, t = _outbound_mission(resume_modes=("hold",))
    flying = dict(armed=True, landed=LandedState.IN_AIR)
    last = status(t, mode=FlightMode.OFFBOARD, **flying)
    m.step(MissionInputs(t + 0.05, est(t), last, HOME, link_ok=False))
    t += 3.0
    m.step(MissionInputs(t, est(t), last, HOME, link_ok=True))
    assert m.phase is Phase.OUTBOUND  # undecided on the stale status
    t += 0.05
    m.step(MissionInputs(t, est(t, d=-3.0), status(t, mode=FlightMode.POSITION, **flying), HOME))
    assert m.phase is Phase.PILOT and "position" in m.summary.failure


def _descent_setpoints(m, offsets_ned, t0=0.0, dt=0.05, d=-2.0):
    """Horizontal setpoints (N, E) of the final descent over the pad at these NED offsets, one
    guidance tick apart."""
    pn, pe = float(m.pad_ned[0]), float(m.pad_ned[1])
    out = []
    for k, (dn, de) in enumerate(offsets_ned):
        t = t0 + k * dt
        sp = precision_descent(m, est(t, pn + dn, pe + de, d), Leg.OUT, t, True)
        out.append((sp.north_m_s, sp.east_m_s))
    return out


def test_final_descent_integral_term_accumulates_clamps_freezes_and_restarts_per_landing():
    """k_i * sum(e * dt) added to the proportional law (mission._landing_integral), by hand: a
    constant 0.04 m offset east for 10 ticks of 0.05 s at k_i = 2.5 1/s^2 adds 2.5 * 0.04 * 0.45 =
    0.045 m/s against the offset (the first tick only starts the sum)."""
    kw = dict(landing_xy_gain_1_s=5.0, landing_touchdown_height_m=0.15, landing_xy_integral_max_m_s=0.3)
    m_p = DeliveryMission(cfg(**kw))
    m_pi = DeliveryMission(cfg(landing_xy_integral_gain_1_s2=2.5, **kw))
    for m in (m_p, m_pi):
        m.step(MissionInputs(0.0, est(0.0), status(0.0), HOME))
        m.enter(Phase.LANDING_PAD)
    offs = [(0.0, 0.04)] * 10
    p = _descent_setpoints(m_p, offs)
    pi = _descent_setpoints(m_pi, offs)
    assert pi[0] == pytest.approx(p[0])
    assert p[-1][1] == pytest.approx(-5.0 * 0.04, abs=1e-9)  # proportional alone: -k_p e
    assert pi[-1][0] == pytest.approx(p[-1][0], abs=1e-9)
    assert pi[-1][1] - p[-1][1] == pytest.approx(-2.5 * 0.04 * 0.45, abs=1e-9)
    # held at landing_xy_integral_max_m_s however long the error stays
    long = _descent_setpoints(m_pi, [(0.0, 0.04)] * 200, t0=0.5)
    assert long[-1][1] - p[-1][1] == pytest.approx(-0.3, abs=1e-9)
    # frozen below the touchdown height (only the descent is commanded there)
    low = _descent_setpoints(m_pi, [(0.0, 0.04)] * 5, t0=11.0, d=-0.1)
    assert low[-1] == (0.0, 0.0)
    back = _descent_setpoints(m_pi, [(0.0, 0.0)], t0=11.3)
    assert back[0][1] == pytest.approx(-0.3, abs=1e-9)  # the sum kept, nothing added on the ground
    # a new landing phase starts from nothing
    m_pi.now = 20.0
    m_pi.enter(Phase.LANDING_HOME)
    m_pi.enter(Phase.LANDING_PAD)
    again = _descent_setpoints(m_pi, [(0.0, 0.04)] * 2, t0=20.0)
    assert again[0] == pytest.approx(p[0])
    assert again[1][1] - p[0][1] == pytest.approx(-2.5 * 0.04 * 0.05, abs=1e-9)


def test_a_negative_touchdown_height_keeps_closing_the_error_down_to_the_ground():
    m = DeliveryMission(cfg(landing_xy_gain_1_s=5.0, landing_touchdown_height_m=-1.0))
    m.step(MissionInputs(0.0, est(0.0), status(0.0), HOME))
    m.enter(Phase.LANDING_PAD)
    (sp,) = _descent_setpoints(m, [(0.0, 0.04)], d=0.05)  # the estimate already below the ground
    assert sp[1] == pytest.approx(-0.2, abs=1e-9)
    m0 = DeliveryMission(cfg(landing_xy_gain_1_s=5.0))
    m0.step(MissionInputs(0.0, est(0.0), status(0.0), HOME))
    m0.enter(Phase.LANDING_PAD)
    assert _descent_setpoints(m0, [(0.0, 0.04)], d=0.05) == [(0.0, 0.0)]


def _aborted_in_the_air():
    """A mission aborted 2 m up in its takeoff, through HOLD and LAND, now reported on the ground
    and still armed (an autopilot whose own disarm after landing is turned off)."""
    m = DeliveryMission(cfg(abort_hold_s=1.0))
    t = 0.0
    req = m.step(MissionInputs(t, est(t), status(t), HOME)).request
    m.on_result(RequestResult(req.id, True))
    air = status(t, armed=True, mode=FlightMode.TAKEOFF, landed=LandedState.IN_AIR)
    req = m.step(MissionInputs(t, est(t, d=-2.0), air, HOME)).request
    m.on_result(RequestResult(req.id, True))  # TAKEOFF
    m.abort(t, "operator abort")
    kinds = []
    while t < 3.0:
        t += 0.05
        out = m.step(MissionInputs(t, est(t, d=-2.0), air, HOME))
        if out.request is not None:
            kinds.append(out.request.kind)
            m.on_result(RequestResult(out.request.id, True))
    assert kinds == [RequestKind.HOLD, RequestKind.LAND] and m.phase is Phase.ABORT_LAND
    return m, t


def test_an_abort_landing_asks_to_disarm_on_the_ground_and_ends_once_disarmed():
    m, t = _aborted_in_the_air()
    ground = status(t, armed=True, mode=FlightMode.LAND)
    sent = []
    for _ in range(100):  # 5 s on the ground, armed
        t += 0.05
        out = m.step(MissionInputs(t, est(t), ground, HOME))
        if out.request is not None:
            assert out.request.kind is RequestKind.DISARM
            sent.append(t)
            m.on_result(RequestResult(out.request.id, True))
    # at once, then again only every DISARM_REPEAT_S (2 s) while the status still shows armed
    assert len(sent) == 3 and sent[1] - sent[0] >= 2.0 - 1e-9 and sent[2] - sent[1] >= 2.0 - 1e-9
    assert m.phase is Phase.ABORT_LAND
    m.step(MissionInputs(t + 0.05, est(t), status(t, armed=False, mode=FlightMode.LAND), HOME))
    assert m.phase is Phase.FAILED and m.summary.failure == "aborted: operator abort"
    assert m.summary.failure_kind is FailureKind.ABORTED


def test_an_abort_landing_whose_disarm_is_refused_ends_saying_it_is_still_armed():
    m, t = _aborted_in_the_air()
    ground = status(t, armed=True, mode=FlightMode.LAND)
    tries = 0
    while m.phase is not Phase.FAILED and t < 30.0:
        t += 0.05
        out = m.step(MissionInputs(t, est(t), ground, HOME))
        if out.request is not None:
            assert out.request.kind is RequestKind.DISARM
            tries += 1
            m.on_result(RequestResult(out.request.id, False, "disarm denied"))
    assert tries == 3  # never asked again for ever
    assert m.phase is Phase.FAILED
    assert m.summary.failure == "aborted: operator abort; landed but still armed (disarm failed 3 times: disarm denied)"
    assert m.summary.failure_kind is FailureKind.LANDED_ARMED


def test_the_failure_kind_is_the_one_the_abort_was_asked_with_not_read_from_the_text():
    """An abort of kind OPERATOR_ABORT ends with that kind whatever its reason says; a ground
    command's land is ABORTED, a refusal before take-off REFUSED, a pilot's mode switch
    PILOT_TAKEOVER; a mission that ends well has none."""
    m = DeliveryMission(cfg())
    m.step(MissionInputs(0.0, est(0.0), status(0.0), HOME))
    m.abort(0.1, "stop", FailureKind.OPERATOR_ABORT)
    assert m.phase is Phase.FAILED and m.summary.failure == "aborted on the ground: stop"
    assert m.summary.failure_kind is FailureKind.OPERATOR_ABORT
    m = DeliveryMission(cfg())
    m.refuse(0.0, "too windy")
    assert m.summary.failure_kind is FailureKind.REFUSED
    m = DeliveryMission(cfg())
    m.command(0.0, CommandKind.LAND, "ground")
    assert m.summary.failure_kind is FailureKind.ABORTED
    assert DeliveryMission(cfg()).summary.failure_kind is FailureKind.NONE


def test_the_mission_says_which_request_it_waits_on():
    m = DeliveryMission(cfg())
    assert m.waiting_for() == "no request in flight"
    req = m.step(MissionInputs(0.0, est(0.0), status(0.0), HOME)).request
    assert m.waiting_for() == f"waiting for the answer to arm #{req.id} (try 1)"
    m.on_result(RequestResult(req.id, False, "not ready"))
    assert m.waiting_for() == "arm to be retried at t = 1.0 s"


def test_final_descent_holds_to_align_only_while_the_pad_is_in_sight():
    """Off-centre at 2 m: with a pad observation within PAD_DATA_FRESH_S the descent slows (by
    1 - (e - tol) / tol) and holds at twice the tolerance; blind (observation stale, no pad sensor,
    no lock measured) it goes down at land speed, as it does below landing_hold_min_height_m."""
    from companion.delivery.padlock import NO_SENSORS, PAD_DATA_FRESH_S, PadLock

    c = cfg(landing_xy_tolerance_m=0.1, landing_hold_min_height_m=0.5, land_speed_m_s=0.5)
    flying = dict(armed=True, mode=FlightMode.OFFBOARD, landed=LandedState.IN_AIR)

    def down_m_s(offset_east_m, lock, height_m=2.0):
        m = DeliveryMission(c)
        m.step(MissionInputs(0.0, est(0.0), status(0.0), HOME))
        m.enter(Phase.LANDING_PAD)
        pn, pe = float(m.pad_ned[0]), float(m.pad_ned[1])
        out = m.step(
            MissionInputs(
                0.05, est(0.05, pn, pe + offset_east_m, -height_m), status(0.05, **flying), HOME, pad_lock=lock
            )
        )
        assert m.phase is Phase.LANDING_PAD and out.setpoint is not None
        return out.setpoint.down_m_s

    fresh = PadLock(0.05, PAD_DATA_FRESH_S, 0.02)
    stale = PadLock(0.05, PAD_DATA_FRESH_S + 0.01, 0.02)
    assert down_m_s(0.05, fresh) == pytest.approx(0.5)  # within the tolerance: full speed
    assert down_m_s(0.15, fresh) == pytest.approx(0.25)  # half-way to twice it: half speed
    assert down_m_s(0.25, fresh) == pytest.approx(0.0)  # beyond twice it: holds
    assert down_m_s(0.25, fresh, height_m=0.4) == pytest.approx(0.5)  # below the hold's floor
    for blind in (stale, NO_SENSORS, None):
        assert down_m_s(0.25, blind) == pytest.approx(0.5), blind


def test_final_descent_holds_no_longer_than_the_touchdown_timeout_leaves_time_for():
    """The hold to align ends once the time left before touchdown_timeout_s is no more than the
    rest of the descent at land speed plus TOUCHDOWN_REPORT_MARGIN_S: a vehicle circling wider
    than the hold's gate (real PX4 SIH with a CPU-starved companion, CI of 2026-11-27) goes on down
    under the companion instead of waiting for the autopilot's LAND (1.3 m off then)."""
    from companion.delivery.mission import TOUCHDOWN_REPORT_MARGIN_S
    from companion.delivery.padlock import PAD_DATA_FRESH_S, PadLock

    c = cfg(landing_xy_tolerance_m=0.1, landing_hold_min_height_m=0.5, land_speed_m_s=0.5, touchdown_timeout_s=15.0)
    flying = dict(armed=True, mode=FlightMode.OFFBOARD, landed=LandedState.IN_AIR)
    height_m = 2.0
    last_hold_s = 15.0 - (height_m / 0.5 + TOUCHDOWN_REPORT_MARGIN_S)  # 6 s into the landing phase

    def down_m_s(after_s):
        m = DeliveryMission(c)
        m.step(MissionInputs(0.0, est(0.0), status(0.0), HOME))
        m.enter(Phase.LANDING_PAD)
        m.state.t0 = 0.0
        pn, pe = float(m.pad_ned[0]), float(m.pad_ned[1])
        lock = PadLock(after_s, PAD_DATA_FRESH_S, 0.02)
        out = m.step(
            MissionInputs(
                after_s, est(after_s, pn, pe + 0.25, -height_m), status(after_s, **flying), HOME, pad_lock=lock
            )
        )
        assert m.phase is Phase.LANDING_PAD and out.setpoint is not None
        return out.setpoint.down_m_s

    assert down_m_s(1.0) == pytest.approx(0.0)  # off-centre, in sight, time enough: holds
    assert down_m_s(last_hold_s - 0.1) == pytest.approx(0.0)
    assert down_m_s(last_hold_s + 0.1) == pytest.approx(0.5)  # no time left to hold: goes on down


def test_final_descent_settles_at_the_floor_before_the_last_part():
    """landing_settle_s = 1: the descent goes below landing_hold_min_height_m (0.5 m) only once the
    error has stayed within the tolerance (0.1 m) for 1 s with the pad in sight; until then the
    speed is proportional to the height above the floor over SETTLE_BAND_S x land speed (0.4 s x
    0.5 m/s = 0.2 m: 0.25 m/s at 0.1 m above it, climbing at 0.25 m/s 0.1 m below). Once settled
    near the floor it goes on at land speed and is not held again; blind it does not wait."""
    from companion.delivery.padlock import PAD_DATA_FRESH_S, PadLock
    from companion.guidance.descent import SETTLE_BAND_S

    assert SETTLE_BAND_S == 0.4
    c = cfg(landing_xy_tolerance_m=0.1, landing_hold_min_height_m=0.5, land_speed_m_s=0.5, landing_settle_s=1.0)
    flying = dict(armed=True, mode=FlightMode.OFFBOARD, landed=LandedState.IN_AIR)
    m = DeliveryMission(c)
    m.step(MissionInputs(0.0, est(0.0), status(0.0), HOME))
    m.enter(Phase.LANDING_PAD)
    pn, pe = float(m.pad_ned[0]), float(m.pad_ned[1])

    def down_m_s(t, offset_east_m, height_m, lock_age_s=PAD_DATA_FRESH_S):
        lock = PadLock(t, lock_age_s, 0.02)
        out = m.step(
            MissionInputs(t, est(t, pn, pe + offset_east_m, -height_m), status(t, **flying), HOME, pad_lock=lock)
        )
        assert m.phase is Phase.LANDING_PAD and out.setpoint is not None
        return out.setpoint.down_m_s

    assert down_m_s(0.05, 0.05, 2.0) == pytest.approx(0.5)  # far above the floor: not slowed
    assert down_m_s(0.10, 0.05, 0.6) == pytest.approx(0.25)  # within 0.05 s only: slowed to the floor
    assert down_m_s(0.15, 0.05, 0.5) == pytest.approx(0.0)  # at the floor: waits
    assert down_m_s(0.20, 0.05, 0.4) == pytest.approx(-0.25)  # below it: climbs back
    assert down_m_s(0.60, 0.15, 0.5) == pytest.approx(0.0)  # off: the second starts again
    assert down_m_s(0.65, 0.05, 0.5) == pytest.approx(0.0)
    assert down_m_s(1.60, 0.05, 0.5) == pytest.approx(0.0)  # 0.95 s within
    assert down_m_s(1.70, 0.05, 0.5) == pytest.approx(0.5)  # 1.05 s: settled, on down
    assert down_m_s(1.75, 0.15, 0.45) == pytest.approx(0.5)  # off again below the floor: not held again
    m2 = DeliveryMission(c)
    m2.step(MissionInputs(0.0, est(0.0), status(0.0), HOME))
    m2.enter(Phase.LANDING_PAD)
    m = m2
    assert down_m_s(0.05, 0.05, 0.5, lock_age_s=PAD_DATA_FRESH_S + 0.01) == pytest.approx(0.5)  # blind


def test_the_final_descent_feeds_its_command_rate_forward_as_an_acceleration():
    """landing_xy_accel_feedforward = c sends a = -c (k_p v + k_i e) with the velocity command, by
    hand in NED (the law is the same in every horizontal frame): 0.04 m east, moving 0.2 m/s north,
    k_p = 5, k_i = 2.5, c = 0.5: a = -0.5 (5 (0.2, 0) + 2.5 (0, 0.04)) = (-0.5, -0.05) m/s^2. None
    without the share, at the speed limit (the command's rate is not what it flies) and below the
    touchdown height (only the descent is commanded)."""
    kw = dict(landing_xy_gain_1_s=5.0, landing_xy_integral_gain_1_s2=2.5, landing_touchdown_height_m=0.15)
    m = DeliveryMission(cfg(landing_xy_accel_feedforward=0.5, **kw))
    off = DeliveryMission(cfg(**kw))
    for mk in (m, off):
        mk.step(MissionInputs(0.0, est(0.0), status(0.0), HOME))
        mk.enter(Phase.LANDING_PAD)
    pn, pe = float(m.pad_ned[0]), float(m.pad_ned[1])

    def at(mk, t, dn, de, vn, d=-2.0):
        return precision_descent(mk, StateEstimate(t, pn + dn, pe + de, d, vn, 0.0, 0.0, 0, 0, 0), Leg.OUT, t, True)

    sp = at(m, 0.0, 0.0, 0.04, 0.2)
    assert sp.accel_ne_m_s2 == pytest.approx((-0.5, -0.05), abs=1e-9)
    assert (sp.north_m_s, sp.east_m_s) == pytest.approx((at(off, 0.0, 0.0, 0.04, 0.2).north_m_s, -0.2), abs=1e-9)
    assert at(off, 0.05, 0.0, 0.04, 0.2).accel_ne_m_s2 is None
    assert at(m, 0.05, 0.0, 0.8, 0.2).accel_ne_m_s2 is None  # 4 m/s asked, 1 m/s sent
    assert at(m, 0.1, 0.0, 0.04, 0.2, d=-0.1).accel_ne_m_s2 is None


def _descent_from_far_off(m, start_north_m, lag_s=0.4, dt=0.05, ticks=160):
    """The final descent flown blind from ``start_north_m`` north of the pad by a vehicle whose
    velocity follows the setpoint with a first-order lag (exact step): its north offsets per tick."""
    pn, pe = float(m.pad_ned[0]), float(m.pad_ned[1])
    n, v, a = start_north_m, 0.0, 1.0 - math.exp(-dt / lag_s)
    track = []
    for k in range(ticks):
        t = k * dt
        sp = precision_descent(m, est(t, pn + n, pe, -3.0), Leg.OUT, t, False)
        v += a * (sp.north_m_s - v)
        n += v * dt
        track.append(n)
    return track


def test_the_integral_does_not_wind_up_while_the_command_is_at_its_speed_limit():
    """Conditional integration: 0.8 m off at k_p = 5 1/s the command sits at the 1 m/s limit, and
    the sum waits; once inside k_p's reach it sums as before. Without it the full 0.5 m/s sum built
    on the way carried the vehicle 0.3 m past the target (real PX4 SIH, GPS only)."""
    kw = dict(
        landing_xy_gain_1_s=5.0,
        landing_touchdown_height_m=-1.0,
        landing_xy_integral_gain_1_s2=2.5,
        landing_xy_integral_max_m_s=0.5,
        landing_max_xy_speed_m_s=1.0,
    )
    m = DeliveryMission(cfg(**kw))
    m.step(MissionInputs(0.0, est(0.0), status(0.0), HOME))
    m.enter(Phase.LANDING_PAD)
    pn, pe = float(m.pad_ned[0]), float(m.pad_ned[1])
    for k in range(10):  # held 0.8 m off: P alone is 4 m/s, beyond the limit
        precision_descent(m, est(k * 0.05, pn + 0.8, pe, -3.0), Leg.OUT, k * 0.05, False)
    assert m.state.descent.integral_m_s == (0.0, 0.0)
    precision_descent(m, est(0.5, pn + 0.1, pe, -3.0), Leg.OUT, 0.5, False)  # within reach: 0.5 m/s
    assert math.hypot(*m.state.descent.integral_m_s) == pytest.approx(2.5 * 0.1 * 0.05, abs=1e-9)  # (in F_I)
    # flown from 0.8 m off by a vehicle with a 0.3 s velocity lag: the sum adds no overshoot to the
    # proportional law's own (9.6 cm here; with the sum built on the way: 19.0 cm)
    tracks = []
    for ki in (0.0, 2.5):
        mk = DeliveryMission(cfg(**{**kw, "landing_xy_integral_gain_1_s2": ki}))
        mk.step(MissionInputs(0.0, est(0.0), status(0.0), HOME))
        mk.enter(Phase.LANDING_PAD)
        tracks.append(_descent_from_far_off(mk, 0.8, lag_s=0.3))
    p_only, pi = tracks
    assert -min(pi) < -min(p_only) + 0.01
    assert abs(pi[-1]) < 0.001


def _landing_after(stall_s: float, gap_s: float, mode: FlightMode, regained_ticks: int = 0):
    """A mission in its final descent over the pad (stall limit ``stall_s``), its steps then
    ``gap_s`` apart once, then ``regained_ticks`` steps 0.05 s apart flying in OFFBOARD, then the
    vehicle reported on the pad, disarmed, in ``mode``: what it asks for next."""
    m = DeliveryMission(cfg(), stall_s=stall_s)
    m.step(MissionInputs(0.0, est(0.0), status(0.0), HOME))
    m.enter(Phase.LANDING_PAD)
    pn, pe = float(m.pad_ned[0]), float(m.pad_ned[1])
    air = dict(armed=True, landed=LandedState.IN_AIR)
    t = 0.05
    m.step(MissionInputs(t, est(t, pn, pe, -2.0), status(t, mode=FlightMode.OFFBOARD, **air), HOME))
    t += gap_s
    for _ in range(regained_ticks):
        m.step(MissionInputs(t, est(t, pn, pe, -0.5), status(t, mode=FlightMode.OFFBOARD, **air), HOME))
        t += 0.05
    out = m.step(MissionInputs(t, est(t, pn, pe, 0.0), status(t, armed=False, mode=mode), HOME))
    return m, out


def test_a_touchdown_after_a_stall_is_not_the_companions_and_releases_nothing():
    """The companion stalled 15 s (beyond its 0.5 s limit: its heartbeats and setpoints were
    withheld) and finds the vehicle on the pad, disarmed, in LAND: the autopilot's failsafe landed
    it. No release, no request, autonomy ended with the kind AUTOPILOT_LANDED; the same in OFFBOARD
    (it came down on its last setpoint while nobody steered)."""
    for mode in (FlightMode.LAND, FlightMode.OFFBOARD):
        m, out = _landing_after(0.5, 15.0, mode)
        assert out.request is None and m.phase is Phase.FAILED, mode
        assert m.summary.failure_kind is FailureKind.AUTOPILOT_LANDED and not m.summary.delivered
        assert any("did not step for 15.00 s" in e.detail for e in m.summary.events)


def test_a_short_stall_the_vehicle_rode_out_in_offboard_still_delivers():
    """A 0.6 s stall, then statuses from after it with the vehicle flying in OFFBOARD for
    CONTROL_REGAINED_S (1 s): the companion is in control again, and its touchdown on the pad is its
    own (the release follows). One status in OFFBOARD is not enough: after a freeze the link's
    buffered backlog arrives stamped anew."""
    m, _ = _landing_after(0.5, 0.6, FlightMode.OFFBOARD, regained_ticks=22)
    assert m.phase is Phase.RELEASE and m.summary.failure_kind is FailureKind.NONE
    m, _ = _landing_after(0.5, 0.6, FlightMode.OFFBOARD, regained_ticks=1)
    assert m.phase is Phase.FAILED and m.summary.failure_kind is FailureKind.AUTOPILOT_LANDED


def test_a_landing_mode_the_mission_did_not_ask_for_is_not_its_touchdown():
    """No stall, no link loss, but the vehicle touched down in LAND that the mission never asked
    for (a pilot's switch it did not see armed): nothing released."""
    m, _ = _landing_after(math.inf, 0.05, FlightMode.LAND)
    assert m.phase is Phase.FAILED and m.summary.failure_kind is FailureKind.AUTOPILOT_LANDED


def test_a_touchdown_outside_the_pad_by_the_estimate_releases_nothing():
    """No pad-lock policy (GPS only), the vehicle reported on the ground 2 m from the pad's centre
    (a 1 m pad): no release, the parcel flown home (ARM for the way back); 0.4 m off: released."""
    for off_m, released in ((2.0, False), (0.4, True)):
        m = DeliveryMission(cfg())
        arm = m.step(MissionInputs(0.0, est(0.0), status(0.0), HOME)).request
        m.on_result(RequestResult(arm.id, True))  # armed: no request in flight
        m.enter(Phase.LANDING_PAD)
        pn, pe = float(m.pad_ned[0]), float(m.pad_ned[1])
        ground = status(0.05, armed=False, mode=FlightMode.OFFBOARD)
        out = m.step(MissionInputs(0.05, est(0.05, pn + off_m, pe, 0.0), ground, HOME))
        if released:
            assert m.phase is Phase.RELEASE, off_m
        else:
            assert out.request is not None and out.request.kind is RequestKind.ARM and m.phase is Phase.ARMING
            assert m.summary.failure_kind is FailureKind.NOT_DELIVERED and "outside the pad" in m.summary.failure


def test_a_touchdown_is_judged_where_the_sinking_stopped_not_where_the_estimate_drifted_after():
    """descent.contact_time_s = 0.3: the vehicle sinks onto the pad's centre and stops there; while
    the contact is being confirmed its estimate (on the ground, under the sideways command) drifts
    1.2 m off, and the autopilot reports it disarmed there. The touchdown is judged where the
    sinking stopped: released. Without the stop (the vehicle slid in the air to 1.2 m off and came
    down there) the same last estimate keeps the parcel aboard."""
    for drift_on_the_ground, released in ((True, True), (False, False)):
        c = cfg(descent=DescentConfig(touchdown_height_m=-1.0, contact_time_s=0.3), land_speed_m_s=0.7)
        m = DeliveryMission(c)
        arm = m.step(MissionInputs(0.0, est(0.0), status(0.0), HOME)).request
        m.on_result(RequestResult(arm.id, True))
        m.enter(Phase.LANDING_PAD)
        pn, pe = float(m.pad_ned[0]), float(m.pad_ned[1])
        air = status(0.0, armed=True, mode=FlightMode.OFFBOARD, landed=LandedState.IN_AIR)
        t, d = 0.05, -1.0
        off = 0.0 if drift_on_the_ground else 1.2
        while d < 0.0:  # sinking at 0.7 m/s onto the ground
            m.step(MissionInputs(t, StateEstimate(t, pn + off, pe, d, 0, 0, 0.7, 0, 0, 0), air, HOME))
            t, d = t + 0.05, d + 0.035
        for i in range(12):  # stopped: the estimate drifts 0.1 m a tick (only on the ground)
            n = pn + (0.1 * (i + 1) if drift_on_the_ground else off)
            m.step(MissionInputs(t, StateEstimate(t, n, pe, 0.0, 0, 0, 0.0, 0, 0, 0), air, HOME))
            t += 0.05
        ground = status(t, armed=False, mode=FlightMode.OFFBOARD)
        m.step(MissionInputs(t, StateEstimate(t, pn + 1.2, pe, 0.0, 0, 0, 0.0, 0, 0, 0), ground, HOME))
        assert (m.phase is Phase.RELEASE) is released, (drift_on_the_ground, m.summary.failure)


def test_after_a_stall_past_the_offboard_timeout_control_is_not_regained():
    """A 15 s freeze: PX4's LAND failsafe brought the vehicle down, then handed OFFBOARD back when
    the setpoints resumed (CI, 2026-12-04: OFFBOARD again at +15.5 s, the vehicle on the ground since
    +12.2 s, and the companion released). However long OFFBOARD is seen afterwards, the touchdown is
    not the companion's: nothing released. A stall shorter than 1 s still regains control."""
    m, _ = _landing_after(0.5, 15.0, FlightMode.OFFBOARD, regained_ticks=60)
    assert m.phase is Phase.FAILED and m.summary.failure_kind is FailureKind.AUTOPILOT_LANDED
    assert not m.summary.delivered
    m, _ = _landing_after(0.5, 0.9, FlightMode.OFFBOARD, regained_ticks=22)
    assert m.phase is Phase.RELEASE

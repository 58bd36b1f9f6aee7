"""How the mission treats the autopilot's answers: one retry path, permanent refusals never
resent, a failed release handled once (fly home with the parcel, or stay), no request storms.

The firmware answers these tests model are those of PX4 v1.16 SIH and ArduCopter 4.7 SITL:
PX4 answers DO_SET_SERVO with UNSUPPORTED and refuses to arm in the mode a landing leaves;
ArduCopter answers DO_GRIPPER with FAILED while GRIP_ENABLE = 0.
"""

import itertools
import math

from companion.autopilot.types import FlightMode, HomePosition, LandedState, VehicleStatus
from companion.config import MissionConfig, PadConfig
from companion.delivery.mission import (
    MAX_REQUEST_TRIES,
    REQUEST_RETRY_DELAY_S,
    DeliveryMission,
    Leg,
    MissionInputs,
    RequestKind,
    RequestResult,
)
from companion.delivery.mission.phases import DISARM_REPEAT_S, after_touchdown
from companion.estimation.types import StateEstimate
from companion.events import EventKind, Phase

HOME = HomePosition(0.0, -19.869, -43.9638, 850.0)
DT = 0.05  # the guidance rate


def est(t, n=0.0, e=0.0, d=0.0):
    return StateEstimate(t, n, e, d, 0, 0, 0, 0, 0, 0)


def status(t, armed=False, mode=FlightMode.HOLD, landed=LandedState.ON_GROUND, released=False):
    return VehicleStatus(t, armed, mode, landed, True, 90.0, released)


def on_the_pad(**kw) -> tuple[DeliveryMission, float]:
    """A mission that has flown out and touched down on the pad, now in RELEASE."""
    m = DeliveryMission(MissionConfig(pad=PadConfig(north_m=60.0, east_m=80.0), **kw))
    req = m.step(MissionInputs(0.0, est(0.0), status(0.0), HOME)).request
    assert req is not None and req.kind is RequestKind.ARM
    m.on_result(RequestResult(req.id, True))
    after_touchdown(m, Leg.OUT)  # the flight itself is covered by the whole-mission tests
    assert m.phase is Phase.RELEASE
    return m, 0.0


def run(m, t, seconds, answer, st=None):
    """Tick at 20 Hz for ``seconds``, answering every request with ``answer(req)``; the requests."""
    reqs = []
    end = t + seconds
    while t < end and not m.phase.terminal:
        t += DT
        out = m.step(MissionInputs(t, est(t, 60.0, 80.0), st(t) if st else status(t), HOME))
        if out.request is not None:
            reqs.append((t, out.request))
            res = answer(out.request)
            if res is not None:
                m.on_result(res)
    return t, reqs


def refuse(result_ok_kinds=(), permanent=True, error="release (gripper): FAILED"):
    def answer(req):
        if req.kind in result_ok_kinds:
            return RequestResult(req.id, True)
        return RequestResult(req.id, False, error, permanent)

    return answer


def test_a_permanent_release_refusal_is_sent_once_then_the_vehicle_flies_home_with_the_parcel():
    m, t = on_the_pad()
    t, reqs = run(m, t, 10.0, refuse(result_ok_kinds=(RequestKind.ARM, RequestKind.TAKEOFF)))
    releases = [r for _, r in reqs if r.kind is RequestKind.RELEASE]
    assert len(releases) == 1  # not 20 Hz forever
    assert m.phase is Phase.TAKEOFF_RETURN  # re-armed for the return leg, not the outbound one
    assert not m.summary.delivered
    assert "parcel not released" in m.summary.failure and "FAILED" in m.summary.failure
    warnings = [e for e in m.summary.events if e.kind is EventKind.WARNING and "parcel not released" in e.detail]
    assert len(warnings) == 1 and "flying home with the parcel" in warnings[0].detail
    failed = [e for e in m.summary.events if e.kind is EventKind.REQUEST_FAILED]
    assert len(failed) == 1 and "try 1 of 3, not retried" in failed[0].detail


def test_on_release_failure_stay_ends_the_mission_disarmed_on_the_pad():
    m, t = on_the_pad(on_release_failure="stay")
    t, reqs = run(m, t, 10.0, refuse())
    assert [r.kind for _, r in reqs] == [RequestKind.RELEASE]
    assert m.phase is Phase.FAILED
    assert m.summary.failure.startswith("parcel not released: release refused: release (gripper): FAILED")


def test_a_temporary_refusal_is_retried_on_the_one_retry_path_then_given_up():
    m, t = on_the_pad(on_release_failure="stay")
    t, reqs = run(m, t, 10.0, refuse(permanent=False, error="release: TEMPORARILY_REJECTED"))
    times = [tr for tr, r in reqs if r.kind is RequestKind.RELEASE]
    assert len(times) == MAX_REQUEST_TRIES
    assert all(b - a >= REQUEST_RETRY_DELAY_S - 1e-9 for a, b in itertools.pairwise(times))
    tries = [e.detail for e in m.summary.events if e.kind is EventKind.REQUEST_FAILED]
    assert [d.split(")")[0] for d in tries] == ["release (try 1 of 3", "release (try 2 of 3", "release (try 3 of 3"]
    assert m.phase is Phase.FAILED and "failed 3 times" in m.summary.failure


def test_an_unanswered_release_is_not_resent_while_it_is_in_flight():
    m, t = on_the_pad()
    t, reqs = run(m, t, 5.0, lambda req: None)  # the autopilot never answers
    assert len(reqs) == 1 and reqs[0][1].kind is RequestKind.RELEASE


def test_a_released_parcel_still_reported_attached_takes_the_release_failure_path():
    m, t = on_the_pad(release_time_s=1.0)
    t, reqs = run(m, t, 5.0, refuse(result_ok_kinds=(RequestKind.RELEASE, RequestKind.ARM, RequestKind.TAKEOFF)))
    assert [r.kind for _, r in reqs][:2] == [RequestKind.RELEASE, RequestKind.ARM]
    assert m.phase is Phase.TAKEOFF_RETURN
    assert "still attached" in m.summary.failure and not m.summary.delivered


def test_a_permanent_arm_refusal_fails_at_once_with_the_autopilots_answer():
    m = DeliveryMission(MissionConfig(pad=PadConfig(north_m=60.0, east_m=80.0)))
    req = m.step(MissionInputs(0.0, est(0.0), status(0.0), HOME)).request
    m.on_result(RequestResult(req.id, False, "arm: DENIED (Arming denied: switch to a manual mode)", True))
    _, reqs = run(m, 0.0, 5.0, refuse())
    assert reqs == []
    assert m.phase is Phase.FAILED and "arm refused: arm: DENIED" in m.summary.failure


def test_disarm_after_touchdown_is_asked_once_and_again_only_if_the_vehicle_stays_armed():
    m, t = on_the_pad()
    m.enter(Phase.LANDING_HOME)  # touched down at home, still armed

    def landed_armed(t):
        return status(t, armed=True, mode=FlightMode.OFFBOARD, landed=LandedState.ON_GROUND)

    t, reqs = run(m, t, 3 * DISARM_REPEAT_S - 0.01, refuse(result_ok_kinds=(RequestKind.DISARM,)), landed_armed)
    kinds = [r.kind for _, r in reqs]
    assert kinds == [RequestKind.DISARM] * 3  # at 0, 2 and 4 s: not 20 Hz
    t, _ = run(m, t, 0.2, refuse(), lambda t: status(t, landed=LandedState.ON_GROUND))
    assert m.phase is Phase.DONE and m.summary.returned


def test_the_touchdown_timeout_hands_over_to_land_once():
    m, t = on_the_pad()
    m.enter(Phase.LANDING_HOME)

    def hovering(t):
        return status(t, armed=True, mode=FlightMode.OFFBOARD, landed=LandedState.IN_AIR)

    t, reqs = run(m, t, m.cfg.touchdown_timeout_s + 5.0, refuse(result_ok_kinds=(RequestKind.LAND,)), hovering)
    assert [r.kind for _, r in reqs] == [RequestKind.LAND]
    warnings = [e for e in m.summary.events if "no touchdown in time" in e.detail]
    assert len(warnings) == 1


def test_the_pad_is_placed_from_home_in_the_autopilots_local_frame():
    """PX4's local origin (the EKF origin) need not be home: HOME_POSITION's x/y/z say where home
    is, and the pad's offsets start there."""
    home = HomePosition(0.0, -19.869, -43.9638, 850.0, north_m=15.0, east_m=-7.0, down_m=0.1)
    m = DeliveryMission(MissionConfig(pad=PadConfig(north_m=60.0, east_m=80.0)))
    m.step(MissionInputs(0.0, est(0.0, 15.0, -7.0, 0.1), status(0.0), home))
    assert m.frame is not None and m.path is not None
    assert math.isclose(m.path.d, 100.0, rel_tol=1e-9)
    assert [round(float(v), 9) for v in m.frame.pad_ned] == [75.0, 73.0, 0.1]


def test_takeoff_counts_as_done_once_the_autopilot_holds_in_the_air_short_of_our_90_percent():
    """PX4 climbs to the takeoff height by its own altitude; ours can read 0.2-0.3 m lower."""
    m, t = on_the_pad()
    m.enter(Phase.TAKEOFF_RETURN)
    m.state.requested = True
    climbing = status(t, armed=True, mode=FlightMode.TAKEOFF, landed=LandedState.IN_AIR)
    alt = 0.85 * m.cfg.takeoff_alt_m
    out = m.step(MissionInputs(t + DT, est(t + DT, 60.0, 80.0, -alt), climbing, HOME))
    assert out.setpoint is None  # still the autopilot's takeoff
    holding = status(t, armed=True, mode=FlightMode.HOLD, landed=LandedState.IN_AIR)
    out = m.step(MissionInputs(t + 2 * DT, est(t + 2 * DT, 60.0, 80.0, -alt), holding, HOME))
    assert out.setpoint is not None  # the field takes over


def test_the_field_stream_goes_on_when_the_mode_leaves_hold_for_offboard_short_of_our_90_percent():
    """PX4 SIH can finish a take-off while our height reads short of 90 % of it. The field takes
    over in HOLD and asks for OFFBOARD, and the stream must not stop when HOLD ends, or PX4's
    offboard-loss failsafe lands the vehicle and the return is aborted."""
    m, t = on_the_pad()
    m.enter(Phase.TAKEOFF_RETURN)
    m.state.requested = True
    alt = 0.55 * m.cfg.takeoff_alt_m  # above the HOLD test's half, short of 90 %
    holding = status(t, armed=True, mode=FlightMode.HOLD, landed=LandedState.IN_AIR)
    offboard = status(t, armed=True, mode=FlightMode.OFFBOARD, landed=LandedState.IN_AIR)
    switched, ticks = False, 0
    while m.phase is Phase.TAKEOFF_RETURN and ticks < 200:
        t += DT
        ticks += 1
        out = m.step(MissionInputs(t, est(t, 60.0, 80.0, -alt), offboard if switched else holding, HOME))
        assert out.setpoint is not None, f"the stream stopped at tick {ticks} ({'OFFBOARD' if switched else 'HOLD'})"
        if out.request is not None:
            assert out.request.kind is RequestKind.START_OFFBOARD
            m.on_result(RequestResult(out.request.id, True))
            switched = True
    assert switched and m.phase is Phase.INBOUND


def _armed_for_return(m, t, n, e):
    """Tick RELEASE -> ARMING -> TAKEOFF_RETURN with the vehicle on the ground at (n, e)."""
    released = lambda tt: status(tt, released=True)  # noqa: E731
    while m.phase is not Phase.TAKEOFF_RETURN:
        t += DT
        out = m.step(MissionInputs(t, est(t, n, e), released(t), HOME))
        if out.request is not None:
            m.on_result(RequestResult(out.request.id, True))
    out = m.step(MissionInputs(t + DT, est(t + DT, n, e), status(t, armed=True), HOME))
    return out


def test_the_way_home_is_planned_from_where_the_vehicle_landed():
    """Landed 1.5 m from the configured pad (the pad as the camera found it): the return path starts
    there, so the climb goes straight up instead of sideways onto the outbound path."""
    m, t = on_the_pad()
    planned_pad = m.frame.pad_ned.copy() if m.frame is not None else None
    assert planned_pad is not None
    home_d = m.path.d
    landed = (planned_pad[0] + 1.2, planned_pad[1] - 0.9)
    out = _armed_for_return(m, t, *landed)
    assert m.frame.pad_ned[0] == landed[0] and m.frame.pad_ned[1] == landed[1]
    assert m.frame.pad_ned[2] == planned_pad[2]  # the ground at the pad's level
    # home sits at x = -d, y = 0 of the new frame: same home, new length
    home = m.frame.point_from_ned(m.start_ned)
    assert abs(home[0] + m.path.d) < 1e-9 and abs(home[1]) < 1e-9
    assert abs(m.path.d - math.hypot(landed[0], landed[1] - 0.0)) < 1e-9  # the start was (0, 0)
    assert m.path.d != home_d
    # on the ground at the landing point the vehicle is on the new path (sector 5, the descent line)
    assert m.path.distance_to_path(m.frame.point_from_ned([landed[0], landed[1], planned_pad[2]])) < 1e-9
    assert any("return path planned from the landing point (1.50 m" in ev.detail for ev in m.summary.events)
    assert out.phase is Phase.TAKEOFF_RETURN


def test_the_papers_return_along_the_outbound_path_is_kept_as_an_option():
    m, t = on_the_pad(return_from_landing_point=False)
    frame = m.frame
    _armed_for_return(m, t, frame.pad_ned[0] + 1.2, frame.pad_ned[1] - 0.9)
    assert m.frame is frame

"""Never release onto an occupied pad (companion.delivery.mission.dropzone, docs/drop-zone.md):
the drop-zone verdict stops the descent at the approach height or in it, the hold waits hold_s,
a clear pad resumes the descent, a pad still occupied sends the vehicle to the alternate or home
with the parcel, and a touchdown on an occupied pad releases nothing; each an event."""

from __future__ import annotations

import pytest

from companion.autopilot.types import FlightMode, LandedState
from companion.config import DropZoneConfig, PadConfig, PadLockPolicyConfig
from companion.delivery.gcs import SEVERITY_WARNING, event_severity
from companion.delivery.mission import DeliveryMission, MissionInputs, RequestKind, RequestResult
from companion.delivery.padlock import PadLock
from companion.events import EventKind, Phase
from companion.vision.drop_zone import DropZoneVerdict

from .test_mission import HOME, cfg, est, status

POLICY = PadLockPolicyConfig(hold_s=2.0, search_radius_m=0.0)
DZ = DropZoneConfig(enabled=True, hold_s=3.0)
PAD = (60.0, 80.0)
LOCKED = PadLock(0.0, 0.1, 0.05)
CLEAR, OCC, MOVE = DropZoneVerdict.CLEAR, DropZoneVerdict.OCCUPIED, DropZoneVerdict.MOTION_IN_MARGIN


def _at_approach(drop_zone=DZ, policy=POLICY, mission_cfg=None):
    """A mission in OUTBOUND, the vehicle about to be reported under the approach height."""
    m = DeliveryMission(mission_cfg or cfg(), pad_policy=policy, drop_zone=drop_zone)
    t = 0.0
    m.on_result(RequestResult(m.step(MissionInputs(t, est(t), status(t), HOME)).request.id, True))
    out = m.step(MissionInputs(t, est(t), status(t, armed=True), HOME))
    m.on_result(RequestResult(out.request.id, True))
    mode = FlightMode.TAKEOFF
    while m.phase is not Phase.OUTBOUND:
        t += 0.05
        out = m.step(
            MissionInputs(t, est(t, d=-3.0), status(t, armed=True, mode=mode, landed=LandedState.IN_AIR), HOME)
        )
        if out.request is not None:
            m.on_result(RequestResult(out.request.id, True))
            mode = FlightMode.OFFBOARD
    return m, t


def _fly(m, t, verdict, n, e, d, landed=LandedState.IN_AIR, armed=True):
    st = status(t, armed=armed, mode=FlightMode.OFFBOARD, landed=landed)
    return m.step(MissionInputs(t, est(t, n, e, d), st, HOME, pad_lock=LOCKED, drop_zone=verdict))


def _dz_events(m):
    return [e.detail for e in m.summary.events if e.kind is EventKind.DROP_ZONE]


def test_a_clear_pad_descends_and_the_check_off_changes_nothing():
    m, t = _at_approach()
    _fly(m, t + 0.05, CLEAR, *PAD, -2.5)
    assert m.phase is Phase.LANDING_PAD and not _dz_events(m)
    # the check off: an occupied verdict is not looked at
    m, t = _at_approach(drop_zone=DropZoneConfig(enabled=False))
    _fly(m, t + 0.05, OCC, *PAD, -2.5)
    assert m.phase is Phase.LANDING_PAD


def test_an_occupied_pad_holds_then_clears_and_the_descent_resumes():
    m, t = _at_approach()
    t += 0.05
    _fly(m, t, OCC, *PAD, -2.5)
    assert m.phase is Phase.DROP_ZONE_HOLD
    assert "an object on the pad at the approach height: descent stopped" in _dz_events(m)[0]
    out = _fly(m, t + 0.05, OCC, PAD[0] + 0.5, PAD[1], -2.5)
    assert out.setpoint is not None and out.setpoint.north_m_s < 0  # back to where the hold began
    _fly(m, t + 1.0, CLEAR, *PAD, -2.5)
    assert m.phase is Phase.PAD_HOLD and "clear after holding" in _dz_events(m)[1]
    _fly(m, t + 1.05, CLEAR, *PAD, -3.0)
    assert m.phase is Phase.LANDING_PAD


def test_motion_in_the_descent_stops_it_above_the_commit_height():
    m, t = _at_approach()
    _fly(m, t + 0.05, CLEAR, *PAD, -2.5)
    assert m.phase is Phase.LANDING_PAD
    _fly(m, t + 0.1, MOVE, *PAD, -2.0)
    assert m.phase is Phase.DROP_ZONE_HOLD
    assert "motion in the pad's margin in the descent at 2.0 m" in _dz_events(m)[0]


def test_still_occupied_after_the_hold_flies_home_with_the_parcel():
    m, t = _at_approach()
    t += 0.05
    _fly(m, t, OCC, *PAD, -2.5)
    t0 = t
    while m.phase is Phase.DROP_ZONE_HOLD and t < t0 + 10:
        t += 0.05
        _fly(m, t, OCC, *PAD, -2.5)
    assert m.phase is Phase.INBOUND and t - t0 == pytest.approx(DZ.hold_s, abs=0.06)
    assert "drop zone not clear after holding 3 s (occupied)" in _dz_events(m)[-1]
    assert m.summary.failure.startswith("parcel not delivered: drop zone not clear")
    assert all(e.kind is not EventKind.RELEASED for e in m.summary.events)
    ev = next(e for e in m.summary.events if e.kind is EventKind.DROP_ZONE)
    assert event_severity(ev) == SEVERITY_WARNING  # the GCS gets it as a warning


def test_still_occupied_with_an_alternate_diverts():
    alternate = PadConfig(north_m=90.0, east_m=80.0)
    mc = cfg().model_copy(update={"alternate_pad": alternate})
    m, t = _at_approach(
        policy=PadLockPolicyConfig(hold_s=2.0, search_radius_m=0.0, fallback="alternate"), mission_cfg=mc
    )
    t += 0.05
    _fly(m, t, OCC, *PAD, -2.5)
    t0 = t
    while m.phase is Phase.DROP_ZONE_HOLD and t < t0 + 10:
        t += 0.05
        _fly(m, t, OCC, *PAD, -2.5)
    assert m.phase is Phase.DIVERT and m.summary.diverted


def test_a_touchdown_on_a_pad_judged_occupied_releases_nothing():
    m, t = _at_approach()
    _fly(m, t + 0.05, CLEAR, *PAD, -2.5)
    _fly(m, t + 0.1, OCC, *PAD, -0.5)  # below the commit height: no stop, judged at touchdown
    assert m.phase is Phase.LANDING_PAD
    out = _fly(m, t + 0.15, DropZoneVerdict.UNKNOWN, *PAD, 0.0, landed=LandedState.ON_GROUND)
    assert out.request.kind is RequestKind.DISARM
    m.on_result(RequestResult(out.request.id, True))
    out = _fly(m, t + 0.2, DropZoneVerdict.UNKNOWN, *PAD, 0.0, landed=LandedState.ON_GROUND, armed=False)
    assert out.request is not None and out.request.kind is RequestKind.ARM
    assert "drop zone occupied at touchdown" in m.summary.failure
    assert all(e.kind is not EventKind.RELEASED for e in m.summary.events)


def test_without_a_pad_lock_policy_the_check_still_stops_and_resumes():
    m, t = _at_approach(policy=PadLockPolicyConfig(require_pad_lock=False))
    _fly(m, t + 0.05, OCC, *PAD, -2.5)
    assert m.phase is Phase.DROP_ZONE_HOLD
    _fly(m, t + 0.5, CLEAR, *PAD, -2.5)
    assert m.phase is Phase.LANDING_PAD


@pytest.mark.parametrize("verdict", [DropZoneVerdict.UNKNOWN, None])
def test_the_descent_starts_only_on_a_pad_seen_clear(verdict):
    """Unknown (the camera has not judged the pad, or no verdict at all): no evidence that nothing
    is there. The vehicle holds at the approach height; seen clear, it descends; never seen
    clear within hold_s, the parcel flies home."""
    m, t = _at_approach()
    t += 0.05
    _fly(m, t, verdict, *PAD, -2.5)
    assert m.phase is Phase.DROP_ZONE_HOLD
    assert _dz_events(m)[0].startswith("the drop zone not judged clear yet at the approach height: descent stopped")
    _fly(m, t + 0.5, CLEAR, *PAD, -2.5)
    assert m.phase is Phase.PAD_HOLD
    _fly(m, t + 0.55, CLEAR, *PAD, -3.0)
    assert m.phase is Phase.LANDING_PAD
    # never judged clear
    m, t = _at_approach()
    t += 0.05
    t0 = t
    while t < t0 + 10 and m.phase in (Phase.OUTBOUND, Phase.DROP_ZONE_HOLD):
        _fly(m, t, verdict, *PAD, -2.5)
        t += 0.05
    assert m.phase is Phase.INBOUND
    assert "drop zone not clear after holding 3 s" in _dz_events(m)[-1]
    assert all(e.kind is not EventKind.RELEASED for e in m.summary.events)
    # once below the approach height an unknown verdict goes on (the camera abstains near the pad)
    m, t = _at_approach()
    _fly(m, t + 0.05, CLEAR, *PAD, -2.5)
    _fly(m, t + 0.1, verdict, *PAD, -2.0)
    assert m.phase is Phase.LANDING_PAD

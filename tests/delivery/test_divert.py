"""Divert to the alternate pad (landing.policy.fallback = "alternate", docs/delivery-policy.md):
the configuration's checks and the mission's steps, on synthetic inputs."""

import math

import pytest

from companion.autopilot.types import FlightMode, LandedState, VehicleStatus
from companion.config import ConfigError, MissionConfig, PadConfig, PadLockPolicyConfig
from companion.config import shipped_params_path as shipped
from companion.delivery.mission import (
    DeliveryMission,
    MissionInputs,
    MissionOutput,
    Request,
    RequestKind,
    RequestResult,
)
from companion.delivery.padlock import NO_SENSORS
from companion.events import EventKind, Phase
from companion_sitl.params import load_simulated_config

from .test_mission import HOME, est, status
from .test_padlock import LOCKED, PAD, STALE, _fly

ALT = (60.0, 110.0)  # the alternate pad, 30 m east of the first
DIVERT = PadLockPolicyConfig(hold_s=1.0, search_radius_m=0.0, descent_tries=1, fallback="alternate")


def _cfg() -> MissionConfig:
    return MissionConfig(
        pad=PadConfig(north_m=PAD[0], east_m=PAD[1]), alternate_pad=PadConfig(north_m=ALT[0], east_m=ALT[1])
    )


def _req(out: MissionOutput) -> Request:
    assert out.request is not None
    return out.request


def _mission(policy: PadLockPolicyConfig = DIVERT) -> tuple[DeliveryMission, float]:
    """A mission in OUTBOUND (as test_padlock._at_approach, with the alternate pad configured)."""
    m = DeliveryMission(_cfg(), pad_policy=policy)
    t = 0.0
    m.on_result(RequestResult(_req(m.step(MissionInputs(t, est(t), status(t), HOME))).id, True))
    out = m.step(MissionInputs(t, est(t), status(t, armed=True), HOME))
    m.on_result(RequestResult(_req(out).id, True))
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


def _fail_first_pad(m: DeliveryMission, t: float) -> float:
    """No lock at the approach height over the first pad: its one try fails."""
    t += 0.05
    _fly(m, t, STALE, *PAD, -2.5)
    return t


def _pad_lock_details(m: DeliveryMission) -> list[str]:
    return [e.detail for e in m.summary.events if e.kind is EventKind.PAD_LOCK]


def test_fallback_alternate_needs_the_alternate_pad() -> None:
    with pytest.raises(ConfigError, match=r"landing\.policy\.fallback = 'alternate' needs mission\.alternate_pad"):
        load_simulated_config(
            shipped("delivery_paper.toml"), overrides={"landing": {"policy": {"fallback": "alternate"}}}
        )
    with pytest.raises(ConfigError, match=r"sim\.pad_at_alternate = true needs mission\.alternate_pad"):
        load_simulated_config(shipped("delivery_paper.toml"), overrides={"sim": {"pad_at_alternate": True}})
    c = load_simulated_config(
        shipped("delivery_paper.toml"),
        overrides={
            "landing": {"policy": {"fallback": "alternate"}},
            "mission": {"alternate_pad": {"north_m": 40.0, "east_m": 30.0}},
        },
    )
    assert c.landing.policy.fallback == "alternate" and c.mission.alternate_pad is not None
    with pytest.raises(ConfigError, match="fallback"):
        load_simulated_config(
            shipped("delivery_paper.toml"), overrides={"landing": {"policy": {"fallback": "anywhere"}}}
        )


def test_an_alternate_pad_outside_the_fence_is_refused() -> None:
    fence = {
        "enabled": True,
        "inclusion": [{"vertices_deg": [[-19.87, -43.965], [-19.87, -43.962], [-19.867, -43.962], [-19.867, -43.965]]}],
    }
    base = shipped("landing_campaign.toml")
    inside = {"lat_deg": -19.8686, "lon_deg": -43.9637}
    assert load_simulated_config(
        base, overrides={"fence": fence, "mission": {"alternate_pad": inside}}
    ).mission.alternate_pad
    with pytest.raises(ConfigError, match=r"mission\.alternate_pad"):
        load_simulated_config(
            base, overrides={"fence": fence, "mission": {"alternate_pad": {"lat_deg": -19.86, "lon_deg": -43.9637}}}
        )


def test_the_last_failed_try_diverts_to_the_alternate_and_lands_there_locked() -> None:
    m, t = _mission()
    t = _fail_first_pad(m, t)
    assert m.phase is Phase.DIVERT and m.pad_index == 1 and m.summary.diverted
    assert m.frame is not None and m.path is not None
    assert (m.frame.pad_ned[0], m.frame.pad_ned[1]) == ALT and m.path.d == pytest.approx(30.0)
    assert m.pad_ned is not None and tuple(m.pad_ned[:2]) == ALT
    details = _pad_lock_details(m)
    assert "try 1 of 1 failed" in details[-2] and "diverting to the alternate pad, 30.0 m away" in details[-1]
    assert not m.summary.failure
    # the divert climbs first (sector 1 of its path: straight up over the first pad)
    out = _fly(m, t + 0.05, STALE, *PAD, -3.0)
    assert (
        out.setpoint is not None
        and out.setpoint.down_m_s < -0.5
        and math.hypot(out.setpoint.north_m_s, out.setpoint.east_m_s) < 0.5
    )
    _land_release_take_off(m, t + 0.1)


def _land_release_take_off(m: DeliveryMission, t: float) -> None:
    """Over the alternate under the approach height, locked: the descent, the release there, and
    the take-off for home, whose path starts at the alternate."""
    _fly(m, t, LOCKED, *ALT, -2.5)
    assert m.phase is Phase.LANDING_PAD
    out = _fly(m, t + 0.05, LOCKED, ALT[0], ALT[1], 0.0, landed=LandedState.ON_GROUND)
    m.on_result(RequestResult(_req(out).id, True))  # disarm
    _fly(m, t + 0.1, LOCKED, ALT[0], ALT[1], 0.0, landed=LandedState.ON_GROUND, armed=False)
    assert m.phase is Phase.RELEASE
    out = _fly(m, t + 0.15, LOCKED, ALT[0], ALT[1], 0.0, landed=LandedState.ON_GROUND, armed=False)
    assert _req(out).kind is RequestKind.RELEASE
    m.on_result(RequestResult(_req(out).id, True))
    t += 0.2 + m.cfg.release_time_s
    st = VehicleStatus(t, False, FlightMode.HOLD, LandedState.ON_GROUND, True, 90.0, True)  # parcel gone
    out = m.step(MissionInputs(t, est(t, ALT[0], ALT[1], 0.0), st, HOME, pad_lock=LOCKED))
    assert m.summary.delivered and "parcel released on the alternate pad" in m.summary.events[-2].detail
    m.on_result(RequestResult(_req(out).id, True))  # arm for the way home
    assert m.phase is Phase.TAKEOFF_RETURN
    st = VehicleStatus(t + 0.05, True, FlightMode.TAKEOFF, LandedState.IN_AIR, True, 90.0, True)
    m.step(MissionInputs(t + 0.05, est(t + 0.05, ALT[0], ALT[1], -0.5), st, HOME, pad_lock=LOCKED))
    assert m.path is not None and m.path.d == pytest.approx(math.hypot(*ALT))  # alternate -> home
    assert m.frame is not None and tuple(m.frame.pad_ned[:2]) == pytest.approx(ALT)


def test_no_lock_on_the_alternate_either_flies_home_with_the_parcel() -> None:
    m, t = _mission()
    t = _fail_first_pad(m, t)
    assert m.phase is Phase.DIVERT
    t += 0.05
    _fly(m, t, STALE, *ALT, -2.5)  # the same policy on the alternate: its try 1 of 1 fails
    assert "try 1 of 1 failed: no pad lock at the approach height" in _pad_lock_details(m)[-2]
    assert m.phase is Phase.INBOUND and m.summary.pad_tries == 2
    assert m.summary.failure == "parcel not delivered: 1 tries without a pad lock on the alternate pad"
    # the way home is planned from over the alternate to home (not back to the first pad)
    out = _fly(m, t + 0.05, STALE, *ALT, -3.0)
    assert m.path is not None and m.path.d == pytest.approx(math.hypot(*ALT))
    assert m.frame is not None and tuple(m.frame.pad_ned[:2]) == ALT
    assert out.setpoint is not None and out.setpoint.down_m_s < 0  # climbing out over the alternate
    assert not any(e.kind is EventKind.RELEASED for e in m.summary.events)


def test_a_touchdown_without_lock_takes_off_again_and_diverts() -> None:
    m, t = _mission(DIVERT.model_copy(update={"descent_tries": 2}))
    _fly(m, t + 0.05, LOCKED, *PAD, -2.5)
    assert m.phase is Phase.LANDING_PAD
    out = _fly(m, t + 0.1, STALE, *PAD, 0.0, landed=LandedState.ON_GROUND)
    m.on_result(RequestResult(out.request.id, True))  # disarm
    out = _fly(m, t + 0.15, STALE, *PAD, 0.0, landed=LandedState.ON_GROUND, armed=False)
    assert out.request is not None and out.request.kind is RequestKind.ARM
    assert "taking off to divert to the alternate pad" in _pad_lock_details(m)[-1]
    m.on_result(RequestResult(out.request.id, True))
    assert m.phase is Phase.TAKEOFF_RETURN
    t += 0.2
    mode = FlightMode.HOLD
    while m.phase is Phase.TAKEOFF_RETURN and t < 60:
        t += 0.05
        st = status(t, armed=True, mode=mode, landed=LandedState.IN_AIR)
        out = m.step(MissionInputs(t, est(t, PAD[0], PAD[1], -3.0), st, HOME, pad_lock=STALE))
        if out.request is not None:
            m.on_result(RequestResult(out.request.id, True))
            mode = FlightMode.OFFBOARD
    assert m.phase is Phase.DIVERT and m.pad_index == 1 and not m.summary.delivered
    assert m.frame is not None and tuple(m.frame.pad_ned[:2]) == ALT
    _land_release_take_off(m, t + 0.05)


def test_without_pad_sensors_there_is_no_divert() -> None:
    m, t = _mission()
    _fly(m, t + 0.05, NO_SENSORS, *PAD, -2.5)
    assert m.phase is Phase.INBOUND and m.pad_index == 0 and not m.summary.diverted


def test_an_alternate_too_close_to_divert_to_goes_home_saying_why() -> None:
    cfg = _cfg().model_copy(update={"alternate_pad": PadConfig(north_m=PAD[0] + 3.0, east_m=PAD[1])})
    m = DeliveryMission(cfg, pad_policy=DIVERT)
    t = 0.0
    m.on_result(RequestResult(_req(m.step(MissionInputs(t, est(t), status(t), HOME))).id, True))
    out = m.step(MissionInputs(t, est(t), status(t, armed=True), HOME))
    m.on_result(RequestResult(_req(out).id, True))
    mode = FlightMode.TAKEOFF
    while m.phase is not Phase.OUTBOUND:
        t += 0.05
        out = m.step(
            MissionInputs(t, est(t, d=-3.0), status(t, armed=True, mode=mode, landed=LandedState.IN_AIR), HOME)
        )
        if out.request is not None:
            m.on_result(RequestResult(out.request.id, True))
            mode = FlightMode.OFFBOARD
    _fail_first_pad(m, t)
    assert m.phase is Phase.INBOUND and m.pad_index == 0
    assert "cannot divert to the alternate pad (start-pad distance d = 3.00 m" in _pad_lock_details(m)[-2]

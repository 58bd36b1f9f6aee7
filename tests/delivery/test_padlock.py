"""No release off the pad (docs/delivery-policy.md): the lock's rules, the search pattern, and the
mission's steps, on synthetic inputs."""

import math

import numpy as np
import pytest

from companion.autopilot.types import FlightMode, LandedState
from companion.config import ConfigError, PadLockPolicyConfig, load_config, shipped_params_path
from companion.delivery.mission import DeliveryMission, MissionInputs, RequestKind, RequestResult
from companion.delivery.padlock import NO_SENSORS, PadLock, expanding_square, horizontal_sigma_m, judge_pad_lock
from companion.events import EventKind, Phase

from .test_mission import HOME, cfg, est, status

POLICY = PadLockPolicyConfig(hold_s=2.0, search_radius_m=4.0, search_spacing_m=2.0, search_dwell_s=0.0)
PAD = (60.0, 80.0)
LOCKED = PadLock(0.0, 0.1, 0.05)
STALE = PadLock(0.0, 5.0, 0.05)


def test_a_lock_needs_a_recent_observation_and_a_small_sigma():
    assert judge_pad_lock(LOCKED, POLICY)[0]
    ok, why = judge_pad_lock(STALE, POLICY)
    assert not ok and "5.00 s old (limit 2.0 s)" in why
    ok, why = judge_pad_lock(PadLock(0.0, 0.1, 0.4), POLICY)
    assert not ok and "1-sigma 0.40 m (limit 0.25 m)" in why
    ok, why = judge_pad_lock(PadLock(0.0, math.inf, math.inf), POLICY)
    assert not ok and "no camera or UWB observation" in why
    assert not judge_pad_lock(NO_SENSORS, POLICY)[0] and not judge_pad_lock(None, POLICY)[0]


def test_horizontal_sigma_is_the_largest_axis_of_the_north_east_block():
    rng = np.random.default_rng(1)
    for _ in range(20):
        a = rng.normal(size=(4, 4))
        P = a @ a.T
        want = math.sqrt(np.linalg.eigvalsh(P[:2, :2]).max())
        assert horizontal_sigma_m(P) == pytest.approx(want, rel=1e-12)
    assert horizontal_sigma_m(np.full((2, 2), np.nan)) == math.inf


def test_the_expanding_square_starts_at_the_pad_and_stays_within_the_radius():
    pts = expanding_square(6.0, 2.5)
    assert pts[0] == (0.0, 0.0) and len(pts) > 4
    assert all(math.hypot(n, e) <= 6.0 + 1e-9 for n, e in pts)
    assert pts[1] == (2.5, 0.0) and pts[2] == (2.5, 2.5) and pts[3] == (-2.5, 2.5)
    assert math.hypot(*pts[-1]) == pytest.approx(6.0)  # the last leg cut at the radius
    assert expanding_square(0.0, 2.5) == [(0.0, 0.0)]


def test_a_search_below_the_approach_height_is_refused_at_load():
    with pytest.raises(ConfigError, match="search_height_m"):
        load_config(
            shipped_params_path("delivery_paper.toml"),
            overrides={"mission": {"final_descent_alt_m": 5.0}, "landing": {"policy": {"search_height_m": 4.0}}},
        )


def _at_approach(policy=POLICY):
    """A mission in OUTBOUND, then the vehicle reported above the pad under the approach height."""
    m = DeliveryMission(cfg(), pad_policy=policy)
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


def _fly(m, t, lock, n, e, d, landed=LandedState.IN_AIR, armed=True):
    st = status(t, armed=armed, mode=FlightMode.OFFBOARD, landed=landed)
    return m.step(MissionInputs(t, est(t, n, e, d), st, HOME, pad_lock=lock))


def test_without_pad_sensors_the_parcel_flies_home_from_the_approach_height():
    m, t = _at_approach()
    _fly(m, t + 0.05, NO_SENSORS, *PAD, -2.5)
    assert m.phase is Phase.INBOUND
    assert m.summary.failure == "parcel not delivered: no pad sensor: no pad lock can come"
    assert [e.kind for e in m.summary.events].count(EventKind.PAD_LOCK) == 2


def test_no_lock_holds_then_searches_then_lands_once_found():
    m, t = _at_approach()
    t += 0.05
    _fly(m, t, STALE, *PAD, -2.5)
    assert m.phase is Phase.PAD_HOLD and m.summary.pad_tries == 1
    t0 = t
    while t < 10 and m.phase is Phase.PAD_HOLD:
        t += 0.05
        out = _fly(m, t, STALE, *PAD, -3.0)
        assert out.setpoint is not None and abs(out.setpoint.north_m_s) < 1e-9  # over the configured pad
    assert m.phase is Phase.PAD_SEARCH and t - t0 == pytest.approx(2.0, abs=0.06)
    # climbs to the search height over the pad, then the first corner (2 m north)
    out = _fly(m, t + 0.05, STALE, *PAD, -3.0)
    assert out.setpoint.down_m_s < 0 and abs(out.setpoint.north_m_s) < 1e-9
    t += 0.1
    out = _fly(m, t, STALE, PAD[0], PAD[1], -8.0)
    out = _fly(m, t + 0.05, STALE, PAD[0], PAD[1], -8.0)
    assert out.setpoint.north_m_s > 0.5  # towards (62, 80)
    t += 0.1
    _fly(m, t, LOCKED, PAD[0] + 2.0, PAD[1], -8.0)
    assert m.phase is Phase.PAD_HOLD
    out = _fly(m, t + 0.05, LOCKED, PAD[0] + 2.0, PAD[1], -8.0)
    assert out.setpoint.north_m_s < 0 and out.setpoint.down_m_s > 0  # onto the pad, down to the approach
    _fly(m, t + 0.1, LOCKED, PAD[0] + 0.1, PAD[1], -3.0)
    assert m.phase is Phase.LANDING_PAD
    details = [e.detail for e in m.summary.events if e.kind is EventKind.PAD_LOCK]
    assert "searching within 4.0 m" in details[1] and "pad found in the search" in details[2]
    assert "descent try 2 of 2" in details[3]


def test_a_touchdown_without_lock_releases_nothing_and_takes_off_for_home():
    m, t = _at_approach()
    _fly(m, t + 0.05, LOCKED, *PAD, -2.5)
    assert m.phase is Phase.LANDING_PAD
    _fly(m, t + 0.1, STALE, *PAD, -0.5)  # below commit_height_m: the descent goes on
    assert m.phase is Phase.LANDING_PAD
    out = _fly(m, t + 0.15, STALE, *PAD, 0.0, landed=LandedState.ON_GROUND)
    assert out.request.kind is RequestKind.DISARM
    m.on_result(RequestResult(out.request.id, True))
    out = _fly(m, t + 0.2, STALE, *PAD, 0.0, landed=LandedState.ON_GROUND, armed=False)
    assert out.request is not None and out.request.kind is RequestKind.ARM
    assert m.phase is Phase.ARMING and not m.summary.delivered
    assert "no pad lock at touchdown" in m.summary.failure
    assert all(e.kind is not EventKind.RELEASED for e in m.summary.events)


def test_a_lock_lost_in_the_descent_stops_it_and_the_last_try_goes_home():
    m, t = _at_approach(PadLockPolicyConfig(descent_tries=1))
    _fly(m, t + 0.05, LOCKED, *PAD, -2.5)
    _fly(m, t + 0.1, STALE, *PAD, -2.0)
    assert m.phase is Phase.INBOUND and m.summary.pad_tries == 1
    assert "pad lock lost in the descent at 2.0 m" in m.summary.events[-3].detail


REOPENED = PadLock(0.0, 0.1, 10.0)  # observed 0.1 s ago, the EKF's covariance just re-opened


def test_a_reopened_covariance_with_the_pad_in_sight_gets_the_grace_and_no_more():
    m, t = _at_approach(PadLockPolicyConfig(descent_tries=1, reopen_grace_s=1.0))
    _fly(m, t + 0.05, LOCKED, *PAD, -2.5)
    t += 0.1
    t0 = t
    while t < t0 + 0.95:  # sigma over the limit, observations fresh: the descent goes on
        out = _fly(m, t, REOPENED, *PAD, -2.4)
        assert m.phase is Phase.LANDING_PAD and out.setpoint is not None
        t += 0.05
    _fly(m, t, LOCKED, *PAD, -2.3)  # the next accepted observation closed it: the clock starts again
    t += 0.05
    t1 = t
    while m.phase is Phase.LANDING_PAD:
        _fly(m, t, REOPENED, *PAD, -2.2)
        t += 0.05
    assert t - 0.05 - t1 == pytest.approx(1.0, abs=0.051)  # failed once it lasted reopen_grace_s
    assert m.phase is Phase.INBOUND and "1-sigma 10.00 m" in m.summary.events[-3].detail


def test_without_fresh_observations_or_without_a_grace_the_try_fails_at_once():
    for policy, lock in (
        (PadLockPolicyConfig(descent_tries=1), PadLock(0.0, 0.6, 10.0)),  # last observation 0.6 s old
        (PadLockPolicyConfig(descent_tries=1, reopen_grace_s=0.0), REOPENED),
    ):
        m, t = _at_approach(policy)
        _fly(m, t + 0.05, LOCKED, *PAD, -2.5)
        _fly(m, t + 0.1, lock, *PAD, -2.0)
        assert m.phase is Phase.INBOUND, (policy, lock)


def test_the_opt_out_releases_where_it_lands():
    m, t = _at_approach(PadLockPolicyConfig(require_pad_lock=False))
    _fly(m, t + 0.05, NO_SENSORS, *PAD, -2.5)
    assert m.phase is Phase.LANDING_PAD

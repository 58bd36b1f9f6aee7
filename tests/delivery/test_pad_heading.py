"""A pad with a heading: the camera's measured heading (delivery.pad_heading), the configured
fallback, and the mission's yaw setpoint turning to it at the rate limit (docs/pad-heading.md)."""

from __future__ import annotations

import math
from dataclasses import replace

import pytest
from pydantic import ValidationError

from companion.autopilot.types import FlightMode, HomePosition, LandedState, VehicleStatus
from companion.config import LimitsConfig, MissionConfig, PadConfig
from companion.delivery.mission import DeliveryMission, MissionInputs
from companion.delivery.pad_heading import (
    HEADING_WINDOW_S,
    PadHeadingEstimator,
    landing_heading_rad,
    pad_yaw_and_tolerance_rad,
)
from companion.estimation.types import StateEstimate
from companion.events import Phase
from companion.geometry.heading import heading_difference_rad
from companion.geometry.mounts import downward_mount, pad_pose_ned
from companion.geometry.rotations import euler_to_rotmat
from companion.guidance.setpoint import VelocitySetpoint

HOME = HomePosition(0.0, -19.869, -43.9638, 850.0)
R_BC = downward_mount().R


def observation(att_deg: tuple[float, float, float], pad_deg: float):
    """R_camera_pad of a pad with heading ``pad_deg`` seen from a vehicle at ``att_deg``."""
    R_wb = euler_to_rotmat(*(math.radians(a) for a in att_deg))
    return (R_wb @ R_BC).T @ pad_pose_ned(yaw_rad=math.radians(pad_deg)).R


def test_the_measured_heading_wins_after_enough_observations_at_their_exposure_attitude() -> None:
    """The dock lies 4 deg off its configured 135 deg; the vehicle turns at 60 deg/s, so the
    attitude of each observation is the one at its exposure (interpolated), not the newest."""
    h = PadHeadingEstimator(math.radians(135.0), math.radians(20.0))
    yaw_rate = 60.0
    for k in range(101):  # attitude at 100 Hz over 1 s, yaw 0 -> 60 deg
        h.on_attitude(k * 0.01, 0.0, 0.0, math.radians(yaw_rate * k * 0.01))
    assert h.target_rad == pytest.approx(math.radians(135.0))
    for k in range(4):
        t = 0.2 + 0.1 * k + 0.005  # between two attitude samples
        assert h.on_observation(t, observation((0.0, 0.0, yaw_rate * t), 139.0), R_BC)
        assert h.measured_rad is None  # not enough yet: the configured heading holds
    t = 0.705
    assert h.on_observation(t, observation((0.0, 0.0, yaw_rate * t), 139.0), R_BC)
    assert math.degrees(h.measured_rad or 0.0) == pytest.approx(139.0, abs=1e-6)
    assert math.degrees(h.target_rad) == pytest.approx(139.0, abs=1e-6)


def test_a_measurement_beyond_the_bound_is_rejected_and_one_before_the_attitude_is_not_used() -> None:
    h = PadHeadingEstimator(math.radians(135.0), math.radians(10.0), min_observations=1)
    assert not h.on_observation(0.5, observation((0.0, 0.0, 0.0), 135.0), R_BC)  # no attitude yet
    h.on_attitude(1.0, 0.0, 0.0, 0.0)
    assert not h.on_observation(1.0, observation((0.0, 0.0, 0.0), 135.0 - 90.0), R_BC)  # a wrong marker
    assert h.rejected == 1 and h.measured_rad is None
    assert h.target_rad == pytest.approx(math.radians(135.0))
    assert h.on_observation(1.0, observation((0.0, 0.0, 0.0), 141.0), R_BC)
    assert math.degrees(h.target_rad) == pytest.approx(141.0)


def test_the_circular_mean_works_across_180() -> None:
    h = PadHeadingEstimator(math.radians(180.0), math.radians(10.0), min_observations=2)
    h.on_attitude(0.0, 0.0, 0.0, 0.0)
    h.on_observation(0.0, observation((0.0, 0.0, 0.0), 178.0), R_BC)
    h.on_observation(0.0, observation((0.0, 0.0, 0.0), -176.0), R_BC)
    assert abs(math.degrees(heading_difference_rad(h.target_rad, math.radians(-179.0)))) < 1e-6


def test_the_measured_heading_follows_a_drifting_autopilot_yaw_frame() -> None:
    """The autopilot's yaw estimate drifts 1 deg/s against the truth while the vehicle truly holds
    still over a dock at 139 deg: observed in the drifting frame, the dock's heading moves with it,
    and the heading to land on must be that of the last HEADING_WINDOW_S, not of the whole descent."""
    h = PadHeadingEstimator(math.radians(135.0), math.radians(20.0))
    drift_deg_s = 1.0
    for k in range(601):  # 6 s of observations and attitude at 100 Hz
        t = k * 0.01
        yaw_est = drift_deg_s * t  # reported yaw; the true yaw is 0
        h.on_attitude(t, 0.0, 0.0, math.radians(yaw_est))
        # the camera sees the dock 139 deg right of the true nose; turned by the reported yaw
        assert h.on_observation(t, observation((0.0, 0.0, 0.0), 139.0), R_BC)
    # in the frame of now (drift 6 deg) the dock is at 145 deg; the window's mean lags it by half
    # its length (0.5 deg); the mean over all 6 s would say 142 deg
    assert math.degrees(h.target_rad) == pytest.approx(145.0 - drift_deg_s * HEADING_WINDOW_S / 2, abs=1e-6)


def test_the_window_keeps_the_minimum_count_after_a_gap() -> None:
    h = PadHeadingEstimator(math.radians(0.0), math.radians(20.0), min_observations=3)
    h.on_attitude(0.0, 0.0, 0.0, 0.0)
    for t, pad_deg in ((0.0, 2.0), (0.1, 4.0), (5.0, 6.0)):  # the pad lost for 4.9 s before the last
        h.on_observation(t, observation((0.0, 0.0, 0.0), pad_deg), R_BC)
    assert math.degrees(h.target_rad) == pytest.approx(4.0, abs=1e-3)  # all three still count


def test_estimator_rejects_bad_setup() -> None:
    with pytest.raises(ValueError, match="tolerance"):
        PadHeadingEstimator(0.0, 0.0)
    with pytest.raises(ValueError, match="must be finite"):
        PadHeadingEstimator(math.nan, 0.1)


def test_the_heading_to_land_on_comes_from_the_pad_landed_on() -> None:
    plain = MissionConfig(pad=PadConfig(north_m=10.0, east_m=0.0))
    assert landing_heading_rad(plain, 0, None) is None
    assert pad_yaw_and_tolerance_rad(plain, 0) == (0.0, None)
    headed = MissionConfig(
        pad=PadConfig(north_m=10.0, east_m=0.0, heading_deg=270.0),
        alternate_pad=PadConfig(north_m=30.0, east_m=0.0, heading_deg=45.0, heading_tolerance_deg=5.0),
    )
    assert math.degrees(landing_heading_rad(headed, 0, None) or 0.0) == pytest.approx(-90.0)
    assert math.degrees(landing_heading_rad(headed, 1, None) or 0.0) == pytest.approx(45.0)
    yaw, tol = pad_yaw_and_tolerance_rad(headed, 1)
    assert math.degrees(yaw) == pytest.approx(45.0) and math.degrees(tol or 0.0) == pytest.approx(5.0)
    est = PadHeadingEstimator(math.radians(45.0), math.radians(5.0), min_observations=1)
    est.on_attitude(0.0, 0.0, 0.0, 0.0)
    est.on_observation(0.0, observation((0.0, 0.0, 0.0), 47.0), R_BC)
    assert math.degrees(landing_heading_rad(headed, 1, est) or 0.0) == pytest.approx(47.0)


@pytest.mark.parametrize("bad", [-181.0, 361.0, math.nan])
def test_a_bad_pad_heading_is_refused(bad: float) -> None:
    with pytest.raises(ValidationError, match="heading_deg"):
        PadConfig(north_m=1.0, east_m=0.0, heading_deg=bad)


def _mission_in(phase: Phase, max_yaw_rate_deg_s: float = 30.0) -> DeliveryMission:
    m = DeliveryMission(
        MissionConfig(pad=PadConfig(north_m=60.0, east_m=80.0)),
        limits=LimitsConfig(max_yaw_rate_deg_s=max_yaw_rate_deg_s),
    )
    m.enter(phase)
    return m


def _inp(t: float, heading_deg: float | None, yaw_deg: float = 0.0) -> MissionInputs:
    est = StateEstimate(t, 0.0, 0.0, -2.0, 0, 0, 0, 0, 0, math.radians(yaw_deg))
    st = VehicleStatus(t, True, FlightMode.OFFBOARD, LandedState.IN_AIR, True, 90.0, False)
    h = None if heading_deg is None else math.radians(heading_deg)
    return MissionInputs(t, est, st, HOME, pad_heading_rad=h)


def _aligned(m: DeliveryMission, inp: MissionInputs, sp: VelocitySetpoint | None) -> VelocitySetpoint | None:
    return m.yaw.apply(m.phase, inp, sp, lambda: m.height_above_ground(inp.estimate))


def test_the_yaw_setpoint_turns_to_the_pad_heading_at_the_rate_limit_the_short_way() -> None:
    m = _mission_in(Phase.LANDING_PAD)
    sp = VelocitySetpoint(0.1, 0.0, 0.5, math.radians(170.0))  # the path's heading
    # before the final descent the path's heading is flown and remembered
    m.phase = Phase.OUTBOUND
    assert _aligned(m, _inp(0.0, -150.0, 170.0), sp) == sp
    m.phase = Phase.LANDING_PAD
    yaws = []
    for k in range(1, 60):
        out = _aligned(m, _inp(0.1 * k, -150.0, 170.0), sp)
        assert out is not None and (out.north_m_s, out.east_m_s, out.down_m_s) == (0.1, 0.0, 0.5)
        yaws.append(math.degrees(out.yaw_rad))
    # 40 deg the short way (through 180) at 30 deg/s: 3 deg a tick, there after 14 ticks
    assert yaws[0] == pytest.approx(173.0)
    assert yaws[2] == pytest.approx(179.0)
    assert yaws[3] == pytest.approx(-178.0)
    assert yaws[12] == pytest.approx(-151.0)
    assert all(y == pytest.approx(-150.0) for y in yaws[13:])


def test_without_a_pad_heading_or_outside_the_landing_the_setpoint_is_untouched() -> None:
    sp = VelocitySetpoint(0.0, 0.0, 0.5, 0.3)
    m = _mission_in(Phase.LANDING_PAD)
    assert _aligned(m, _inp(0.0, None), sp) is sp
    for phase in (Phase.OUTBOUND, Phase.INBOUND, Phase.LANDING_HOME):
        m = _mission_in(phase)
        assert _aligned(m, _inp(0.0, 90.0), sp) is sp
    assert _aligned(m, _inp(0.0, 90.0), None) is None


def test_turned_and_blind_near_the_ground_the_yaw_setpoint_follows_the_vehicles_yaw() -> None:
    """Turned to the pad (setpoint at the target), below landing_hold_min_height_m with no heading
    observation within PAD_DATA_FRESH_S, the setpoint is the autopilot's own yaw (37 deg; not the
    fusion's 38): no turn by the autopilot's yaw drift; with the heading in sight, higher up, still
    turning or without the autopilot's attitude, the target."""
    from companion.delivery.padlock import PAD_DATA_FRESH_S

    c = MissionConfig(pad=PadConfig(north_m=60.0, east_m=80.0), landing_hold_min_height_m=0.3)
    flying = VehicleStatus(0.0, True, FlightMode.OFFBOARD, LandedState.IN_AIR, True, 90.0, False)

    def yaw_sp_deg(height_m: float, age_s: float, turned: bool, ap_yaw_deg: float | None = 37.0) -> float:
        m = DeliveryMission(c, limits=LimitsConfig(max_yaw_rate_deg_s=60.0))
        m.step(MissionInputs(0.0, StateEstimate(0.0, 0.0, 0.0, 0.0, 0, 0, 0, 0, 0, 0.0), None, HOME))
        m.enter(Phase.LANDING_PAD)
        pn, pe = float(m.pad_ned[0]), float(m.pad_ned[1])
        m.yaw.last = (0.0, math.radians(40.0 if turned else 20.0))
        e = StateEstimate(0.05, pn, pe, -height_m, 0, 0, 0, 0, 0, math.radians(38.0))  # the fusion's yaw
        inp = MissionInputs(0.05, e, flying, HOME, pad_heading_rad=math.radians(40.0), pad_heading_age_s=age_s)
        out = m.step(replace(inp, autopilot_yaw_rad=None if ap_yaw_deg is None else math.radians(ap_yaw_deg)))
        assert m.phase is Phase.LANDING_PAD and out.setpoint is not None
        return math.degrees(out.setpoint.yaw_rad)

    stale = PAD_DATA_FRESH_S + 0.01
    assert yaw_sp_deg(0.2, stale, turned=True) == pytest.approx(37.0)
    assert yaw_sp_deg(0.2, math.inf, turned=True) == pytest.approx(37.0)  # never measured: the same
    assert yaw_sp_deg(0.2, PAD_DATA_FRESH_S, turned=True) == pytest.approx(40.0)  # in sight
    assert yaw_sp_deg(0.4, stale, turned=True) == pytest.approx(40.0)  # above the hold's floor
    assert yaw_sp_deg(0.2, stale, turned=False) == pytest.approx(23.0)  # still turning: 3 deg a tick
    assert yaw_sp_deg(0.2, stale, turned=True, ap_yaw_deg=None) == pytest.approx(40.0)  # no attitude yet

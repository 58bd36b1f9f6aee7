"""The simulated winch and the parcel's pendulum (sitl/winch.py), against hand-computed figures."""

from __future__ import annotations

import itertools
import math

import pytest

from companion.autopilot.winch import (
    MAV_WINCH_STATUS_HEALTHY,
    MAV_WINCH_STATUS_MOVING,
    WinchAction,
    WinchCommand,
)
from companion_sitl.winch import G_M_S2, ParcelOnLine, SimWinch

DT = 1e-3  # the vehicle steps the pendulum at >= 1 kHz (PARCEL_STEP_HZ)


def _swing(length_m: float, theta0_rad: float, seconds: float, drag_1_s: float = 0.0) -> list[tuple[float, float]]:
    """(t, north) of a parcel released from rest at theta0 under a fixed suspension point."""
    par = ParcelOnLine(drag_1_s)
    a = (0.0, 0.0, -20.0)
    par.p = [length_m * math.sin(theta0_rad), 0.0, a[2] + length_m * math.cos(theta0_rad)]
    par.v = [0.0, 0.0, 0.0]
    out, t = [], 0.0
    for _ in range(round(seconds / DT)):
        t += DT
        par.step(t, DT, a, (0.0, 0.0, 0.0), length_m)
        out.append((t, par.p[0]))
    return out


def _period_s(xs: list[tuple[float, float]]) -> float:
    ups = [t0 + (t1 - t0) * (-x0) / (x1 - x0) for (t0, x0), (t1, x1) in itertools.pairwise(xs) if x0 < 0 <= x1]
    return (ups[-1] - ups[0]) / (len(ups) - 1)


@pytest.mark.parametrize("length_m", [1.0, 4.0, 9.0])
def test_small_angle_period_is_two_pi_root_l_over_g(length_m: float) -> None:
    # 2*pi*sqrt(L/g): 2.006 s at 1 m, 4.013 s at 4 m, 6.019 s at 9 m
    expected = 2.0 * math.pi * math.sqrt(length_m / G_M_S2)
    assert _period_s(_swing(length_m, 0.05, 8.0 * expected)) == pytest.approx(expected, rel=2e-3)


def test_undamped_swing_keeps_its_amplitude_and_never_gains_energy() -> None:
    length_m, th0 = 4.0, 0.1
    xs = _swing(length_m, th0, 5 * 4.013)
    a0 = length_m * math.sin(th0)
    last = max(abs(x) for t, x in xs if t > 4 * 4.013)
    # no energy from nowhere; the integrator's damping stays below 1 % of the swing per period
    assert max(abs(x) for _, x in xs) <= a0 * (1 + 1e-6)
    assert last > a0 * 0.95


def test_drag_damps_the_swing_and_wind_sets_the_steady_angle() -> None:
    xs = _swing(4.0, 0.1, 40.0, drag_1_s=0.3)
    assert max(abs(x) for t, x in xs if t > 30.0) < 0.02 * 0.4
    # steady wind w: drag k*w balances gravity's pull back: tan(theta) = k w / g
    par = ParcelOnLine(drag_1_s=0.3)
    a = (0.0, 0.0, -20.0)
    par.p, par.v = [0.0, 0.0, -16.0], [0.0, 0.0, 0.0]
    t = 0.0
    for _ in range(round(60.0 / DT)):
        t += DT
        par.step(t, DT, a, (0.0, 0.0, 0.0), 4.0, wind=(5.0, 0.0, 0.0))
    theta = math.atan2(par.p[0], par.p[2] - a[2])
    assert math.tan(theta) == pytest.approx(0.3 * 5.0 / G_M_S2, rel=1e-2)


def test_paying_out_lowers_the_parcel_to_the_ground_under_the_vehicle() -> None:
    w = SimWinch(rate_max_m_s=0.5, pos_p=1.0)
    par = ParcelOnLine(0.3)
    a, va = (3.0, -2.0, -5.0), (0.0, 0.0, 0.0)
    w.command(WinchCommand(1, WinchAction.RELATIVE_LENGTH_CONTROL, 5.3, 0.5))
    t = 0.0
    while par.touchdown is None and t < 30.0:
        t += DT
        w.step(DT)
        par.step(t, DT, a, va, w.length_m)
    td = par.touchdown
    assert td is not None
    # 4.8 m at 0.5 m/s (9.6 s), then the last 0.2 m as the length error (0.5 -> 0.3 m) decays at
    # WINCH_POS_P = 1/s: ln(0.5 / 0.3) = 0.51 s more; it lands at the 0.3 m/s the winch then runs at
    assert td.time_s == pytest.approx(9.6 + math.log(0.5 / 0.3), abs=0.02)
    assert math.hypot(td.north_m - 3.0, td.east_m + 2.0) < 1e-6
    assert td.vertical_speed_m_s == pytest.approx(0.3, abs=0.02)


def test_winch_control_laws_follow_ap_winch() -> None:
    w = SimWinch(rate_max_m_s=1.0, pos_p=2.0)
    w.command(WinchCommand(1, WinchAction.RELATIVE_LENGTH_CONTROL, 0.2))
    w.step(0.1)  # error 0.2 m * P 2 = 0.4 m/s, below the 1 m/s limit
    assert w.length_m == pytest.approx(0.04)
    w.command(WinchCommand(1, WinchAction.RATE_CONTROL, 0.0, 3.0))
    assert w.rate_desired_m_s == 1.0  # clamped to WINCH_RATE_MAX
    w.command(WinchCommand(1, WinchAction.RELAXED))
    w.step(1.0)
    assert w.length_m == pytest.approx(0.04)  # relaxed: no output, no estimate
    w.command(WinchCommand(1, WinchAction.RATE_CONTROL, 0.0, -1.0))
    w.step(1.0)
    assert w.length_m == 0.0  # fully retracted


def _lowered(par: ParcelOnLine, seconds: float, a: tuple[float, float, float] = (0.0, 0.0, -5.0)) -> list[bool]:
    """Pay out 5.3 m at 0.5 m/s under a still vehicle 5 m up; ``taut`` at every 10th step."""
    w = SimWinch(rate_max_m_s=0.5, pos_p=1.0)
    w.command(WinchCommand(1, WinchAction.RELATIVE_LENGTH_CONTROL, 5.3, 0.5))
    taut, t = [], 0.0
    for k in range(round(seconds / DT)):
        t += DT
        w.step(DT)
        par.step(t, DT, a, (0.0, 0.0, 0.0), w.length_m)
        if k % 10 == 0:
            taut.append(par.taut)
    return taut


def test_the_line_is_taut_while_the_parcel_hangs_and_slack_once_it_stands_on_the_ground() -> None:
    par = ParcelOnLine(0.3)
    taut = _lowered(par, 14.0)
    assert par.on_ground and par.touchdown is not None
    # stowed for the first ~0.04 s (under STOWED_M), then hanging all the way down, slack on the ground
    assert not any(taut[:3]) and all(taut[30:900]) and not any(taut[-100:])


def test_a_snag_holds_the_parcel_at_its_height_with_the_line_slack_until_the_line_lifts_it() -> None:
    par = ParcelOnLine(0.3, snag_height_m=2.0)
    taut = _lowered(par, 14.0)
    assert par.caught and not par.on_ground and par.touchdown is None
    assert par.p[2] == pytest.approx(-2.0) and not any(taut[-100:])
    # reeled in above the snag: the line takes it up again and it does not catch a second time
    for k in range(3000):
        par.step(14.0 + k * DT, DT, (0.0, 0.0, -5.0), (0.0, 0.0, 0.0), 2.5)
    assert not par.caught and par.taut and par.p[2] == pytest.approx(-2.5, abs=1e-3)


def test_the_load_cell_weighs_the_parcel_only_while_the_line_holds_it() -> None:
    from companion_sitl.params import SimWinchConfig
    from companion_sitl.payload import SimPayload

    plain = SimPayload(SimWinchConfig(fitted=True), (0.0, 0.0, -5.0))
    assert math.isnan(plain.line_tension_kg())  # AP_Winch_PWM: no tension
    cell = SimPayload(SimWinchConfig(fitted=True, load_cell=True, parcel_mass_kg=0.7), (0.0, 0.0, -5.0))
    assert cell.parcel is not None
    cell.parcel.taut = True
    assert cell.line_tension_kg() == 0.7
    cell.parcel.taut = False
    assert cell.line_tension_kg() == 0.0


def test_a_drum_that_jams_inwards_pays_out_and_then_holds_its_line() -> None:
    w = SimWinch(rate_max_m_s=0.5, pos_p=1.0, reel_in_jams=True)
    w.command(WinchCommand(1, WinchAction.RATE_CONTROL, 0.0, 0.5))
    for _ in range(40):
        w.step(0.1)
    assert w.length_m == pytest.approx(2.0) and w.speed_m_s == 0.5 and w.flags() & MAV_WINCH_STATUS_MOVING
    w.command(WinchCommand(1, WinchAction.RELATIVE_LENGTH_CONTROL, -2.0))
    for _ in range(40):
        w.step(0.1)
    # the line as it is, at speed 0, not moving: what an encoder winch reports of a jammed drum
    assert w.length_m == pytest.approx(2.0) and w.speed_m_s == 0.0 and not w.flags() & MAV_WINCH_STATUS_MOVING
    assert w.flags() & MAV_WINCH_STATUS_HEALTHY

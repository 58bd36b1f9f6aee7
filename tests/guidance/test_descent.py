"""The final descent's controller on its own section ([mission.descent])."""

from __future__ import annotations

import pytest

from companion.config import DescentConfig
from companion.guidance.descent import PrecisionDescent


def _still() -> tuple[float, float]:
    return (0.0, 0.0)


def test_the_descent_closes_the_error_with_its_gain_within_its_speed_limit():
    d = PrecisionDescent(DescentConfig(xy_gain_1_s=2.0, max_xy_speed_m_s=0.5), land_speed_m_s=0.5)
    near = d.command(0.1, -0.05, 2.0, 0.0, may_hold=False, velocity_xy=_still)
    assert (near.x_m_s, near.y_m_s) == pytest.approx((-0.2, 0.1))
    far = PrecisionDescent(DescentConfig(xy_gain_1_s=2.0, max_xy_speed_m_s=0.5), 0.5).command(
        3.0, 4.0, 2.0, 0.0, may_hold=False, velocity_xy=_still
    )
    assert (far.x_m_s, far.y_m_s) == pytest.approx((-0.3, -0.4))  # 0.5 m/s along the error
    assert far.accel_xy_m_s2 is None  # no feedforward by default


def test_below_the_touchdown_height_only_the_descent_at_land_speed_remains():
    d = PrecisionDescent(DescentConfig(touchdown_height_m=0.15), land_speed_m_s=0.7)
    c = d.command(0.3, 0.3, 0.1, 0.0, may_hold=False, velocity_xy=_still)
    assert (c.x_m_s, c.y_m_s) == (0.0, 0.0) and c.z_m_s == pytest.approx(-0.7)


def _fly(d: PrecisionDescent, sinks: list[tuple[float, float]], height_m: float = 0.2, t: float = 0.0):
    """Ticks at 20 Hz from ``t`` with (sink m/s, seconds) segments; the commands."""
    out = []
    for sink, seconds in sinks:
        for _ in range(round(seconds / 0.05)):
            out.append(d.command(0.3, 0.0, height_m, t, may_hold=False, velocity_xy=_still, down_m_s=sink))
            t += 0.05
    return out


def test_a_vehicle_that_stops_sinking_near_the_ground_is_in_contact_and_only_descends():
    cfg = DescentConfig(touchdown_height_m=-1.0, contact_time_s=0.3, xy_integral_gain_1_s2=2.5)
    d = PrecisionDescent(cfg, land_speed_m_s=0.7)
    cmds = _fly(d, [(0.7, 1.0), (0.05, 0.25)])
    assert not d.contact and cmds[-1].x_m_s < 0.0  # not yet: 0.25 s < contact_time_s
    integral = d.integral_m_s
    cmds = _fly(d, [(0.05, 0.15)], t=1.25)
    assert d.contact and (cmds[-1].x_m_s, cmds[-1].y_m_s) == (0.0, 0.0) and cmds[-1].z_m_s == pytest.approx(-0.7)
    _fly(d, [(0.7, 0.5)], t=1.4)  # latched for the phase, the integral frozen
    assert d.contact and d.integral_m_s == integral


def test_the_integral_stops_summing_once_the_sinking_stops_and_goes_on_if_it_was_no_contact():
    """On the ground the estimate drifts under the sideways command: while the sinking has
    stopped (before contact_time_s confirms it) the integral holds; a short stop that was no
    contact lets it sum again."""
    cfg = DescentConfig(touchdown_height_m=-1.0, contact_time_s=0.3, xy_integral_gain_1_s2=2.5, xy_gain_1_s=1.0)
    d = PrecisionDescent(cfg, land_speed_m_s=0.7)
    _fly(d, [(0.7, 0.4)])
    before = d.integral_m_s
    _fly(d, [(0.05, 0.2)], t=0.4)
    assert d.sinking_stopped and not d.contact and d.integral_m_s == before
    _fly(d, [(0.7, 0.2)], t=0.6)
    assert not d.sinking_stopped and d.integral_m_s[0] > before[0]


@pytest.mark.parametrize(
    "sinks, height_m, why",
    [
        ([(0.0, 2.0)], 0.2, "never descending (a hold released at the floor): the autopilot's lag, not the ground"),
        ([(0.7, 1.0), (0.05, 1.0)], 2.5, "stopped higher than CONTACT_HEIGHT_M: not the ground"),
        ([(0.7, 1.0), (0.3, 1.0)], 0.2, "slowed to 0.43 of the command, above CONTACT_STOPPED"),
        ([(0.7, 1.0), (0.05, 0.2), (0.7, 0.1), (0.05, 0.2)], 0.2, "two short stops, neither contact_time_s long"),
    ],
)
def test_no_contact_without_a_descent_that_stopped_near_the_ground(sinks, height_m, why):
    d = PrecisionDescent(DescentConfig(contact_time_s=0.3, touchdown_height_m=-1.0), land_speed_m_s=0.7)
    cmds = _fly(d, sinks, height_m)
    assert not d.contact and cmds[-1].x_m_s < 0.0, why


def test_contact_is_off_by_default():
    d = PrecisionDescent(DescentConfig(touchdown_height_m=-1.0), land_speed_m_s=0.7)
    _fly(d, [(0.7, 1.0), (0.0, 2.0)])
    assert not d.contact


def test_grounded_once_a_commanded_descent_stops_sinking_whatever_contact_time_s_says():
    """PrecisionDescent.grounded (a moving pad's feed-forward switches on it): sank at land speed,
    then below a quarter of it near the ground; contact_time_s off (ArduCopter's tuning)."""
    d = PrecisionDescent(DescentConfig(), land_speed_m_s=0.5)
    _fly(d, [(0.5, 1.0)])
    assert not d.grounded  # still sinking
    _fly(d, [(0.2, 0.2)], t=1.0)
    assert not d.grounded  # slower, not stopped
    _fly(d, [(0.05, 0.05)], t=1.2)
    assert d.grounded and not d.contact  # at once, without contact_time_s's confirmation
    _fly(d, [(0.5, 0.5)], t=1.25)
    assert d.grounded  # latched for the phase


def test_not_grounded_where_no_descent_was_commanded_or_high_up():
    high = PrecisionDescent(DescentConfig(), land_speed_m_s=0.5)
    _fly(high, [(0.5, 1.0), (0.0, 0.5)], height_m=3.0)  # stopped 3 m up (above CONTACT_HEIGHT_M)
    assert not high.grounded
    never = PrecisionDescent(DescentConfig(), land_speed_m_s=0.5)
    _fly(never, [(0.0, 1.0)])  # never sank: a hover is no contact
    assert not never.grounded

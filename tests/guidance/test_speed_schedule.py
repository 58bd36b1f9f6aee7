"""The field's speed kept within the autopilot's acceleration limits (hand-computed cases)."""

import math

import pytest

from companion.guidance.path import DeliveryPath
from companion.guidance.speed_schedule import sector_remaining_m, speed_scale

PATH = DeliveryPath(h=8.0, r=2.0, d=20.0)
SPEEDS = (2.5, 3.0, 5.0, 3.0, 2.0)
END = (2.0, 2.0)  # the landings take over 2 m above the pad and above home


def test_distance_left_in_each_sector_both_ways():
    # sector 1 climbs x = -d from the ground to h - r = 6; sector 5 descends x = 0
    assert sector_remaining_m(PATH, -20.0, 1.0, 1, +1, END) == pytest.approx(5.0)
    assert sector_remaining_m(PATH, -20.0, 5.0, 1, -1, END) == pytest.approx(3.0)  # down to 2 m
    assert sector_remaining_m(PATH, 0.0, 5.0, 5, +1, END) == pytest.approx(3.0)
    assert sector_remaining_m(PATH, 0.0, 5.0, 5, -1, END) == pytest.approx(1.0)
    # the cruise z = h from x = -d + r = -18 to -r = -2
    assert sector_remaining_m(PATH, -10.0, 8.0, 3, +1, END) == pytest.approx(8.0)
    assert sector_remaining_m(PATH, -10.0, 8.0, 3, -1, END) == pytest.approx(8.0)
    # arcs: a quarter circle of r = 2 (length pi); half way along, half of it is left either way
    c = (-18.0, 6.0)
    mid = (c[0] - 2.0 * math.cos(math.pi / 4), c[1] + 2.0 * math.sin(math.pi / 4))
    assert sector_remaining_m(PATH, *mid, 2, +1, END) == pytest.approx(math.pi / 2)
    assert sector_remaining_m(PATH, *mid, 2, -1, END) == pytest.approx(math.pi / 2)
    assert sector_remaining_m(PATH, -2.0, 8.0, 4, +1, END) == pytest.approx(math.pi)  # the arc's start


def test_no_limits_is_the_papers_field():
    assert speed_scale(PATH, -10.0, 8.0, 3, 1, SPEEDS, 0.0, 0.0, 0.5) == 1.0


def test_the_arcs_are_flown_at_sqrt_a_r():
    # a = min(2.5, 1.0) = 1 on an arc of r = 2: v <= sqrt(2); v_4 = 3 -> scale sqrt(2) / 3 at the
    # arc's end (nothing left to slow for: sector 5's 2.0 is faster than the cap)
    s = speed_scale(PATH, 0.0, 6.0, 4, 1, SPEEDS, 2.5, 1.0, 0.5)
    assert s == pytest.approx(math.sqrt(2.0) / 3.0)


def test_the_cruise_slows_in_time_for_the_arc():
    # 4 m before the cruise ends: v <= sqrt(v_arc^2 + 2 a_xy s) = sqrt(2 + 2 * 2.5 * 4) = sqrt(22)
    s = speed_scale(PATH, -6.0, 8.0, 3, 1, SPEEDS, 2.5, 1.0, 0.5)
    assert s == pytest.approx(math.sqrt(22.0) / 5.0)
    # far from it the cruise speed stands
    assert speed_scale(PATH, -17.0, 8.0, 3, 1, SPEEDS, 2.5, 1.0, 0.5) == 1.0
    # on the way back the arc to slow for is sector 2's, at the other end
    back = speed_scale(PATH, -14.0, 8.0, 3, -1, SPEEDS, 2.5, 1.0, 0.5)
    assert back == pytest.approx(math.sqrt(2.0 + 2.0 * 2.5 * 4.0) / 5.0)


def test_the_descent_slows_to_the_landing_speed_with_the_vertical_limit():
    # 0.5 m above where the landing takes over (2 m): v <= sqrt(0.5^2 + 2 * 1 * 0.5)
    s = speed_scale(PATH, 0.0, 2.5, 5, 1, SPEEDS, 2.5, 1.0, 0.5, END)
    assert s == pytest.approx(math.sqrt(0.25 + 1.0) / 2.0)
    # at or below the hand-over: the landing speed, never zero
    assert speed_scale(PATH, 0.0, 1.0, 5, 1, SPEEDS, 2.5, 1.0, 0.5, END) == pytest.approx(0.5 / 2.0)


def test_a_single_limit_applies_alone():
    # only a vertical limit: the cruise is not slowed (it may stop at once), the arcs are
    assert speed_scale(PATH, -3.0, 8.0, 3, 1, SPEEDS, 0.0, 1.0, 0.5) == 1.0
    assert speed_scale(PATH, 0.0, 6.0, 4, 1, SPEEDS, 0.0, 1.0, 0.5) == pytest.approx(math.sqrt(2.0) / 3.0)
    # only a horizontal one: the descent is not slowed for the landing
    assert speed_scale(PATH, 0.0, 2.5, 5, 1, SPEEDS, 2.5, 0.0, 0.5, END) == 1.0

"""Guidance onto a moving pad (companion.delivery.mission.moving_pad): the pad's velocity fed
forward only in the phases that fly relative to the pad, and the stated speed limit."""

from __future__ import annotations

import math

import pytest

from companion.delivery.mission.moving_pad import TRACKED_PHASES, pad_feedforward, too_fast, with_pad_velocity
from companion.events import Phase
from companion.guidance.setpoint import VelocitySetpoint

SP = VelocitySetpoint(0.5, -0.25, 0.7, 1.0, (0.1, 0.2))


@pytest.mark.parametrize("phase", TRACKED_PHASES)
def test_the_pads_velocity_is_added_to_the_horizontal_setpoint_over_the_pad(phase: Phase) -> None:
    out = with_pad_velocity(phase, SP, (2.0, -1.0))
    assert out == VelocitySetpoint(2.5, -1.25, 0.7, 1.0, (0.1, 0.2))  # down, yaw, acceleration untouched


@pytest.mark.parametrize("phase", [Phase.INBOUND, Phase.LANDING_HOME, Phase.TAKEOFF, Phase.RELEASE])
def test_elsewhere_or_without_an_estimate_the_setpoint_is_unchanged(phase: Phase) -> None:
    assert with_pad_velocity(phase, SP, (2.0, -1.0)) is SP
    assert with_pad_velocity(Phase.LANDING_PAD, SP, None) is SP
    assert with_pad_velocity(Phase.LANDING_PAD, None, (2.0, 0.0)) is None


def test_a_pad_faster_than_the_limit_is_named_with_its_speed_and_the_key() -> None:
    assert too_fast(None, 3.0) is None
    assert too_fast((3.0, 0.0), 3.0) is None  # at the limit: landed on
    why = too_fast((3.0, 1.0), 3.0)
    assert why is not None and f"{math.hypot(3.0, 1.0):.2f} m/s" in why
    assert "landing.moving_pad.max_speed_m_s = 3 m/s" in why


def test_on_the_ground_the_own_velocity_is_fed_forward_not_the_estimate():
    assert pad_feedforward((2.0, 0.5), False, (1.9, 0.4)) == (2.0, 0.5)  # flying: the estimate
    assert pad_feedforward((2.0, 0.5), True, (0.0, 0.01)) == (0.0, 0.01)  # grounded: the deck's
    assert pad_feedforward(None, True, (0.0, 0.0)) is None  # no moving pad estimate: nothing
    assert pad_feedforward((2.0, 0.5), True, None) == (2.0, 0.5)  # no own velocity: the estimate

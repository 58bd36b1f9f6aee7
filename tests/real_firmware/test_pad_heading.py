"""A pad with a heading on the real firmware (PX4 SIH, ArduCopter SITL): the pad_heading variant of
the landing campaign (heading drawn per seed, the dock placed a few degrees off it); the vehicle
touches down on the pad within 3 deg of the pad's true heading, on PX4 while its own yaw estimate
drifts degrees against the truth through the descent (docs/pad-heading.md)."""

from __future__ import annotations

import pytest

from companion_lab.real_campaign import aligned_landing_problem

pytestmark = pytest.mark.firmware


def test_touches_down_aligned_with_the_pad(firmware, tmp_path):
    name, _root = firmware
    problem = aligned_landing_problem(name, tmp_path)
    assert problem is None, problem

"""A pad with a heading on the real ArduCopter SITL: the pad_heading variant of the landing campaign
(heading drawn per seed, the dock placed a few degrees off it); the vehicle touches down on the pad
within 3 deg of the pad's true heading (docs/pad-heading.md)."""

from __future__ import annotations

import pytest

from companion_lab.real_campaign import aligned_landing_problem

pytestmark = pytest.mark.firmware


def test_touches_down_aligned_with_the_pad(ardupilot_root, tmp_path):
    problem = aligned_landing_problem("ardupilot", tmp_path)
    assert problem is None, problem

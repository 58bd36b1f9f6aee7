"""A pad with a heading on the real PX4 SIH: the pad_heading variant of the landing campaign
(heading drawn per seed, the dock placed a few degrees off it); the vehicle touches down on the pad
within 3 deg of the pad's true heading, while PX4's own yaw estimate drifts degrees against the
truth through the descent (docs/pad-heading.md)."""

from __future__ import annotations

import pytest

from companion_lab.real_campaign import aligned_landing_problem

pytestmark = pytest.mark.firmware


def test_touches_down_aligned_with_the_pad(px4_root, tmp_path):
    problem = aligned_landing_problem("px4", tmp_path)
    assert problem is None, problem

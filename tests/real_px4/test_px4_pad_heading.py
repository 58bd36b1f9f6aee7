"""A pad with a heading on the real PX4 SIH SITL: the pad_heading variant of the landing campaign
(heading drawn per seed, the dock placed a few degrees off it); the vehicle touches down on the pad
within 3 deg of the pad's true heading (docs/pad-heading.md)."""

from __future__ import annotations

import math

import pytest

from companion.config import shipped_params_path
from companion_lab.campaign_landing import pad_heading_draw
from companion_lab.real_campaign import landing_diagnostics, run_real_landing_campaign

pytestmark = pytest.mark.firmware


def test_touches_down_aligned_with_the_pad(px4_root, tmp_path):
    r = run_real_landing_campaign(
        "px4", 1, 11, ("pad_heading",), shipped_params_path("landing_campaign_short.toml"), tmp_path
    )
    (x,) = r["landings"]["pad_heading"]
    heading_deg, placed_deg = pad_heading_draw(x["seed"])
    assert abs(placed_deg) > 1.0  # the dock lies off its configured heading: the measured one must win
    assert x["delivered"] and x["failure"] == "", landing_diagnostics([x])
    assert x["on_pad"], landing_diagnostics([x])
    assert math.isfinite(x["heading_error_deg"]) and x["heading_error_deg"] < 3.0, x
    assert r["summary"]["pad_heading"]["heading_max_deg"] < 3.0

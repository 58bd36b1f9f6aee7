"""`landing.controller = "autopilot"`: the autopilot's own precision landing does the descent,
fed LANDING_TARGET from our pad observations, on the embedded simulator."""

from __future__ import annotations

import math

import pytest

from companion.config import ConfigError
from companion.events import EventKind
from companion_lab.demo import run_demo

pytestmark = pytest.mark.flight

BIAS = [1.5, -1.0, 0.0]
PAD_OFFSET = [0.4, -0.3]


def _cfg(mav, landing: dict) -> object:  # type: ignore[no-untyped-def]
    """The campaign's params, one biased draw in a light wind, with [landing] keys set."""
    sim = {"seed": 3, "gps_bias_m": BIAS, "pad_offset_m": PAD_OFFSET, "wind_speed_m_s": 2.0}
    return mav.shipped_config("landing_campaign.toml", sim=sim, landing=landing)


def test_autopilot_precision_landing_fed_landing_target_ends_on_the_displaced_pad(mav):
    seen = {}

    def tick(shell, out):
        seen["sent"] = shell.landing_targets_sent
        seen["received"] = shell.autopilot.vehicle.landing_targets_received
        seen["requests"] = [e.detail for e in shell.events if e.kind is EventKind.REQUEST_FAILED]

    r = run_demo(_cfg(mav, {"controller": "autopilot", "landing_target_output": "local_ned"}), on_tick=tick)
    assert r.delivered, r.failure
    dn, de = r.pad_landing_error_ne_m
    # the GPS bias alone is 1.8 m: landing on the 1 x 1 m pad needs the targets
    assert abs(dn) <= 0.5 and abs(de) <= 0.5, r.pad_landing_error_ne_m
    assert seen["sent"] >= 20 and seen["received"] == seen["sent"]
    assert not seen["requests"]
    assert any(e[1] == "touchdown" for e in r.events)


def test_without_targets_the_autopilots_landing_misses_by_the_bias(mav):
    """Control: the same flight with our controller but GPS only lands about the bias away, so the
    interop test above cannot pass by accident."""
    r = run_demo(_cfg(mav, {"fusion": False, "policy": {"require_pad_lock": False}}))  # released where it lands
    assert r.delivered
    assert r.pad_landing_error_m > 1.0
    assert math.isfinite(r.pad_landing_error_m)


def test_autopilot_controller_without_landing_target_output_is_a_config_error(mav):
    with pytest.raises(ConfigError, match="landing_target_output"):
        _cfg(mav, {"controller": "autopilot"})
    with pytest.raises(ConfigError, match="fusion"):
        _cfg(mav, {"fusion": False, "landing_target_output": "local_ned"})


@pytest.mark.parametrize(("dialect", "form"), [("px4", "local_ned"), ("ardupilot", "body_angles")])
def test_over_mavlink_each_autopilot_lands_on_the_pad_from_its_own_landing_target_form(mav, dialect, form):
    """Real time over loopback UDP: PX4 dialect reads the local-NED position form in AUTO.PRECLAND,
    ArduPilot's LAND (PLND_TYPE = 1) the body-frame angles; both land on the displaced pad."""
    overrides = {
        "sim": {"seed": 4, "gps_bias_m": [1.2, 0.9, 0.0], "pad_offset_m": [-0.3, 0.4]},
        "mission": {"return_home": False},
        "landing": {"controller": "autopilot", "landing_target_output": form},
    }
    config = mav.shipped_config(**overrides)
    seen = {}

    def tick(shell, out):
        seen["sent"] = shell.landing_targets_sent

    r = run_demo(config, mavlink=dialect, on_tick=tick)
    assert r.delivered, r.failure
    dn, de = r.pad_landing_error_ne_m
    assert abs(dn) <= 0.5 and abs(de) <= 0.5, (r.pad_landing_error_ne_m, seen)  # the bias alone is 1.5 m
    assert seen["sent"] >= 10

"""A line that will not reel in, on the embedded simulator ([sim.winch] reel_in_jams,
winch.reel_check_s; docs/winch.md): the parcel is lowered and released on the pad, the drum then
does not turn inwards. The jam is said CRITICAL first, the hover holds at its height while the
reel-in is tried again, then the autopilot lands the vehicle where it hovers and it disarms: the
line is never flown home."""

from __future__ import annotations

import itertools
import math
from typing import Any

import pytest

from companion.config import shipped_params_path
from companion_lab.campaign_landing import draw_scenarios
from companion_lab.demo import run_demo
from companion_sitl.params import load_simulated_config

pytestmark = pytest.mark.flight

DRIFT_S_M = 0.3 / 9.80665  # the simulated parcel's drag over g (test_winch_flight.py)


def _fly(**winch: Any) -> tuple[Any, list[tuple[str, float, float]]]:
    d = draw_scenarios(5, 11)[3]  # seed 11003: 1.2 m/s of wind
    sim = {**d.sim_overrides(), "winch": {"fitted": True, "reel_in_jams": True}}
    cfg = load_simulated_config(
        shipped_params_path("landing_campaign.toml"),
        overrides={"sim": sim, "mission": {"delivery": "winch"}, "winch": {"wind_drift_s_m": DRIFT_S_M, **winch}},
    )
    track: list[tuple[str, float, float]] = []  # (phase, line out m, height above the start m)

    def on_tick(shell: Any, out: Any) -> None:
        w, p = shell.autopilot.telemetry.winch, shell.autopilot.telemetry.position_ned
        if p is not None:
            track.append((out.phase.value, w.line_length_m if w is not None else 0.0, -p.down_m))

    return run_demo(cfg, on_tick=on_tick), track


def test_a_jammed_reel_in_is_said_critical_first_then_the_vehicle_lands_where_it_hovers() -> None:
    r, track = _fly(reel_check_s=2.0, reel_retries=1)
    events = [(k, d) for _, k, _, d in r.events]
    jams = [i for i, (k, _) in enumerate(events) if k == "winch_jam"]
    assert len(jams) == 2, events  # the first try, then the retry
    assert "holding, reel-in try 2 of 2" in events[jams[0]][1]
    assert "landing where the vehicle is" in events[jams[1]][1]
    # the GCS hears it before the vehicle does anything about it: no abort_land, no inbound before it
    land = events.index(("phase", "abort_land"))
    assert jams[1] < land and ("phase", "inbound") not in events
    assert r.delivered and not r.returned  # released on the pad, then landed there, disarmed
    assert r.failure == "aborted: the line will not reel in after 2 tries", r.failure
    assert r.parcel_touchdown_error_m < 0.3  # released only on the pad
    assert [d for k, d in events if k == "released"] == ["release commanded over the pad (winch)"]
    assert track[-1][0] == "failed" and track[-1][1] > 5.0  # the line still out, on the ground
    # never a climb with the line out (the cruise is 30 m): the hover's height on the autopilot's
    # GPS estimate wanders by 0.6 m at most (measured 4.22-4.92 m), the landing only descends
    out = [(ph, h) for ph, length, h in track if length > 0.1]
    hover = out[0][1]
    assert max(h for _, h in out) < hover + 1.0, (hover, max(h for _, h in out))
    landing = [h for ph, h in out if ph == "abort_land"]
    assert all(b <= a + 0.05 for a, b in itertools.pairwise(landing))
    assert not math.isnan(r.pad_landing_error_m) and r.pad_landing_error_m < 1.0  # landed at the pad


def test_with_the_check_off_the_jammed_line_is_flown_home_after_reel_timeout() -> None:
    """What the check changes: without it the sequence waits reel_timeout_s, then flies the line
    home at cruise height."""
    r, track = _fly(reel_timeout_s=5.0)
    assert r.returned and r.delivered
    assert not [k for _, k, _, _ in r.events if k == "winch_jam"]
    cruise = [h for ph, length, h in track if ph == "inbound" and length > 5.0]
    assert cruise and max(cruise) > 20.0  # the line out under the vehicle at its cruise height

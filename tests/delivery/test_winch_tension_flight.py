"""Whole winch deliveries on the embedded simulator with a load cell on the line
([sim.winch] load_cell, winch.tension_sensing): the parcel down when the line goes slack and left
on the pad once the line comes up light; a parcel caught on an obstacle on its way down, and one
that stays on the hook, come home (docs/winch.md). Without tension sensing the caught parcel is
released where it hangs: what the line's tension prevents."""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import pytest

from companion.config import shipped_params_path
from companion.delivery.replay import replay_run
from companion_lab.campaign_landing import draw_scenarios
from companion_lab.demo import run_demo
from companion_sitl.params import SimulatedConfig, load_simulated_config

pytestmark = pytest.mark.flight

DRIFT_S_M = 0.3 / 9.80665  # the simulated parcel's drag over g (test_winch_flight.py)


def _config(tension_sensing: bool = True, **sim_winch: Any) -> SimulatedConfig:
    d = draw_scenarios(5, 11)[3]  # seed 11003: 1.2 m/s of wind
    sim = {**d.sim_overrides(), "winch": {"fitted": True, "load_cell": True, **sim_winch}}
    winch = {"wind_drift_s_m": DRIFT_S_M, "tension_sensing": tension_sensing}
    return load_simulated_config(
        shipped_params_path("landing_campaign.toml"),
        overrides={"sim": sim, "mission": {"delivery": "winch"}, "winch": winch},
    )


def _kinds(r: Any, kind: str) -> list[str]:
    return [d for _, k, _, d in r.events if k == kind]


def test_the_slack_line_puts_the_parcel_down_and_the_light_line_confirms_it_and_replays(tmp_path: Path) -> None:
    run = tmp_path / "run"
    r = run_demo(_config(), run_dir=run)
    assert r.delivered and r.returned and not r.home_with_parcel, r.failure
    assert r.parcel_touchdown_error_m < 0.3
    winch = _kinds(r, "winch")
    assert any(s.startswith("parcel down: the line went slack at") for s in winch), winch
    assert any("came up light" in s for s in winch), winch
    # the tension each tick handed the mission is logged: replay is exact
    rep = replay_run(run, tmp_path / "replayed")
    assert rep.identical, "\n".join(rep.lines())


def test_a_parcel_caught_on_the_way_down_comes_home_unreleased() -> None:
    r = run_demo(_config(snag_height_m=2.5))
    assert not r.delivered and r.returned and r.home_with_parcel
    assert r.failure.startswith("parcel not delivered: the parcel caught on the way down: the line went slack at"), (
        r.failure
    )
    assert not _kinds(r, "released")  # no release was commanded
    assert math.isnan(r.parcel_touchdown_error_m)  # it never reached the ground


def test_without_the_tension_a_caught_parcel_is_released_where_it_hangs() -> None:
    r = run_demo(_config(tension_sensing=False, snag_height_m=2.5))
    assert r.delivered  # the mission believes it: the line reached its length
    assert math.isnan(r.parcel_touchdown_error_m)  # but the parcel never reached the pad


def test_a_parcel_still_on_the_hook_comes_home() -> None:
    r = run_demo(_config(hook_fails=True))
    assert not r.delivered and r.returned and r.home_with_parcel
    assert r.failure.startswith("parcel not delivered: parcel not released: the line took its load again"), r.failure
    assert _kinds(r, "released")  # the servo did move

"""Winch deliveries on the embedded simulator with the camera's look ([winch.camera]): the
simulated camera draws the parcel on its line with its tag, and the mission releases only once the
camera has seen it down on the pad; a parcel caught above the pad, or one without its tag, comes
home. The camera's sightings are logged: replay is exact."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from companion.config import shipped_params_path
from companion.delivery.landing_setup import LandingSetupError
from companion.delivery.replay import replay_run
from companion_lab.campaign_landing import draw_scenarios
from companion_lab.demo import run_demo
from companion_sitl.params import SimulatedConfig, load_simulated_config

pytestmark = pytest.mark.flight

DRIFT_S_M = 0.3 / 9.80665  # the simulated parcel's drag over g (test_winch_flight.py)


def _config(snag_m: float = 0.0, tag: bool = True, tag_id: int = 7) -> SimulatedConfig:
    d = draw_scenarios(5, 11)[3]  # 1.2 m/s of wind
    winch = {"fitted": True, "draw_parcel": True, "parcel_tag": tag, "snag_height_m": snag_m}
    return load_simulated_config(
        shipped_params_path("landing_campaign.toml"),
        overrides={
            "sim": {**d.sim_overrides(), "winch": winch},
            "mission": {"delivery": "winch"},
            "winch": {"wind_drift_s_m": DRIFT_S_M, "camera": {"enabled": True, "tag_id": tag_id}},
        },
    )


def _winch_said(r) -> list[str]:  # type: ignore[no-untyped-def]
    return [d for _, k, _, d in r.events if k == "winch"]


def test_seen_down_on_the_pad_it_is_released_and_the_flight_replays(tmp_path: Path) -> None:
    run = tmp_path / "run"
    r = run_demo(_config(), run_dir=run)
    assert r.delivered and r.returned and not r.home_with_parcel, r.failure
    said = _winch_said(r)
    looked = [s for s in said if s.startswith("the camera sees the parcel on the pad")]
    assert len(looked) == 1, said
    bottom = float(looked[0].split("its bottom ")[1].split(" m")[0])
    assert abs(bottom) <= 0.15  # down_tolerance_m; it lies on the ground (truth), the estimate's error
    assert r.parcel_touchdown_error_m < 0.3
    assert (run / "parcel.csv").exists()
    rep = replay_run(run, tmp_path / "replayed")
    assert rep.identical, "\n".join(rep.lines())


def test_caught_a_metre_above_the_pad_it_comes_home() -> None:
    r = run_demo(_config(snag_m=1.0))
    assert not r.delivered and r.home_with_parcel and r.returned
    assert "the camera sees the parcel 1.0" in r.failure and "above the pad" in r.failure, r.failure
    # the PWM winch's line length alone said it was down
    assert any(s.startswith("parcel down: line") for s in _winch_said(r))
    assert math.isnan(r.parcel_touchdown_error_m)  # it never reached the ground (truth): caught, then reeled up


def test_a_parcel_without_its_tag_is_not_released() -> None:
    r = run_demo(_config(tag=False))
    assert not r.delivered and r.home_with_parcel
    assert r.failure == (
        "parcel not delivered: the camera did not see the parcel's tag within 4.0 s with the line out 5.30 m"
    )


def test_a_tag_that_is_one_of_the_pads_markers_is_refused_before_take_off() -> None:
    with pytest.raises(LandingSetupError, match=r"the pad's inner marker; choose another winch\.camera\.tag_dict"):
        run_demo(_config(tag_id=0))

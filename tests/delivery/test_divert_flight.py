"""A whole delivery on the embedded simulator whose first pad is missing: the vehicle diverts to the
alternate pad (a real pad there: the simulated camera and UWB see it), releases on it, flies home,
and the replay of the flight is identical bit for bit."""

from __future__ import annotations

import csv
import math
from pathlib import Path

import pytest

from companion.config import shipped_params_path
from companion.delivery.replay import replay_run
from companion_lab.campaign_landing import diverted, draw_scenarios, scenario_config
from companion_lab.demo import run_demo, true_pad_ned

pytestmark = pytest.mark.flight


def test_first_pad_missing_diverts_releases_on_the_alternate_and_replays_identically(tmp_path: Path) -> None:
    draw = draw_scenarios(1, 11)[0]
    config = scenario_config(shipped_params_path("landing_campaign.toml"), draw, "pad_missing_alternate")
    config = config.model_copy(update={"mission": config.mission.model_copy(update={"return_home": True})})
    run = tmp_path / "run"
    r = run_demo(config, run_dir=run)
    assert r.delivered and r.returned and not r.home_with_parcel, r.failure
    assert diverted(r.events) and r.pad_tries == 2  # the two tries on the first pad
    # released on the alternate: the true touchdown is on the real pad (1 x 1 m), 25 m from the first
    assert r.pad_landing_error_m < 0.3
    n, e = true_pad_ned(config)
    assert math.hypot(n, e) > 30.0
    assert r.home_landing_error_m < 3.0
    with (run / "events.csv").open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    kinds = [(row["kind"], row["phase"], row["detail"]) for row in rows]
    assert any(k == "pad_lock" and "diverting to the alternate pad" in d for k, _, d in kinds)
    assert any(k == "phase" and d == "divert" for k, _, d in kinds)
    assert any(k == "delivered" and d == "parcel released on the alternate pad" for k, _, d in kinds)
    assert any(k == "phase" and d.startswith("return path planned from the landing point") for k, _, d in kinds)
    rep = replay_run(run, tmp_path / "replayed")
    assert rep.identical, "\n".join(rep.lines())


def test_no_lock_on_either_pad_brings_the_parcel_home(tmp_path: Path) -> None:
    """Camera and UWB dead all flight: two tries on the first pad, the divert, two tries on the
    alternate, then home with the parcel on a path planned from over the alternate."""
    draw = draw_scenarios(1, 11)[0]
    config = scenario_config(shipped_params_path("landing_campaign.toml"), draw, "pad_missing_alternate")
    sim = config.sim.model_copy(update={"camera_fails_below_m": 10000.0, "uwb_fails_below_m": 10000.0})
    config = config.model_copy(update={"sim": sim})
    run = tmp_path / "run"
    r = run_demo(config, run_dir=run)
    assert not r.delivered and r.home_with_parcel and r.returned, r.failure
    assert diverted(r.events) and r.pad_tries == 4
    assert r.failure == "parcel not delivered: 2 tries without a pad lock on the alternate pad"
    assert r.home_landing_error_m < 3.0
    assert not any(kind == "released" for _, kind, _, _ in r.events)
    assert any(kind == "phase" and d.startswith("return path planned from the divert") for _, kind, _, d in r.events)
    rep = replay_run(run, tmp_path / "replayed")
    assert rep.identical, "\n".join(rep.lines())

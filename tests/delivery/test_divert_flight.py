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

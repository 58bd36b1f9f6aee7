"""The drop-zone check in flight (docs/drop-zone.md), on the embedded simulator: each frame the
detector sees in the approach and the descent is also judged, and the verdict reaches the mission.
A box on the pad stops the descent and the parcel flies home; a person walking into the margin
during the descent stops it until the person has gone, then the parcel is released on the pad; a
clear pad with the check on lands as without it. The verdicts are in the run folder
(drop_zone.csv): the replay of the held flight is identical bit for bit."""

from __future__ import annotations

import math
import shutil
from pathlib import Path
from typing import Any

import pytest

from companion.config import shipped_params_path
from companion.delivery.replay import replay_run
from companion.flightlog.reader import LogFormatError
from companion_lab.campaign_landing import draw_scenarios, scenario_config
from companion_lab.demo import run_demo

pytestmark = pytest.mark.flight


def _config(seed: int, kind: str, **occluder: Any):  # type: ignore[no-untyped-def]
    cfg = scenario_config(shipped_params_path("landing_campaign.toml"), draw_scenarios(1, seed)[0], "fusion")
    dz = cfg.landing.drop_zone.model_copy(update={"enabled": True})
    occ = cfg.sim.camera.occluder.model_copy(update={"kind": kind, **occluder})
    sim = cfg.sim.model_copy(update={"camera": cfg.sim.camera.model_copy(update={"occluder": occ})})
    return cfg.model_copy(update={"landing": cfg.landing.model_copy(update={"drop_zone": dz}), "sim": sim})


def _drop_zone_events(r) -> list[tuple[str, str]]:  # type: ignore[no-untyped-def]
    return [(phase, detail) for _, kind, phase, detail in r.events if kind == "drop_zone"]


def test_a_box_on_the_pad_stops_the_descent_and_the_parcel_flies_home(tmp_path: Path) -> None:
    cfg = _config(1, "box")
    r = run_demo(cfg, run_dir=tmp_path / "run")
    assert not r.delivered and r.home_with_parcel, r.failure
    assert not any(kind == "released" for _, kind, _, _ in r.events)
    dz = _drop_zone_events(r)
    assert dz[0][1].startswith("an object on the pad"), dz
    assert any(d == f"drop zone not clear after holding {cfg.landing.drop_zone.hold_s:g} s (occupied)" for _, d in dz)
    # stopped above the commit height: the descent never reached the box
    held = next(t for t, kind, _, d in r.events if kind == "phase" and d == "drop_zone_hold")
    assert not any(kind == "touchdown" and d == "pad" for t, kind, _, d in r.events if t > held)
    assert r.home_landing_error_m < 3.0
    verdicts = (tmp_path / "run" / "drop_zone.csv").read_text().splitlines()
    assert verdicts[0] == "time_s,seq,verdict" and any(row.endswith(",occupied") for row in verdicts)
    rep = replay_run(tmp_path / "run", tmp_path / "replayed")
    assert rep.identical, "\n".join(rep.lines())
    # a verdict the log cannot hold is an error naming the file, the row and what is expected
    bad = tmp_path / "bad"
    shutil.copytree(tmp_path / "run", bad)
    verdicts[1] = verdicts[1].rsplit(",", 1)[0] + ",ocupied"
    (bad / "drop_zone.csv").write_text("\n".join(verdicts) + "\n")
    with pytest.raises(LogFormatError, match=r"drop_zone.csv row 2: verdict 'ocupied' is not one of \['clear'"):
        replay_run(bad, tmp_path / "replayed_bad")


def test_a_person_walking_into_the_margin_holds_the_descent_until_gone() -> None:
    r = run_demo(_config(1, "person", from_height_m=6.0, window_s=4.0))
    assert r.delivered and not r.home_with_parcel, r.failure
    dz = _drop_zone_events(r)
    assert dz[0][0] == "landing_pad" and dz[0][1].startswith("motion in the pad's margin in the descent"), dz
    assert dz[1][1].startswith("drop zone clear after holding"), dz
    stopped = next(t for t, kind, _, d in r.events if kind == "drop_zone")
    released = next(t for t, kind, _, d in r.events if kind == "released")
    assert released > stopped
    assert math.isfinite(r.pad_landing_error_m) and r.pad_landing_error_m < 0.1


def test_a_clear_pad_with_the_check_on_lands_as_without_it() -> None:
    on = run_demo(_config(1, "none"))
    off = run_demo(scenario_config(shipped_params_path("landing_campaign.toml"), draw_scenarios(1, 1)[0], "fusion"))
    assert on.delivered and off.delivered
    assert _drop_zone_events(on) == []
    assert on.pad_landing_error_m < 0.1
    assert abs(on.pad_landing_error_m - off.pad_landing_error_m) < 0.03

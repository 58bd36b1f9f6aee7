"""Whole deliveries onto a moving pad on the embedded simulator ([sim.pad_motion] with
[landing.moving_pad] on, docs/moving-pad.md): a pad driving at 2 m/s straight and one turning,
scored against the pad's true position at the touchdown; the parcel on the pad; a pad faster than
landing.moving_pad.max_speed_m_s is not landed on and the parcel flies home. The pad starts
moving at 34 s, during the approach (the vehicle reaches the landing at ~39 s)."""

from __future__ import annotations

from pathlib import Path

import pytest

from companion.config import shipped_params_path
from companion.delivery.replay import replay_run
from companion_lab.campaign_landing import draw_scenarios, scenario_config
from companion_lab.demo import run_demo
from companion_sitl.params import SimConfig, SimulatedConfig

pytestmark = pytest.mark.flight


def _moving(speed_m_s: float, turn_deg_s: float = 0.0, enabled: bool = True) -> SimulatedConfig:
    draw = draw_scenarios(1, 11)[0]
    base = scenario_config(shipped_params_path("landing_campaign.toml"), draw, "fusion")
    motion = {"speed_m_s": speed_m_s, "course_deg": 60.0, "turn_rate_deg_s": turn_deg_s, "start_s": 34.0}
    sim = SimConfig.model_validate({**base.sim.model_dump(), "pad_motion": motion})
    mp = base.landing.moving_pad.model_copy(update={"enabled": enabled})
    return base.model_copy(update={"sim": sim, "landing": base.landing.model_copy(update={"moving_pad": mp})})


def test_lands_on_a_pad_driving_at_2_m_s_and_replays_identically(tmp_path: Path) -> None:
    run = tmp_path / "run"
    r = run_demo(_moving(2.0), run_dir=run)
    assert r.delivered, r.failure
    assert r.pad_landing_error_m < 0.15  # against the pad where it was at the touchdown
    assert any(e[1] == "delivered" for e in r.events)
    rep = replay_run(run, tmp_path / "replayed")
    assert rep.identical, "\n".join(rep.lines())


def test_lands_on_a_pad_turning_at_3_deg_s() -> None:
    r = run_demo(_moving(2.0, turn_deg_s=3.0))
    assert r.delivered, r.failure
    assert r.pad_landing_error_m < 0.15


def test_without_the_moving_pad_model_the_pad_is_never_locked_and_nothing_is_released() -> None:
    r = run_demo(_moving(2.0, enabled=False))
    assert not r.delivered and r.home_with_parcel
    assert r.failure_kind.value == "not_delivered"


def test_a_pad_faster_than_the_limit_is_not_landed_on_and_the_parcel_flies_home() -> None:
    r = run_demo(_moving(4.0))
    assert not r.delivered and r.home_with_parcel
    assert "faster than landing.moving_pad.max_speed_m_s = 3.5 m/s" in r.failure
    events = [e for e in r.events if e[1] == "pad_lock" and "not landing on the pad" in e[3]]
    assert len(events) == 1
    assert not any(e[1] in ("touchdown",) and e[3] == "pad" for e in r.events)  # never touched down there

"""Seeded small version of `companion campaign landing` (the full one prints the campaign's table)."""

import json

import matplotlib.image as mpimg
import pytest

from companion.cli.main import main
from companion_lab.campaign_landing import draw_scenarios
from companion_lab.landing_campaign import run_landing_campaign

pytestmark = pytest.mark.flight


def test_draws_are_seeded_and_bounded():
    a, b = draw_scenarios(20, 3), draw_scenarios(20, 3)
    assert a == b and a != draw_scenarios(20, 4)
    assert all(abs(d.gps_bias_m[0]) <= 4.5 and (d.pad_offset_m[0] ** 2 + d.pad_offset_m[1] ** 2) <= 1.0 for d in a)
    with pytest.raises(ValueError):
        draw_scenarios(0, 1)


def test_a_variants_configuration_does_not_carry_over_into_the_next_landing():
    """The firmware tuning is shared by every landing of a campaign: the pad_heading and winch
    variants change their own copy of its mission table, not the tuning the next landing uses."""
    import copy

    from companion.config import shipped_params_path
    from companion_lab.campaign_landing import scenario_config
    from companion_lab.real_campaign import firmware_tuning

    base = shipped_params_path("landing_campaign.toml")
    (d,) = draw_scenarios(1, 11)
    tuning = firmware_tuning("px4")
    before = copy.deepcopy(tuning)
    headed = scenario_config(base, d, "pad_heading", "px4-sih", tuning)
    winch = scenario_config(base, d, "winch", "px4-sih", tuning)
    plain = scenario_config(base, d, "fusion", "px4-sih", tuning)
    assert tuning == before
    assert headed.mission.pad.heading_deg is not None and winch.mission.delivery == "winch"
    assert plain.mission.pad.heading_deg is None and plain.mission.delivery == "land"
    assert plain.mission.descent.xy_gain_1_s == tuning["mission"]["descent"]["xy_gain_1_s"]  # the tuning still applies


def test_fusion_beats_gps_only_and_every_failure_variant_lands_on_the_pad():
    # 18 landings in two worker processes (52.6 s in one here, 40.6 s in two; the same result)
    r = run_landing_campaign(3, 11, ("fusion", "gps_only", "no_camera", "no_uwb", "outer_only", "inner_only"), jobs=2)
    s = r["summary"]
    assert s["fusion"]["on_pad_pct"] == 100.0 and s["fusion"]["max_m"] <= 0.25 and s["fusion"]["mean_m"] <= 0.15
    assert s["gps_only"]["mean_m"] >= 0.8  # the drawn bias is real
    for v in ("no_camera", "no_uwb", "outer_only", "inner_only"):
        assert s[v]["on_pad_pct"] == 100.0, (v, s[v])


def test_campaign_command_writes_summary_and_scatter_the_same_in_two_processes_as_in_one(tmp_path, capsys):
    out = {j: tmp_path / f"camp{j}" for j in (2, 1)}
    for j, d in out.items():
        assert (
            main(["campaign", "landing", "--n", "2", "--seed", "5", "--jobs", str(j), "--out", str(d), "--quiet"]) == 0
        )
    summary = json.loads((out[2] / "landing_campaign.json").read_text())["summary"]
    assert set(summary) == {"fusion", "gps_only"}
    img = mpimg.imread(out[2] / "landing_scatter.png")
    assert img.shape[0] > 400 and img[..., :3].std() > 0.03
    assert "on the pad" in capsys.readouterr().out
    # the landings flown in worker processes (the camera ones first): the same rows, in the same order
    for name in ("landing_campaign.json", "landing_scatter.png"):
        assert (out[2] / name).read_bytes() == (out[1] / name).read_bytes(), name

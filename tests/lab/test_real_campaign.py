"""The real-SITL landing campaign and the parity check, the parts that need no firmware: the
mapping of a draw onto a SITL, the comparison, the figure and the profile campaign."""

from __future__ import annotations

import json
import math
import os

import matplotlib.image as mpimg
import pytest

from companion.cli.main import main
from companion.config import EkfConfig, shipped_params_path
from companion.delivery.planning import pad_position_ned
from companion.geometry.earth import GeoPoint
from companion_lab.campaign_landing import Draw, draw_scenarios, scenario_config
from companion_lab.landing_campaign import run_landing_campaign
from companion_lab.real_campaign import (
    compare,
    firmware_tuning,
    landing_config,
    landing_diagnostics,
    parity_figure,
    real_config,
    real_pad_displacement,
    run_real_landing_campaign,
)
from companion_sitl.params import load_simulated_config


def test_a_draw_maps_onto_a_sitl_without_gps_bias():
    d = Draw(seed=7, gps_bias_m=(1.0, -2.0, 0.3), pad_offset_m=(0.25, 0.5), wind_speed_m_s=3.0, wind_from_deg=90.0)
    assert real_pad_displacement(d) == (1.25, -1.5)  # the vehicle arrives at the biased pad
    base = shipped_params_path("landing_campaign.toml")
    cfg = real_config(base, "px4", "fusion")
    h = cfg.sim.home
    n, e, _ = pad_position_ned(load_simulated_config(base).mission, GeoPoint(h.lat_deg, h.lon_deg, h.alt_amsl_m))
    assert cfg.mission.pad.north_m == pytest.approx(n) and cfg.mission.pad.east_m == pytest.approx(e)
    assert cfg.mission.pad.lat_deg is None and cfg.autopilot == "px4"
    assert math.hypot(n, e) == pytest.approx(15.0, abs=0.5)  # the shipped pad, 15 m from home
    # the firmware's own landing tuning comes from its shipped parameters (params/px4_sih_quad.toml)
    assert firmware_tuning("px4") == {
        "landing": {
            "ekf": {
                **EkfConfig().model_dump(),
                "position_process_sigma_m_per_sqrt_s": 0.3,
                "gate_reset_after_rejections": 5,
            },
            "ekf_velocity_bias_tau_s": 1.0,  # PX4's velocity, the EKF's input, corrected
            "ekf_level_pad": True,  # PX4's roll / pitch error, seen on the level pad, taken out
        },
        "mission": {
            "land_speed_m_s": 0.7,  # PX4's MPC_LAND_SPEED: less time for its estimate to wander
            "descent": {
                "xy_gain_1_s": 5.0,
                "xy_tolerance_m": 0.04,  # aligned within 4-8 cm before it goes on down
                "max_xy_speed_m_s": 1.0,
                "hold_min_height_m": 0.3,  # down to where the camera still sees the pad
                "settle_s": 0.0,  # no wait at that height (held out, it did not help)
                "touchdown_height_m": -1.0,  # closed until the ground contact...
                "contact_time_s": 0.3,  # ...once it stopped sinking 0.3 s, not PX4's ON_GROUND seconds later
                "xy_integral_gain_1_s2": 2.5,
                "xy_integral_max_m_s": 0.5,
                "xy_accel_feedforward": 0.4,  # the command's rate fed forward: no circling
            },
            "velocity_bias_tau_s": 1.0,
            "velocity_bias_source": "fusion",  # against the pad, not PX4's drifting position
            "autopilot_accel_xy_m_s2": 1.0,  # the field's speed within what SIH's velocity loop delivers
            "autopilot_accel_z_m_s2": 1.0,
        },
    }
    assert firmware_tuning("ardupilot")["mission"]["velocity_bias_tau_s"] == 0.0  # its estimate is consistent
    assert firmware_tuning("ardupilot")["mission"]["land_speed_m_s"] == 0.5  # LAND_SPEED, as the campaign's
    assert firmware_tuning("ardupilot")["mission"]["autopilot_accel_z_m_s2"] == 0.5  # GUIDED's limits
    assert cfg.landing.ekf.position_process_sigma_m_per_sqrt_s == 0.3 and cfg.mission.descent.xy_gain_1_s == 5.0
    assert firmware_tuning("ardupilot")["mission"]["descent"]["touchdown_height_m"] == 0.15  # the default
    assert real_config(base, "px4", "gps_only").landing.fusion is False
    with pytest.raises(ValueError, match="unknown variant"):
        real_config(base, "px4", "no_such")


def test_each_real_landing_renders_its_sensors_with_its_own_draw_seed():
    # the camera's and UWB's noise come from sim.seed (sitl/landing_sensors.sim_landing_kit): one
    # seed for every landing would give every draw the same noise, hence a shared error
    base = shipped_params_path("landing_campaign.toml")
    a, b = draw_scenarios(2, 61)
    for variant in ("fusion", "pad_heading"):
        cfg = real_config(base, "ardupilot", variant)
        got = [landing_config(cfg, variant, d) for d in (a, b)]
        embedded = [scenario_config(base, d, variant).sim.seed for d in (a, b)]
        assert [c.sim.seed for c in got] == [a.seed, b.seed] == embedded
        assert cfg.sim.seed == load_simulated_config(base).sim.seed  # the variant's own configuration is left as it was
        assert got[0].mission.pad.north_m == cfg.mission.pad.north_m  # the pad stays where the SITL's home puts it
    heading = landing_config(real_config(base, "ardupilot", "pad_heading"), "pad_heading", a)
    assert heading.mission.pad.heading_deg == scenario_config(base, a, "pad_heading").mission.pad.heading_deg
    assert landing_config(real_config(base, "ardupilot", "fusion"), "fusion", a).mission.pad.heading_deg is None


def test_profile_campaign_flies_the_same_draws_without_wind_on_px4_sih():
    d = draw_scenarios(1, 4)[0]
    cfg = scenario_config(shipped_params_path("landing_campaign.toml"), d, "fusion", "px4-sih")
    assert cfg.sim.profile == "px4-sih" and cfg.sim.wind_speed_m_s == d.wind_speed_m_s  # the vehicle drops it
    tuned = scenario_config(
        shipped_params_path("landing_campaign.toml"), d, "gps_only", "px4-sih", firmware_tuning("px4")
    )
    assert tuned.mission.descent.xy_gain_1_s == 5.0 and tuned.landing.fusion is False
    r = run_landing_campaign(1, 4, ("fusion",), profile="px4-sih")
    assert r["profile"] == "px4-sih" and r["landings"]["fusion"][0]["wind_m_s"] == 0.0
    assert r["landings"]["fusion"][0]["delivered"]


def _campaign(errors: list[float], pad: float = 0.5) -> dict:
    rows = [{"seed": 1000 + k, "error_m": e, "on_pad": math.isfinite(e) and e <= pad} for k, e in enumerate(errors)]
    return {"landings": {"fusion": rows}}


def test_compare_against_hand_computed_figures(tmp_path):
    pred = _campaign([0.10, 0.20, 0.30, 0.40])
    real = _campaign([0.10, 0.10, 0.20, 0.20])
    c = compare(pred, real)
    assert c["predicted"]["mean_m"] == pytest.approx(0.25) and c["real"]["mean_m"] == pytest.approx(0.15)
    # numpy's linear p90 of (0.1, 0.2, 0.3, 0.4): 0.37; of (0.1, 0.1, 0.2, 0.2): 0.2
    assert c["predicted"]["p90_m"] == pytest.approx(0.37) and c["real"]["p90_m"] == pytest.approx(0.2)
    assert c["ratio_predicted_to_real"]["mean_m"] == pytest.approx(0.25 / 0.15)
    assert c["mean_and_p90_within_factor"] is False  # 1.67x and 1.85x > 1.5x
    assert c["failure_classes_agree"] and c["failure_class_disagreements"] == []
    # the failure classes agree draw by draw: one seed off the pad in one run only is a disagreement
    one = compare(_campaign([0.1] * 10), _campaign([0.1] * 9 + [0.9]))
    assert not one["failure_classes_agree"] and one["failure_class_disagreements"] == [1009]
    ok = compare(_campaign([0.10, 0.12, 0.14]), _campaign([0.09, 0.13, 0.15]))
    assert ok["mean_and_p90_within_factor"] and ok["failure_classes_agree"]
    # a landing that never happened (NaN) is counted: not in the figures, a failure-class disagreement
    nan = compare(_campaign([0.1, math.nan]), _campaign([0.1, 0.1]))
    assert nan["predicted"]["mean_m"] == pytest.approx(0.1)
    assert (nan["predicted"]["landed"], nan["predicted"]["n"]) == (1, 2) and nan["real"]["landed"] == 2
    assert not nan["failure_classes_agree"] and nan["failure_class_disagreements"] == [1001]
    res = {"autopilot": "px4", "profile": "px4-sih", "comparison": {"fusion": c}}
    img = mpimg.imread(parity_figure(res, tmp_path / "parity.png"))
    assert img.shape[0] > 300 and img[..., :3].std() > 0.03


def test_campaign_command_with_a_profile(tmp_path, capsys):
    out = tmp_path / "new" / "folder"
    args = ["campaign", "landing", "--n", "1", "--seed", "2", "--variants", "fusion", "--profile", "px4-sih"]
    assert main([*args, "--out", str(out), "--quiet"]) == 0
    result = json.loads((out / "landing_campaign.json").read_text())
    assert result["profile"] == "px4-sih" and "p90_m" in result["summary"]["fusion"]
    assert "px4-sih profile" in capsys.readouterr().out
    with pytest.raises(SystemExit):  # a profile and a real autopilot are two different campaigns
        main([*args, "--autopilot", "px4"])


def test_landing_diagnostics_names_the_machine_and_splits_each_error():
    rows = [
        {
            "seed": 7,
            "error_m": 0.0412,
            "north_m": 0.03,
            "east_m": -0.0283,
            "believed_offset_m": 0.02,
            "estimate_error_m": 0.05,
            "guidance_overruns": 2,
            "setpoint_overruns": 0,
            "markers_used": 300,
            "uwb_used": 200,
        },
        # a landing that could not be flown has no split
        {"seed": 8, "error_m": math.nan, "north_m": math.nan, "east_m": math.nan, "markers_used": 0, "uwb_used": 0},
    ]
    text = landing_diagnostics(rows)
    machine, first, second = text.split("; ")
    assert f"x{os.cpu_count()}, load " in machine
    assert first == (
        "seed 7: 0.041 m (N +0.030 E -0.028), believed 0.020 m, estimate error 0.050 m, "
        "overruns 2/0, markers 300, uwb 200"
    )
    assert second.startswith("seed 8: nan m") and "believed nan m" in second


def test_gnss_lost_variants_fly_external_nav_beside_gps_only_on_the_same_draws():
    base = shipped_params_path("landing_campaign_short.toml")
    d = draw_scenarios(1, seed=1)[0]
    ext = scenario_config(base, d, "gnss_lost_10m", "arducopter-sitl")
    gps = scenario_config(base, d, "gnss_lost_10m_gps_only", "arducopter-sitl")
    three = scenario_config(base, d, "gnss_lost_3m", "arducopter-sitl")
    assert ext.external_nav.enabled and ext.landing.fusion and ext.sim.gnss_lost_below_m == 10.0
    assert not gps.external_nav.enabled and not gps.landing.fusion and gps.sim.gnss_lost_below_m == 10.0
    assert three.sim.gnss_lost_below_m == 3.0
    assert ext.sim.pad_offset_m == gps.sim.pad_offset_m and ext.sim.seed == gps.sim.seed  # the same draw


@pytest.mark.parametrize("autopilot", ["ardupilot", "px4"])
def test_the_real_gnss_lost_variants_cut_at_their_height_and_gps_only_never_releases(autopilot):
    base = shipped_params_path("landing_campaign.toml")
    ext = real_config(base, autopilot, "gnss_lost_10m")
    gps = real_config(base, autopilot, "gnss_lost_10m_gps_only")
    three = real_config(base, autopilot, "gnss_lost_3m")
    assert ext.sim.gnss_lost_below_m == 10.0 and three.sim.gnss_lost_below_m == 3.0
    assert ext.sim.gnss_lost_within_m == gps.sim.gnss_lost_within_m == 6.0
    assert ext.external_nav.enabled and ext.landing.fusion and ext.landing.policy.require_pad_lock
    # GPS-only with the same cut: no pose for the autopilot, and no release (no lock without pad sensors)
    assert gps.sim.gnss_lost_below_m == 10.0 and not gps.external_nav.enabled and not gps.landing.fusion
    assert gps.landing.policy.require_pad_lock
    assert ext.mission.pad == gps.mission.pad == three.mission.pad  # the same pad, the same draws
    # the other variants cut nothing
    assert real_config(base, autopilot, "fusion").sim.gnss_lost_below_m == 0.0
    assert not real_config(base, autopilot, "gps_only").external_nav.enabled
    d = draw_scenarios(1, seed=300000)[0]
    assert landing_config(ext, "gnss_lost_10m", d).sim.gnss_lost_below_m == 10.0


def test_bad_real_gnss_lost_campaigns_are_refused_before_any_sitl_starts():
    base = shipped_params_path("landing_campaign.toml")
    with pytest.raises(ValueError, match=r"autopilot 'sim': expected one of"):
        real_config(base, "sim", "gnss_lost_3m")
    with pytest.raises(ValueError, match=r"variants \['gnss_lost_3m'\] with weather"):
        run_real_landing_campaign("ardupilot", 1, 300000, ("fusion", "gnss_lost_3m"), weather=True)
    with pytest.raises(ValueError, match=r"weather on px4"):
        run_real_landing_campaign("px4", 1, 300000, ("gnss_lost_3m",), weather=True)

"""The winch delivery's settings: default off, and the combinations that cannot fly refused at load."""

from __future__ import annotations

import pytest

from companion.config import ConfigError, shipped_params_path
from companion_sitl.params import load_simulated_config


def test_winch_delivery_is_off_by_default() -> None:
    cfg = load_simulated_config(shipped_params_path("sitl_short.toml"))
    assert cfg.mission.delivery == "land" and not cfg.sim.winch.fitted
    assert cfg.winch.wind_drift_s_m == 0.0


def test_px4_cannot_fly_a_winch_delivery() -> None:
    with pytest.raises(ConfigError, match=r"PX4 v1\.16 has no winch"):
        load_simulated_config(
            shipped_params_path("sitl_short.toml"), overrides={"autopilot": "px4", "mission": {"delivery": "winch"}}
        )


def test_a_winch_delivery_is_not_handed_to_the_autopilots_precision_landing() -> None:
    with pytest.raises(ConfigError, match="never hands a descent to the autopilot"):
        load_simulated_config(
            shipped_params_path("sitl_short.toml"),
            overrides={
                "mission": {"delivery": "winch"},
                "landing": {"controller": "autopilot", "landing_target_output": "body_angles"},
            },
        )


def test_winch_values_out_of_range_name_the_key() -> None:
    with pytest.raises(ConfigError, match=r"winch\.hover_height_m"):
        load_simulated_config(shipped_params_path("sitl_short.toml"), overrides={"winch": {"hover_height_m": 0.2}})


def test_the_winch_campaign_variant_flies_winch_deliveries_on_the_embedded_simulator_only() -> None:
    from companion_lab.campaign_landing import WINCH_DRIFT_S_M, draw_scenarios, scenario_config
    from companion_lab.real_campaign import real_config

    base = shipped_params_path("landing_campaign.toml")
    cfg = scenario_config(base, draw_scenarios(1, 5)[0], "winch")
    assert cfg.mission.delivery == "winch" and cfg.sim.winch.fitted
    assert cfg.winch.wind_drift_s_m == WINCH_DRIFT_S_M == pytest.approx(cfg.sim.winch.parcel_drag_1_s / 9.80665)
    assert scenario_config(base, draw_scenarios(1, 5)[0], "fusion").mission.delivery == "land"
    with pytest.raises(ValueError, match="embedded simulator's line model"):
        real_config(base, "ardupilot", "winch")


def test_the_cameras_look_is_off_by_default_and_needs_a_winch_and_the_camera() -> None:
    cfg = load_simulated_config(shipped_params_path("sitl_short.toml"))
    assert not cfg.winch.camera.enabled and not cfg.sim.winch.draw_parcel
    with pytest.raises(ConfigError, match=r"winch\.camera\.enabled = true with mission\.delivery = 'land'"):
        load_simulated_config(
            shipped_params_path("sitl_short.toml"), overrides={"winch": {"camera": {"enabled": True}}}
        )
    with pytest.raises(ConfigError, match=r"needs landing\.fusion = true and landing\.use_camera = true"):
        load_simulated_config(
            shipped_params_path("sitl_short.toml"),
            overrides={
                "mission": {"delivery": "winch"},
                "winch": {"camera": {"enabled": True}},
                "landing": {"use_camera": False},
            },
        )
    with pytest.raises(ConfigError, match=r"winch\.camera\.tag_dict.*not a cv2\.aruco dictionary name"):
        load_simulated_config(
            shipped_params_path("sitl_short.toml"), overrides={"winch": {"camera": {"tag_dict": "DICT_9X9_1"}}}
        )

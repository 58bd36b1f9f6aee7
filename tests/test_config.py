from pathlib import Path

import pytest

from companion.config import ConfigError, config_from_dict, describe_parameters, load_config, shipped_params_path
from companion_sitl.params import SimulatedConfig, load_simulated_config, simulated_config_from_dict


def write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "p.toml"
    p.write_text(text)
    return p


def test_every_shipped_params_file_validates():
    folder = shipped_params_path("delivery_paper.toml").parent
    files = sorted(folder.glob("*.toml"))
    assert files
    for f in files:
        if f.name.startswith(("camera_", "uwb_", "zenoh_", "pad_", "dart_")):
            continue  # other schemas (their own loaders test them)
        load_config(f)


def test_paper_parameters():
    c = load_config(shipped_params_path("delivery_paper.toml"))
    assert (c.mission.height_m, c.mission.arc_radius_m) == (45.0, 6.0)


def test_unknown_key_names_file_and_key(tmp_path):
    p = write(tmp_path, "[mission]\nheight_m = 40.0\narc_raduis_m = 5.0\n")
    with pytest.raises(ConfigError) as ei:
        load_config(p)
    msg = str(ei.value)
    assert str(p) in msg and "mission.arc_raduis_m" in msg and "unknown key" in msg


def test_wrong_type_and_out_of_range(tmp_path):
    p = write(tmp_path, '[mission]\nheight_m = "high"\n[limits]\nmax_climb_m_s = -1.0\n')
    with pytest.raises(ConfigError) as ei:
        load_config(p)
    probs = ei.value.problems
    assert any(x.startswith("mission.height_m = 'high'") and "number" in x for x in probs)
    assert any(x.startswith("limits.max_climb_m_s = -1.0") and "greater than 0" in x for x in probs)


@pytest.mark.parametrize(
    ("mission", "rule"),
    [
        ({"arc_radius_m": 50.0}, "arc_radius_m (50.0) must be < height_m (45.0)"),
        ({"arc_radius_m": 0.0}, "greater than 0"),
        ({"sector_speed_m_s": [2, 3, -5, 3, 1]}, "v3"),
        ({"sector_speed_m_s": [2, 3, 5]}, "sector_speed_m_s"),
        ({"pad": {"north_m": 1.0}}, "north_m and east_m go together"),
        ({"pad": {"north_m": 1.0, "east_m": 2.0, "lat_deg": 3.0, "lon_deg": 4.0}}, "one form"),
    ],
)
def test_impossible_mission_geometry(mission, rule):
    with pytest.raises(ConfigError) as ei:
        config_from_dict({"mission": mission}, "test.toml")
    assert rule in str(ei.value) and "test.toml" in str(ei.value)


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(ConfigError, match="file not found"):
        load_config(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match="not valid TOML"):
        load_config(write(tmp_path, "[mission\nheight_m = 1"))
    with pytest.raises(ConfigError, match="no shipped parameter set"):
        shipped_params_path("nope.toml")


def test_later_files_and_overrides_win(tmp_path):
    a = write(tmp_path, "[sim]\nseed = 3\nwind_speed_m_s = 2.0\n")
    c = load_simulated_config(a, overrides={"sim": {"seed": 9}})
    assert c.sim.seed == 9 and c.sim.wind_speed_m_s == 2.0
    assert load_config(a, overrides={"sim": {"seed": 9}}).sim == {"seed": 9, "wind_speed_m_s": 2.0}


def test_the_application_takes_the_sim_tables_as_they_are_and_the_simulator_checks_them(tmp_path):
    """[sim] is the embedded simulator's (companion_sitl.params): the application loads every
    shipped file with its [sim] tables unread; the simulator's loader refuses a bad value."""
    for name in ("delivery_paper.toml", "sitl_short.toml", "px4_sih_quad.toml", "ardupilot_quad.toml"):
        app, sim = load_config(shipped_params_path(name)), load_simulated_config(shipped_params_path(name))
        assert app.model_dump(exclude={"sim"}) == sim.model_dump(exclude={"sim"})
    p = write(tmp_path, "[sim]\nwind_speed_m_s = 99.0\n[sim.vehicle]\nmax_tilt_deg = 1.0\n")
    assert load_config(p).sim == {"wind_speed_m_s": 99.0, "vehicle": {"max_tilt_deg": 1.0}}
    with pytest.raises(ConfigError) as err:
        load_simulated_config(p)
    assert err.value.source == str(p)
    assert any(
        x.startswith("sim.wind_speed_m_s = 99.0: Input should be less than or equal to 25") for x in err.value.problems
    )
    assert any(
        x.startswith("sim.vehicle.max_tilt_deg = 1.0: Input should be greater than 5") for x in err.value.problems
    )


def test_describe_parameters_lists_units_and_limits():
    lines = describe_parameters(load_config(shipped_params_path("delivery_paper.toml")))
    line = next(x for x in lines if x.startswith("mission.arc_radius_m"))
    assert "[m]" in line and "> 0.0" in line and "radius" in line


@pytest.mark.parametrize(
    ("table", "value", "line"),
    [
        ("mission", {"arc_radius_m": 50.0}, "mission: arc_radius_m (50.0) must be < height_m (45.0)"),
        ("mission", {"pad": {"north_m": 1.0}}, "mission.pad: pad north_m and east_m go together"),
    ],
)
def test_a_rule_between_keys_names_the_keys_not_the_whole_table(table, value, line):
    with pytest.raises(ConfigError) as ei:
        config_from_dict({table: value}, "test.toml")
    assert any(p.startswith(line) for p in ei.value.problems), ei.value.problems
    assert not any("{" in p for p in ei.value.problems), ei.value.problems


def _float_keys(schema, prefix=""):  # type: ignore[no-untyped-def]
    """Every dotted key of a float (or optional float) field, through the sub-tables."""
    from pydantic import BaseModel

    for name, f in schema.model_fields.items():
        ann = f.annotation
        if isinstance(ann, type) and issubclass(ann, BaseModel):
            yield from _float_keys(ann, f"{prefix}{name}.")
        elif ann in (float, float | None):
            yield f"{prefix}{name}"


def _nested(key: str, value: object) -> dict:
    out: dict = {}
    node = out
    *tables, leaf = key.split(".")
    for t in tables:
        node = node.setdefault(t, {})
    node[leaf] = value
    return out


@pytest.mark.parametrize("value", [float("nan"), float("inf"), float("-inf")])
def test_every_float_of_the_vehicle_file_refuses_nan_and_infinity_as_not_finite(value):
    keys = list(_float_keys(SimulatedConfig))  # the simulator's [sim] tables included
    assert len(keys) > 140  # the walk reaches every table
    for key in keys:
        data = _nested(key, value)
        if key.startswith("mission.pad."):  # the pad's own table: the other keys keep it whole
            data["mission"]["pad"] |= {"north_m": 10.0, "east_m": 10.0} | {key.rsplit(".", 1)[1]: value}
        with pytest.raises(ConfigError) as err:
            simulated_config_from_dict(data, "f.toml")
        assert f"{key} = {value!r}: not finite; expected a finite number" in err.value.problems, err.value.problems
        assert "should be" not in str(err.value)  # a NaN is never compared with a limit


@pytest.mark.parametrize(
    ("text", "line"),
    [
        ("[sim]\ngps_bias_m = [1.0, nan, 0.0]\n", "sim.gps_bias_m[1] = nan: not finite"),
        ("[mission]\nsector_speed_m_s = [2.0, 3.0, inf, 2.0, 1.5]\n", "mission.sector_speed_m_s[2] = inf: not finite"),
        ("[landing]\ncamera_offset_body_m = [0.0, 0.0, -inf]\n", "landing.camera_offset_body_m[2] = -inf: not finite"),
        ("[mission]\nheight_m = nan\n", "mission.height_m = nan: not finite"),
    ],
)
def test_a_non_finite_number_in_an_array_or_a_limited_key_is_named(tmp_path, text, line):
    with pytest.raises(ConfigError) as err:
        load_simulated_config(write(tmp_path, text))
    assert line in str(err.value) and str(tmp_path / "p.toml") in str(err.value)
    assert "should be" not in str(err.value)


@pytest.mark.parametrize(
    ("pad", "key", "ok"),
    [
        ({"north_m": 3000.0, "east_m": -3000.0}, "", True),
        ({"north_m": 3000.5, "east_m": 0.0}, "mission.pad.north_m = 3000.5: Input should be less than or equal", False),
        ({"north_m": 1.0, "east_m": -1e7}, "mission.pad.east_m = -10000000.0: Input should be greater than or", False),
        ({"north_m": 1.0, "east_m": 1.0, "alt_amsl_m": 9001.0}, "mission.pad.alt_amsl_m = 9001.0:", False),
        ({"north_m": 1.0, "east_m": 1.0, "alt_amsl_m": -501.0}, "mission.pad.alt_amsl_m = -501.0:", False),
        ({"lat_deg": -19.869 + 0.0269, "lon_deg": -43.9638}, "", True),  # ~2990 m north of sim.home
        ({"lat_deg": -19.0, "lon_deg": -43.9638}, "mission.pad (-19.0, -43.9638) lies 96214 m north, 0 m east", False),
        ({"lat_deg": -19.869, "lon_deg": 0.0}, "m east of sim.home: each must be within +-3000 m", False),
    ],
)
def test_the_pad_lies_within_the_stated_box_around_home(pad, key, ok):
    home = {"lat_deg": -19.869, "lon_deg": -43.9638, "alt_amsl_m": 850.0}
    for table in ("pad", "alternate_pad"):
        data = {"mission": {table: pad}, "sim": {"home": home}}
        if ok:
            simulated_config_from_dict(data)
            continue
        with pytest.raises(ConfigError) as err:
            simulated_config_from_dict(data)
        assert key.replace("mission.pad", f"mission.{table}") in str(err.value), err.value.problems
    if "lat_deg" in pad:  # on a real autopilot home is known in flight: the planner checks it there
        assert config_from_dict({"autopilot": "px4", "mission": {"pad": pad}}).mission.pad.lat_deg == pad["lat_deg"]


def test_a_geodetic_pad_far_from_the_reported_home_fails_the_planning():
    import numpy as np

    from companion.delivery.planning import plan_delivery
    from companion.geometry.earth import GeoPoint
    from companion.guidance.path import PathGeometryError

    cfg = config_from_dict({"autopilot": "px4", "mission": {"pad": {"lat_deg": -19.0, "lon_deg": -43.9638}}})
    with pytest.raises(PathGeometryError, match=r"the pad lies 96214 m north, 0 m east of home: each must be within"):
        plan_delivery(cfg.mission, GeoPoint(-19.869, -43.9638, 850.0), np.zeros(3))
    near = cfg.mission.model_copy(update={"pad": cfg.mission.pad.model_copy(update={"lat_deg": -19.85})})
    _, path, _ = plan_delivery(near, GeoPoint(-19.869, -43.9638, 850.0), np.zeros(3))
    assert 2000.0 < path.d < 2200.0


@pytest.mark.parametrize("command", ["demo", "fly"])
def test_a_bad_value_ends_demo_and_fly_with_one_line_and_exit_2(tmp_path, capsys, command):
    from companion.cli import exits
    from companion.cli.main import main

    p = write(tmp_path, 'autopilot = "px4"\n[mission.pad]\nnorth_m = nan\neast_m = 5.0\n')
    assert main([command, "--params", str(p), "--out", str(tmp_path / "run")]) == exits.BAD_INPUT
    err = capsys.readouterr().err
    problem = "mission.pad.north_m = nan: not finite; expected a finite number"
    assert err == f"companion {command}: bad configuration: {p}: {problem}\n"
    assert not (tmp_path / "run").exists()


@pytest.mark.parametrize("lat_deg", [90.0, -90.0, 89.5])
def test_the_simulated_home_stays_off_the_poles(lat_deg):
    with pytest.raises(ConfigError, match=rf"sim.home.lat_deg = {lat_deg}: Input should be"):
        simulated_config_from_dict({"sim": {"home": {"lat_deg": lat_deg, "lon_deg": 0.0}}})
    assert simulated_config_from_dict({"sim": {"home": {"lat_deg": 89.0, "lon_deg": 0.0}}}).sim.home.lat_deg == 89.0


def test_the_estimators_and_solvers_tuning_is_a_table_of_the_landing(tmp_path):
    """[landing.ekf], [landing.detector] and [landing.multilateration] are read into the schemas the
    EKF, the pad detector and the UWB solver take as they are."""
    from companion.estimation.ekf import DeliveryEkf
    from companion.uwb.anchors import load_anchor_layout
    from companion.uwb.multilateration import Multilaterator

    f = tmp_path / "v.toml"
    f.write_text(
        "[landing.ekf]\ngate_probability = 0.999\naruco_max_height_m = 12.0\n"
        "[landing.detector]\nfull_search_every = 7\n[landing.multilateration]\nmax_pdop = 8.0\n"
    )
    lc = load_config(f).landing
    assert (lc.ekf.gate_probability, lc.ekf.aruco_max_height_m) == (0.999, 12.0)
    assert lc.detector.full_search_every == 7 and lc.multilateration.max_pdop == 8.0
    assert DeliveryEkf(lc.ekf).config.aruco_max_height_m == 12.0
    layout = load_anchor_layout(shipped_params_path("uwb_anchors_pad.toml"))
    assert Multilaterator(layout, lc.multilateration).config.max_pdop == 8.0


@pytest.mark.parametrize(
    ("text", "line"),
    [
        ("[landing.ekf]\ngate_probability = 1.0\n", "landing.ekf.gate_probability = 1.0: Input should be less than 1"),
        ("[landing.detector]\nfull_search_every = 0\n", "landing.detector.full_search_every = 0: Input should be"),
        ("[landing.multilateration]\nmax_iterations = 0\n", "landing.multilateration.max_iterations = 0: Input"),
        ("[landing.ekf]\nsigma = 1.0\n", "landing.ekf.sigma: unknown key (value 1.0)"),
    ],
)
def test_a_bad_value_of_the_estimators_tuning_names_file_key_and_rule(tmp_path, text, line):
    f = tmp_path / "v.toml"
    f.write_text(text)
    with pytest.raises(ConfigError) as err:
        load_config(f)
    assert err.value.source == str(f) and any(p.startswith(line) for p in err.value.problems), err.value.problems


def test_the_old_landing_ekf_keys_still_load_into_landing_ekf(tmp_path):
    """Files from before [landing.ekf] (and the run folders they made) set two of its keys in
    [landing]: they load as the new keys do; both forms at once is refused."""
    old, new, both = (tmp_path / n for n in ("old.toml", "new.toml", "both.toml"))
    old.write_text("[landing]\nekf_position_process_sigma_m_per_sqrt_s = 0.3\nekf_gate_reset_after_rejections = 5\n")
    new.write_text("[landing.ekf]\nposition_process_sigma_m_per_sqrt_s = 0.3\ngate_reset_after_rejections = 5\n")
    assert load_config(old) == load_config(new)
    assert load_config(old).landing.ekf.gate_reset_after_rejections == 5
    both.write_text("[landing]\nekf_gate_reset_after_rejections = 5\n[landing.ekf]\ngate_reset_after_rejections = 6\n")
    with pytest.raises(ConfigError, match=r"ekf_gate_reset_after_rejections is the old name of landing\.ekf"):
        load_config(both)
    bad = tmp_path / "bad.toml"
    bad.write_text("[landing]\nekf_position_process_sigma_m_per_sqrt_s = -1.0\n")
    with pytest.raises(ConfigError, match=r"landing.ekf.position_process_sigma_m_per_sqrt_s = -1.0: Input should be"):
        load_config(bad)


def test_the_old_mission_landing_keys_still_load_into_mission_descent(tmp_path):
    """The final descent's gains were ``[mission] landing_*`` before ``[mission.descent]``: files
    and run folders from then load as the new keys do; both forms at once is refused."""
    from companion.config import MISSION_OLD_DESCENT_KEYS, DescentConfig

    assert set(MISSION_OLD_DESCENT_KEYS.values()) == set(DescentConfig.model_fields)
    old, new, both = (tmp_path / n for n in ("old.toml", "new.toml", "both.toml"))
    old.write_text("[mission]\nlanding_xy_gain_1_s = 5.0\nlanding_touchdown_height_m = -1.0\nland_speed_m_s = 0.7\n")
    new.write_text("[mission]\nland_speed_m_s = 0.7\n[mission.descent]\nxy_gain_1_s = 5.0\ntouchdown_height_m = -1.0\n")
    assert load_config(old) == load_config(new)
    assert load_config(old).mission.descent.xy_gain_1_s == 5.0
    both.write_text("[mission]\nlanding_settle_s = 1.0\n[mission.descent]\nsettle_s = 2.0\n")
    with pytest.raises(ConfigError, match=r"landing_settle_s is the old name of mission\.descent\.settle_s"):
        load_config(both)
    bad = tmp_path / "bad.toml"
    bad.write_text("[mission]\nlanding_xy_gain_1_s = 0.0\n")
    with pytest.raises(ConfigError, match=r"mission\.descent\.xy_gain_1_s = 0\.0: Input should be greater than 0"):
        load_config(bad)


@pytest.mark.parametrize("landing", [{"use_camera": False}, {"fusion": False}])
def test_the_drop_zone_check_needs_the_camera(landing):
    with pytest.raises(ConfigError) as ei:
        config_from_dict({"landing": {**landing, "drop_zone": {"enabled": True}}}, "test.toml")
    assert any(
        "landing.drop_zone.enabled = true needs landing.fusion = true and landing.use_camera" in p
        for p in ei.value.problems
    ), ei.value.problems

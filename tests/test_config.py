from pathlib import Path

import pytest

from companion.config import ConfigError, config_from_dict, describe_parameters, load_config, shipped_params_path


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
    c = load_config(a, overrides={"sim": {"seed": 9}})
    assert c.sim.seed == 9 and c.sim.wind_speed_m_s == 2.0


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

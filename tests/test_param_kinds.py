"""Every kind of parameter file has a schema; every shipped file passes `params check`; a broken
copy of each kind fails naming the file, the key, the value and what is expected."""

from __future__ import annotations

import dataclasses
import re
import tomllib
from pathlib import Path

import pytest

from companion.cli.main import main
from companion.config import describe_schema
from companion.dart.mission import DartMissionConfig
from companion.dart.params import DartControlGains, DartRuntimeConfig
from companion.param_kinds import (
    KINDS,
    AnchorsFile,
    CameraTable,
    DartControlTable,
    DartMissionTable,
    DartRuntimeTable,
    DartSimTable,
    PadTable,
    ZenohTable,
    detect_kind,
)
from companion.telemetry.session import ZenohSettings
from companion.vision.pad import PadLayout
from companion_sitl.dart_sim import DartSimConfig

PARAMS = Path(__file__).resolve().parents[1] / "params"
SHIPPED = sorted(PARAMS.glob("*.toml"))

KIND_OF = {
    "ardupilot_quad.toml": "vehicle",
    "delivery_paper.toml": "vehicle",
    "landing_campaign.toml": "vehicle",
    "landing_campaign_short.toml": "vehicle",
    "landing_campaign_camera_only.toml": "vehicle",  # docs/clock.md
    "px4_sih_quad.toml": "vehicle",
    "sitl_short.toml": "vehicle",
    "slow_board.toml": "vehicle",  # an overlay: validates on the defaults alone
    "serial_115200.toml": "vehicle",  # an overlay too (docs/serial-link.md)
    "camera_real.toml": "vehicle",  # an overlay of [sim.camera] (docs/vision.md)
    "dart_hover.toml": "dart",
    "camera_rpi_v2.toml": "camera",
    "pad_delivery.toml": "pad",
    "uwb_anchors_pad.toml": "anchors",
    "uwb_anchors_one_height.toml": "anchors",
    "zenoh_fleet_router.toml": "zenoh",
    "zenoh_fleet_vehicle.toml": "zenoh",
    "zenoh_loopback.toml": "zenoh",
    "zenoh_peer.toml": "zenoh",
}


def test_every_shipped_file_passes_params_check(capsys: pytest.CaptureFixture[str]) -> None:
    assert sorted(p.name for p in SHIPPED) == sorted(KIND_OF)  # a new file gets its kind written here
    assert main(["params", "check", *map(str, SHIPPED)]) == 0
    out = capsys.readouterr().out
    for p in SHIPPED:
        assert f"{p}: OK ({KIND_OF[p.name]})" in out


@pytest.mark.parametrize("path", SHIPPED, ids=[p.name for p in SHIPPED])
def test_the_kind_is_told_from_the_keys(path: Path) -> None:
    with path.open("rb") as fh:
        assert detect_kind(tomllib.load(fh)) == KIND_OF[path.name]


# (shipped file, text replaced, replacement, what the one problem line must say)
BROKEN = [
    (
        "delivery_paper.toml",
        "height_m = 45.0",
        "height_m = 500.0",
        ["mission.height_m = 500.0", "less than or equal to 120"],
    ),
    (
        "dart_hover.toml",
        "max_speed_m_s = 0.1",
        "max_speed_m_s = -0.1",
        ["mission.max_speed_m_s = -0.1", "greater than 0"],
    ),
    (
        "dart_hover.toml",
        "horizontal_kp = 400.0",
        "horizontal_kp = 'strong'",
        ["control.horizontal_kp = 'strong'", "valid number"],
    ),
    ("dart_hover.toml", "hover_s = 25.0", "hover_secs = 25.0", ["mission.hover_secs: unknown key (value 25.0)"]),
    (
        "dart_hover.toml",
        'throttle_mode = "climb_rate"',
        'throttle_mode = "auto"',
        ["sim.throttle_mode = 'auto'", "'climb_rate' or 'thrust'"],
    ),
    ("camera_rpi_v2.toml", "fx = 530.0", "fx = 'wide'", ["camera.fx = 'wide'", "valid number"]),
    (
        "camera_rpi_v2.toml",
        "cx = 319.5",
        "cx = 900.0",
        ["principal point (900.0, 239.5) must lie inside the image 640 x 480"],
    ),
    ("camera_rpi_v2.toml", 'kind = "opencv"', 'kind = "fisheye"', ["camera.kind = 'fisheye'", "'opencv' or 'dart'"]),
    ("pad_delivery.toml", "outer_size_m = 0.8", "outer_size_m = -0.8", ["pad.outer_size_m = -0.8", "greater than 0"]),
    ("pad_delivery.toml", "inner_id = 0", "inner_id = 0\ncolour = 'red'", ["pad.colour: unknown key (value 'red')"]),
    # a rule that ties keys together, checked by the pad's own loader after the schema
    (
        "pad_delivery.toml",
        "inner_size_m = 0.09",
        "inner_size_m = 0.5",
        ["pad inner_size_m = 0.5", "half the outer marker"],
    ),
    (
        "uwb_anchors_pad.toml",
        "position_m = [3.0, 3.0, 0.3]",
        "position_m = [3.0, 3.0]",
        ["anchors[0].position_m = [3.0, 3.0]: item [2] is missing"],
    ),
    (
        "uwb_anchors_pad.toml",
        'base_anchor = "1A01"',
        'base_anchor = "9Z99"',
        ["base_anchor = '9Z99': must be one of the anchor ids"],
    ),
    ("uwb_anchors_pad.toml", "max_range_m = 10.0", "max_range_m = 0.0", ["max_range_m = 0.0", "greater than 0"]),
    (
        "uwb_anchors_one_height.toml",
        'tag_side = "above"',
        'tag_side = "up"',
        ["tag_side = 'up'", "'above' or 'below'"],
    ),
    ("zenoh_peer.toml", 'mode = "peer"', 'mode = "server"', ["zenoh.mode = 'server'", "'peer', 'client' or 'router'"]),
    (
        "zenoh_peer.toml",
        'listen = ["tcp/0.0.0.0:7447"]',
        'listen = ["0.0.0.0:7447"]',
        ["endpoints ['0.0.0.0:7447']", "like 'tcp/127.0.0.1:7447'"],
    ),
    (
        "zenoh_loopback.toml",
        "multicast_scouting = false",
        "multicast_scouting = 'no'",
        ["zenoh.multicast_scouting = 'no'", "valid boolean"],
    ),
    # a NaN or an infinity is refused as not finite in every kind, never compared with a limit
    ("sitl_short.toml", "height_m = 8.0", "height_m = nan", ["mission.height_m = nan: not finite"]),
    ("sitl_short.toml", "north_m = 14.0", "north_m = -inf", ["mission.pad.north_m = -inf: not finite"]),
    ("sitl_short.toml", "north_m = 14.0", "north_m = 1e7", ["mission.pad.north_m = 10000000.0", "3000"]),
    ("camera_rpi_v2.toml", "fx = 530.0", "fx = nan", ["camera.fx = nan: not finite"]),
    ("pad_delivery.toml", "outer_size_m = 0.8", "outer_size_m = inf", ["pad.outer_size_m = inf: not finite"]),
    ("dart_hover.toml", "hover_s = 25.0", "hover_s = nan", ["mission.hover_s = nan: not finite"]),
    ("uwb_anchors_pad.toml", "max_range_m = 10.0", "max_range_m = inf", ["max_range_m = inf: not finite"]),
]


@pytest.mark.parametrize("name, old, new, words", BROKEN, ids=[f"{b[0]}:{b[2][:24]}" for b in BROKEN])
def test_a_broken_copy_fails_naming_file_key_value_and_rule(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str, old: str, new: str, words: list[str]
) -> None:
    text = (PARAMS / name).read_text()
    assert text.count(old) == 1, f"{name} no longer holds {old!r}"
    broken = tmp_path / f"broken_{name}"
    broken.write_text(text.replace(old, new))
    assert main(["params", "check", str(PARAMS / name), str(broken)]) == 1
    captured = capsys.readouterr()
    assert f"{PARAMS / name}: OK ({KIND_OF[name]})" in captured.out
    err = captured.err.splitlines()
    assert err[0] == f"{broken}:"
    problems = "\n".join(err[1:])
    for w in words:
        assert w in problems, problems


def test_kind_can_be_forced(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    pad = PARAMS / "pad_delivery.toml"
    assert main(["params", "check", "--kind", "camera", str(pad)]) == 1
    err = capsys.readouterr().err
    assert "camera: required key is missing" in err and "pad: unknown key" in err


def test_show_says_which_kind_of_defaults_it_prints(capsys: pytest.CaptureFixture[str]) -> None:
    assert main(["params", "show", "--kind", "pad"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].startswith("# defaults of kind pad, nested ArUco landing pad")
    assert "pad.outer_size_m = 0.8 [m] (> 0.0)  outer marker side, black border included" in lines
    assert main(["params", "show"]) == 0
    assert capsys.readouterr().out.startswith("# defaults of kind vehicle")
    assert main(["params", "show", str(PARAMS / "dart_hover.toml")]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"# {PARAMS / 'dart_hover.toml'}: kind dart")
    assert "mission.start_distance_m = 4.0 [m]" in out and "control.horizontal_kp = 400.0 [us/m]" in out
    assert main(["params", "show", "--kind", "camera"]) == 0
    assert "camera.fx = '<required>' [px] (> 0.0" in capsys.readouterr().out


@pytest.mark.parametrize("kind", list(KINDS))
def test_every_key_of_every_kind_has_a_unit_and_a_description(kind: str) -> None:
    for line in describe_schema(KINDS[kind].schema):
        if line.startswith("["):
            continue  # a table
        # key = value [unit] (limits)  description
        assert re.search(r" \[[^\[\]]+\](?: \([^)]*\))?  \S", line), line


def _defaults(cls: type) -> dict[str, object]:
    return {f.name: getattr(cls(), f.name) for f in dataclasses.fields(cls)}


@pytest.mark.parametrize(
    "schema, loader_class",
    [
        (PadTable, PadLayout),
    ],
    ids=["pad"],
)
def test_schema_keys_and_defaults_are_the_loaders(schema: type, loader_class: type) -> None:
    assert schema().model_dump() == _defaults(loader_class)


def test_the_dart_gains_mission_and_runtime_are_their_schema() -> None:
    """[control], [mission] and [runtime] are declared once: the Dart takes the schema's models."""
    assert DartControlGains is DartControlTable and DartMissionConfig is DartMissionTable
    # [runtime] and the simulator's [sim] add rules that need other modules (the estimators'
    # names, the marker's fit), no keys
    for loader, table in ((DartRuntimeConfig, DartRuntimeTable), (DartSimConfig, DartSimTable)):
        assert issubclass(loader, table) and loader.model_fields.keys() == table.model_fields.keys()


def test_zenoh_and_camera_and_anchor_schemas_know_the_loaders_keys() -> None:
    zenoh_defaults = _defaults(ZenohSettings)
    table = ZenohTable().model_dump()
    assert set(table) == set(zenoh_defaults)
    assert table["overrides"] == dict(zenoh_defaults.pop("overrides"))  # type: ignore[call-overload]
    assert {k: v for k, v in table.items() if k != "overrides"} == zenoh_defaults
    from companion.vision.camera import _CAMERA_KEYS, _META_KEYS

    assert set(CameraTable.model_fields) == _CAMERA_KEYS
    assert set(KINDS["camera"].schema.model_fields["calibration"].annotation.model_fields) == _META_KEYS  # type: ignore[union-attr]
    assert set(AnchorsFile.model_fields) == {"frame", "base_anchor", "max_range_m", "tag_side", "anchors"}


@pytest.mark.parametrize("name", sorted(KIND_OF))
def test_a_file_that_is_not_utf8_is_reported_and_the_others_still_checked(
    tmp_path: Path, capsys: pytest.CaptureFixture[str], name: str
) -> None:
    # a Latin-1 byte in a comment: TOML files are UTF-8, so this is not a TOML file at all
    bad = tmp_path / f"latin1_{name}"
    bad.write_bytes((PARAMS / name).read_bytes() + b"# caf\xe9\n")
    assert main(["params", "check", str(bad), str(PARAMS / name)]) == 1
    captured = capsys.readouterr()
    assert f"{PARAMS / name}: OK ({KIND_OF[name]})" in captured.out
    assert captured.err.splitlines()[0] == f"{bad}:"
    assert "not UTF-8 text" in captured.err

"""Anchor layouts: the packaged TOML, validation errors, the anchor-frame transform."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from companion.uwb.anchors import (
    AnchorLayout,
    AnchorLayoutError,
    anchor_frame_to_ned,
    layout_from_positions,
    load_anchor_layout,
)

GOOD = """
frame = "pad"
base_anchor = "A2"
max_range_m = 10.0
[[anchors]]
id = "A1"
position_m = [3.0, 3.0, 0.3]
[[anchors]]
id = "A2"
position_m = [-3.0, 3.0, 2.2]
[[anchors]]
id = "A3"
position_m = [-3.0, -3.0, 0.5]
[[anchors]]
id = "A4"
position_m = [3.0, -3.0, 1.8]
"""


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "anchors.toml"
    p.write_text(text)
    return p


def test_packaged_layout_surrounds_the_pad_with_height_diversity() -> None:
    layout = load_anchor_layout()
    pos = layout.positions_array()
    assert len(layout.anchor_ids) >= 4
    assert layout.frame == "pad"
    assert layout.max_range_m == 10.0
    assert layout.base_anchor_id == layout.anchor_ids[layout.base_index]
    # anchors on every side of the 1 x 1 m pad, at clearly different heights
    assert pos[:, 0].min() < -0.5 and pos[:, 0].max() > 0.5
    assert pos[:, 1].min() < -0.5 and pos[:, 1].max() > 0.5
    assert np.ptp(pos[:, 2]) >= 1.0
    assert load_anchor_layout(Path(__file__).parents[2] / "params" / "uwb_anchors_pad.toml") == layout


def test_good_file_loads(tmp_path: Path) -> None:
    layout = AnchorLayout.from_toml(_write(tmp_path, GOOD))
    assert layout.anchor_ids == ("A1", "A2", "A3", "A4")
    assert layout.base_anchor_id == "A2" and layout.base_index == 1
    np.testing.assert_allclose(layout.position_of("A3"), [-3.0, -3.0, 0.5])
    assert "A4" in layout and "A9" not in layout


@pytest.mark.parametrize(
    ("edit", "key", "rule_part"),
    [
        (lambda t: 'colour = "red"\n' + t, "colour", "unknown key"),
        (lambda t: t.replace('id = "A4"', 'id = "A1"'), "anchors[3].id", "duplicate"),
        (lambda t: t.replace("[3.0, -3.0, 1.8]", "[3.0, -3.0]"), "anchors[3].position_m", "three finite"),
        (lambda t: t.replace("[3.0, -3.0, 1.8]", '[3.0, "x", 1.8]'), "anchors[3].position_m", "three finite"),
        (lambda t: t.replace('base_anchor = "A2"', 'base_anchor = "B7"'), "base_anchor", "one of the anchor ids"),
        (lambda t: t.replace("max_range_m = 10.0", "max_range_m = -1.0"), "max_range_m", "(0, 100]"),
        (  # all four on the diagonal x = y: collinear (coplanar is accepted, see test_coplanar_anchors)
            lambda t: (
                t.replace("[-3.0, 3.0, 2.2]", "[-3.0, -3.0, 0.3]")
                .replace("[-3.0, -3.0, 0.5]", "[1.0, 1.0, 0.3]")
                .replace("[3.0, -3.0, 1.8]", "[-1.0, -1.0, 0.3]")
            ),
            "anchors.position_m",
            "on one line",
        ),
        # two anchors: even at one height a TWR fix needs 3 (see test_coplanar_anchors for 3)
        (lambda t: t.split('[[anchors]]\nid = "A3"')[0], "anchors", "at least 3 anchors at one height"),
        (lambda t: t.replace('id = "A3"\n', 'id = "A3"\nheight = 2\n'), "anchors[2].height", "unknown key"),
    ],
)
def test_bad_files_name_file_key_value_and_rule(tmp_path: Path, edit, key: str, rule_part: str) -> None:  # type: ignore[no-untyped-def]
    path = _write(tmp_path, edit(GOOD))
    with pytest.raises(AnchorLayoutError) as err:
        AnchorLayout.from_toml(path)
    msg = str(err.value)
    assert str(path) in msg
    assert err.value.key == key
    assert rule_part in err.value.rule
    assert key in msg


def test_unreadable_and_invalid_toml(tmp_path: Path) -> None:
    with pytest.raises(AnchorLayoutError, match="cannot read"):
        AnchorLayout.from_toml(tmp_path / "missing.toml")
    with pytest.raises(AnchorLayoutError, match="invalid TOML"):
        AnchorLayout.from_toml(_write(tmp_path, "frame = = 1"))


def test_direct_construction_validates() -> None:
    with pytest.raises(AnchorLayoutError, match="at least 3 anchors at one height"):
        layout_from_positions([[0, 0, 0], [1, 0, 1]])
    with pytest.raises(AnchorLayoutError, match="on one line"):
        layout_from_positions([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0.01]])
    assert layout_from_positions([[0, 0, 0], [1, 0, 0], [0, 1, 0], [1, 1, 0]]).coplanar
    with pytest.raises(AnchorLayoutError, match="finite"):
        layout_from_positions([[0, 0, math.nan], [1, 0, 0], [0, 1, 0], [1, 1, 1]])


def test_anchor_frame_to_ned() -> None:
    T = anchor_frame_to_ned([10.0, -5.0, -0.2], heading_rad=0.0)
    np.testing.assert_allclose(T.apply([1.0, 0.0, 0.0]), [11.0, -5.0, -0.2])  # x north
    np.testing.assert_allclose(T.apply([0.0, 1.0, 0.0]), [10.0, -6.0, -0.2])  # y west
    np.testing.assert_allclose(T.apply([0.0, 0.0, 2.0]), [10.0, -5.0, -2.2])  # z up
    enu = anchor_frame_to_ned([0.0, 0.0, 0.0], heading_rad=math.pi / 2)
    np.testing.assert_allclose(enu.apply([1.0, 2.0, 3.0]), [2.0, 1.0, -3.0], atol=1e-12)
    for T_ in (T, enu):
        assert np.linalg.det(T_.R) == pytest.approx(1.0)
        np.testing.assert_allclose(T_.R.T @ T_.R, np.eye(3), atol=1e-12)


def test_pad_frame_matches_the_vision_pad_frame() -> None:
    from companion_sitl.camera import pad_pose_ned

    for yaw in (0.0, 0.4, -2.0):
        a = anchor_frame_to_ned([3.0, -2.0, 0.1], heading_rad=math.pi / 2 + yaw)
        b = pad_pose_ned(3.0, -2.0, 0.1, yaw_rad=yaw)
        np.testing.assert_allclose(a.R, b.R, atol=1e-12)
        np.testing.assert_allclose(a.t, b.t, atol=1e-12)

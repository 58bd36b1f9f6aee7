"""Nested pad (delivery 4.2.1): geometry, true-scale rendering, two dictionaries, TOML."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from companion.vision.pad import (
    PadConfigError,
    PadLayout,
    aruco_dictionary,
    load_pad,
    pad_side_px,
    render_pad,
    render_pad_px,
    save_pad,
    save_pad_png,
)

PARAMS = Path(__file__).resolve().parents[2] / "params"


def _detect(img: np.ndarray, dict_name: str) -> list[int]:
    p = cv2.aruco.DetectorParameters()
    p.cornerRefinementMethod = cv2.aruco.CORNER_REFINE_SUBPIX
    det = cv2.aruco.ArucoDetector(aruco_dictionary(dict_name), p)
    _, ids, _ = det.detectMarkers(img)
    return [] if ids is None else sorted(int(i) for i in np.asarray(ids).ravel())


def _view(layout: PadLayout, side_px: int = 420) -> np.ndarray:
    """The pad seen straight on, on a grey surround (as a camera would see it)."""
    img = cv2.resize(render_pad_px(layout, 1000), (side_px, side_px), interpolation=cv2.INTER_AREA)
    return cv2.copyMakeBorder(img, 40, 40, 40, 40, cv2.BORDER_CONSTANT, value=110)


def test_default_layout_is_the_delivery_paper_pad() -> None:
    lay = PadLayout()
    assert (lay.outer_size_m, lay.inner_size_m, lay.pad_size_m) == (0.8, 0.09, 1.0)
    assert lay.outer_dict.startswith("DICT_5X5") and lay.inner_dict.startswith("DICT_4X4")
    assert load_pad(PARAMS / "pad_delivery.toml") == lay


def test_corner_coordinates_in_marker_frame() -> None:
    lay = PadLayout(outer_size_m=0.6, inner_size_m=0.1)
    # ArUco order TL, TR, BR, BL with x right, y up, z = 0; pad centre at the origin
    assert np.allclose(lay.outer_corners, [[-0.3, 0.3, 0], [0.3, 0.3, 0], [0.3, -0.3, 0], [-0.3, -0.3, 0]])
    assert np.allclose(lay.inner_corners, [[-0.05, 0.05, 0], [0.05, 0.05, 0], [0.05, -0.05, 0], [-0.05, -0.05, 0]])
    assert np.allclose(lay.inner_corners.mean(axis=0), 0.0)


def test_render_is_true_scale() -> None:
    lay = PadLayout()
    assert pad_side_px(lay, 150) == round(1.0 / 0.0254 * 150)  # 5906 px
    img = render_pad(lay, dpi=50)
    side = round(1.0 / 0.0254 * 50)
    assert img.shape == (side, side) and img.dtype == np.uint8
    # the outer marker's black border spans outer_size_m / pad_size_m of the image
    row = img[side // 2]
    dark = np.nonzero(row < 128)[0]
    span_m = (dark[-1] - dark[0] + 1) / side * lay.pad_size_m
    assert span_m == pytest.approx(lay.outer_size_m, abs=2 * lay.pad_size_m / side)


def test_render_places_markers_exactly_at_1mm() -> None:
    lay = PadLayout()
    img = render_pad_px(lay, 1000)
    # white margin 100 px, outer marker border black from 100 to 899
    assert img[500, 99] == 255 and img[500, 100] == 0 and img[500, 899] == 0 and img[500, 900] == 255
    # inner marker: 90 px centred (455..544) inside a 120 px white quiet zone (440..559)
    assert img[455, 455] == 0 and img[544, 544] == 0
    assert img[450, 500] == 255 and img[500, 441] == 255


def test_save_png(tmp_path: Path) -> None:
    out = save_pad_png(PadLayout(), tmp_path / "pad.png", dpi=30)
    back = cv2.imread(str(out), cv2.IMREAD_GRAYSCALE)
    assert back.shape == (pad_side_px(PadLayout(), 30),) * 2
    with pytest.raises(ValueError, match="png"):
        save_pad_png(PadLayout(), tmp_path / "pad.jpg")


def test_two_dictionaries_find_both_markers() -> None:
    lay = PadLayout()
    img = _view(lay)
    assert _detect(img, lay.outer_dict) == [lay.outer_id]
    assert _detect(img, lay.inner_dict) == [lay.inner_id]
    # one multi-dictionary ArucoDetector (what PadDetector uses) also finds both
    p = cv2.aruco.DetectorParameters()
    det = cv2.aruco.ArucoDetector(aruco_dictionary(lay.outer_dict), p)
    det.setDictionaries([aruco_dictionary(lay.outer_dict), aruco_dictionary(lay.inner_dict)])
    _, ids, _, dict_idx = det.detectMarkersMultiDict(img)
    assert sorted(zip(np.asarray(dict_idx).ravel().tolist(), np.asarray(ids).ravel().tolist(), strict=True)) == [
        (0, lay.outer_id),
        (1, lay.inner_id),
    ]


def test_one_dictionary_loses_the_outer_marker() -> None:
    """Documents why the pad uses two dictionaries: with both markers from DICT_5X5_50 the
    detector reports only the inner marker — the outer one is lost once the inner decodes."""
    lay = PadLayout(outer_id=0, inner_dict="DICT_5X5_50", inner_id=1)
    assert lay.same_dictionary
    found = _detect(_view(lay), "DICT_5X5_50")
    assert found == [1]  # inner only; outer id 0 missing
    # the same outer marker without a nested marker is found: it is the nesting that hides it
    plain = PadLayout(outer_id=0, inner_dict="DICT_5X5_50", inner_id=1, inner_size_m=0.01)
    big = cv2.resize(render_pad_px(plain, 1000), (420, 420), interpolation=cv2.INTER_AREA)
    assert 0 in _detect(cv2.copyMakeBorder(big, 40, 40, 40, 40, cv2.BORDER_CONSTANT, value=110), "DICT_5X5_50")


@pytest.mark.parametrize(
    "kwargs, word",
    [
        ({"outer_size_m": 1.2}, "outer_size_m"),
        ({"inner_size_m": 0.5}, "inner_size_m"),
        ({"inner_dict": "DICT_9X9_50"}, "inner_dict"),
        ({"outer_id": 50}, "outer_id"),
        ({"pad_size_m": float("nan")}, "pad_size_m"),
        ({"inner_dict": "DICT_5X5_50", "inner_id": 0}, "must differ"),
    ],
)
def test_invalid_layouts(kwargs: dict, word: str) -> None:
    with pytest.raises(ValueError, match=word):
        PadLayout(**kwargs)


def test_pad_toml_roundtrip_and_errors(tmp_path: Path) -> None:
    lay = PadLayout(outer_id=3, inner_id=7, inner_size_m=0.1)
    assert load_pad(save_pad(lay, tmp_path / "pad_x.toml")) == lay
    bad = tmp_path / "pad_bad.toml"
    bad.write_text("[pad]\nouter_size_m = -1.0\n")
    with pytest.raises(PadConfigError) as info:
        load_pad(bad)
    assert str(bad) in str(info.value) and "'pad.outer_size_m'" in str(info.value) and "> 0" in str(info.value)
    bad.write_text("[pad]\nouter_colour = 'red'\n")
    with pytest.raises(PadConfigError, match="unknown key"):
        load_pad(bad)
    bad.write_text("[pad]\nouter_size_m = 0.95\ninner_size_m = 0.5\n")
    with pytest.raises(PadConfigError, match="inner_size_m"):
        load_pad(bad)

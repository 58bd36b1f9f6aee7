"""Nested pad (delivery 4.2.1): geometry, true-scale rendering, two dictionaries, TOML."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest
from PIL import Image
from pypdf import PdfReader
from pypdf.generic import ContentStream

from companion.vision.pad import (
    PadConfigError,
    PadLayout,
    aruco_dictionary,
    load_pad,
    max_png_dpi,
    pad_side_px,
    render_pad,
    render_pad_px,
    save_pad,
    save_pad_pdf,
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


def test_png_carries_its_dpi_and_prints_at_true_size(tmp_path: Path) -> None:
    lay = PadLayout(pad_size_m=0.6, outer_size_m=0.5, inner_size_m=0.06)
    out = save_pad_png(lay, tmp_path / "pad.png", dpi=72)
    with Image.open(out) as im:
        dpi_x, dpi_y = im.info["dpi"]
        side_px = im.size[0]
    assert im.size == (side_px, side_px) and dpi_x == pytest.approx(dpi_y)
    printed_mm = side_px / dpi_x * 25.4  # what a print dialog at 100 % makes of it
    assert printed_mm == pytest.approx(lay.pad_size_m * 1000, abs=1.0)


def test_png_stays_below_pillows_decompression_bomb_limit(tmp_path: Path) -> None:
    lay = PadLayout()
    top = max_png_dpi(lay)
    limit = Image.MAX_IMAGE_PIXELS
    assert limit is not None
    assert pad_side_px(lay, top) ** 2 <= limit < pad_side_px(lay, top + 1) ** 2
    with pytest.raises(ValueError, match=r"dpi = 300.0: must be > 0 and <= 240 .*decompression-bomb"):
        save_pad_png(lay, tmp_path / "pad.png", dpi=300.0)
    assert not (tmp_path / "pad.png").exists()


def _pdf_fills(path: Path) -> tuple[tuple[float, float], list[tuple[float, list[tuple[float, float, float, float]]]]]:
    """Page size (pt) and every filled path of a PDF page, in drawing order, as (grey level,
    [(x0, y0, x1, y1) per sub-path]) in page points, read from the content stream's operators
    (re, m/l/h, f, g/rg, cm, q/Q): an independent reading of what a printer draws."""
    reader = PdfReader(path)
    assert len(reader.pages) == 1
    page = reader.pages[0]
    box = page.mediabox
    size = (float(box.width), float(box.height))
    ctm = np.eye(3)
    stack: list[tuple[np.ndarray, float]] = []
    grey = 0.0
    subpaths: list[list[tuple[float, float]]] = []
    fills: list[tuple[float, list[tuple[float, float, float, float]]]] = []

    def pt(x: float, y: float) -> tuple[float, float]:
        v = np.array([x, y, 1.0]) @ ctm
        return float(v[0]), float(v[1])

    for operands, op in ContentStream(page.get_contents(), reader).operations:
        a = [float(v) for v in operands if isinstance(v, int | float)]
        if op == b"q":
            stack.append((ctm.copy(), grey))
        elif op == b"Q":
            ctm, grey = stack.pop()
        elif op == b"cm":
            ctm = np.array([[a[0], a[1], 0], [a[2], a[3], 0], [a[4], a[5], 1]]) @ ctm
        elif op == b"g":
            grey = a[0]
        elif op == b"rg":
            grey = (a[0] + a[1] + a[2]) / 3.0
        elif op == b"m":
            subpaths.append([pt(a[0], a[1])])
        elif op == b"l":
            subpaths[-1].append(pt(a[0], a[1]))
        elif op == b"re":
            x, y, w, h = a
            subpaths.append([pt(x, y), pt(x + w, y), pt(x + w, y + h), pt(x, y + h)])
        elif op in (b"f", b"F", b"f*"):
            boxes = []
            for sp in subpaths:
                xs, ys = [q[0] for q in sp], [q[1] for q in sp]
                boxes.append((min(xs), min(ys), max(xs), max(ys)))
            fills.append((grey, boxes))
            subpaths = []
        elif op in (b"n", b"S", b"s"):
            subpaths = []
    return size, fills


@pytest.mark.parametrize(
    "layout",
    [PadLayout(), PadLayout(pad_size_m=0.6, outer_size_m=0.5, inner_size_m=0.06, outer_id=3, inner_id=7)],
    ids=["delivery", "small"],
)
def test_pdf_prints_page_and_markers_at_true_size(tmp_path: Path, layout: PadLayout) -> None:
    out = save_pad_pdf(layout, tmp_path / "pad.pdf")
    (w_pt, h_pt), fills = _pdf_fills(out)
    mm_per_pt = 25.4 / 72.0
    assert w_pt * mm_per_pt == pytest.approx(layout.pad_size_m * 1000, abs=1.0)
    assert h_pt * mm_per_pt == pytest.approx(layout.pad_size_m * 1000, abs=1.0)
    black = [boxes for grey, boxes in fills if grey < 0.5]
    assert len(black) == 2  # the outer marker, then the inner one: one path each (vector, no image)
    for boxes, size_m in zip(black, (layout.outer_size_m, layout.inner_size_m), strict=True):
        x0 = min(b[0] for b in boxes) * mm_per_pt
        y0 = min(b[1] for b in boxes) * mm_per_pt
        x1 = max(b[2] for b in boxes) * mm_per_pt
        y1 = max(b[3] for b in boxes) * mm_per_pt
        assert x1 - x0 == pytest.approx(size_m * 1000, abs=1.0)
        assert y1 - y0 == pytest.approx(size_m * 1000, abs=1.0)
        centre_mm = layout.pad_size_m * 500
        assert (x0 + x1) / 2 == pytest.approx(centre_mm, abs=1.0)
        assert (y0 + y1) / 2 == pytest.approx(centre_mm, abs=1.0)

    # paint the fills as a printer would (2 px per mm): both markers decode with their ids
    px_per_pt = 2.0 * mm_per_pt
    n = round(w_pt * px_per_pt)
    img = np.zeros((n, n), np.uint8)
    for grey, boxes in fills:
        for bx0, by0, bx1, by1 in boxes:
            c0, c1 = round(bx0 * px_per_pt), round(bx1 * px_per_pt)
            r0, r1 = n - round(by1 * px_per_pt), n - round(by0 * px_per_pt)  # PDF y is up, image rows down
            img[r0:r1, c0:c1] = round(grey * 255)
    view = cv2.copyMakeBorder(cv2.resize(img, (600, 600), interpolation=cv2.INTER_AREA), 40, 40, 40, 40,
                              cv2.BORDER_CONSTANT, value=110)  # fmt: skip
    assert _detect(view, layout.outer_dict) == [layout.outer_id]
    assert _detect(view, layout.inner_dict) == [layout.inner_id]


def test_pdf_refuses_a_page_larger_than_pdf_allows(tmp_path: Path) -> None:
    with pytest.raises(ValueError, match=r"pad_size_m = 6: a PDF page is at most 5.08 m"):
        save_pad_pdf(PadLayout(pad_size_m=6.0, outer_size_m=4.0, inner_size_m=0.3), tmp_path / "pad.pdf")
    with pytest.raises(ValueError, match=r"must end in \.pdf"):
        save_pad_pdf(PadLayout(), tmp_path / "pad.png")


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

"""Anchors at one height (the DWM1001 set-up of delivery 4.2.2): coplanar layouts are solved on
the known side of the anchors' plane, the weak vertical is reported (VDOP) and handed to the EKF,
only collinear or too few distinct anchors are refused."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from companion.estimation.ekf import DeliveryEkf, EkfConfig
from companion.uwb.anchors import (
    AnchorLayout,
    AnchorLayoutError,
    anchor_frame_to_ned,
    layout_from_positions,
    load_anchor_layout,
)
from companion.uwb.multilateration import (
    Multilaterator,
    TdoaMeasurement,
    TwrMeasurement,
    UwbFix,
    UwbRejection,
    dilution_of_precision,
    dilutions_of_precision,
)

#: four anchors on tripods at 1.2 m around the pad, 6 x 6 m (the paper's four-anchor set-up)
SQUARE = np.array([[3.0, 3.0, 1.2], [-3.0, 3.0, 1.2], [-3.0, -3.0, 1.2], [3.0, -3.0, 1.2]])

ONE_HEIGHT = """
frame = "pad"
tag_side = "above"
[[anchors]]
id = "A1"
position_m = [3.0, 3.0, 0.0]
[[anchors]]
id = "A2"
position_m = [-3.0, 3.0, 0.0]
[[anchors]]
id = "A3"
position_m = [-3.0, -3.0, 0.0]
[[anchors]]
id = "A4"
position_m = [3.0, -3.0, 0.0]
"""


def _fix(r: UwbFix | UwbRejection) -> UwbFix:
    assert isinstance(r, UwbFix), r
    return r


def _write(tmp_path: Path, text: str) -> Path:
    p = tmp_path / "anchors.toml"
    p.write_text(text)
    return p


def test_a_one_height_file_loads_as_coplanar(tmp_path: Path) -> None:
    layout = AnchorLayout.from_toml(_write(tmp_path, ONE_HEIGHT))
    assert layout.coplanar and layout.tag_side == "above"
    np.testing.assert_allclose(layout.tag_side_normal, [0.0, 0.0, 1.0], atol=1e-12)
    below = AnchorLayout.from_toml(_write(tmp_path, ONE_HEIGHT.replace('"above"', '"below"')))
    np.testing.assert_allclose(below.tag_side_normal, [0.0, 0.0, -1.0], atol=1e-12)
    # the shipped layout (anchors at different heights) is not coplanar
    assert not load_anchor_layout().coplanar


@pytest.mark.parametrize(
    ("edit", "key", "rule_part"),
    [
        (lambda t: t.replace('"above"', '"left"'), "tag_side", "one of ['above', 'below']"),
        # all four on the line y = 3: the position around the line is unobservable
        (
            lambda t: t.replace("[-3.0, -3.0, 0.0]", "[-1.0, 3.0, 0.0]").replace("[3.0, -3.0, 0.0]", "[1.0, 3.0, 0.0]"),
            "anchors.position_m",
            "on one line",
        ),
        # two positions repeated: 2 distinct points
        (
            lambda t: t.replace("[-3.0, -3.0, 0.0]", "[3.0, 3.0, 0.0]").replace("[3.0, -3.0, 0.0]", "[-3.0, 3.0, 0.0]"),
            "anchors.position_m",
            "2 distinct anchor positions",
        ),
        # a vertical wall of anchors: "above" names no side of it
        (
            lambda t: t.replace("[-3.0, 3.0, 0.0]", "[3.0, 3.0, 2.0]").replace("[-3.0, -3.0, 0.0]", "[3.0, -3.0, 2.0]"),
            "anchors.position_m",
            "steep plane",
        ),
    ],
)
def test_degenerate_layouts_are_refused_naming_file_key_value(tmp_path: Path, edit, key: str, rule_part: str) -> None:  # type: ignore[no-untyped-def]
    path = _write(tmp_path, edit(ONE_HEIGHT))
    with pytest.raises(AnchorLayoutError) as err:
        AnchorLayout.from_toml(path)
    assert err.value.key == key
    assert rule_part in err.value.rule
    assert str(path) in str(err.value)


def test_direct_construction_refuses_collinear_and_bad_side() -> None:
    with pytest.raises(AnchorLayoutError, match="on one line"):
        layout_from_positions([[0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]])
    with pytest.raises(AnchorLayoutError, match="tag_side"):
        layout_from_positions(SQUARE, tag_side="sideways")


@pytest.mark.parametrize("side", ["above", "below"])
def test_noiseless_fix_is_exact_on_the_configured_side(side: str) -> None:
    layout = layout_from_positions(SQUARE, tag_side=side)
    m = Multilaterator(layout)
    rng = np.random.default_rng(5)
    sign = 1.0 if side == "above" else -1.0
    for _ in range(30):
        p = np.array([rng.uniform(-2, 2), rng.uniform(-2, 2), 1.2 + sign * rng.uniform(0.5, 6.0)])
        d = np.linalg.norm(SQUARE - p, axis=1)
        f = _fix(m.solve_twr(TwrMeasurement(0.0, layout.anchor_ids, tuple(d))))
        np.testing.assert_allclose(f.position_m, p, atol=1e-6)
        assert f.vertical_weak and not f.outliers_checked
        assert f.pdop == pytest.approx(math.hypot(f.hdop, f.vdop), rel=1e-9)
        # a prior on the mirror side does not flip the fix: the side is known
        mirror = p.copy()
        mirror[2] = 2 * 1.2 - p[2]
        g = _fix(m.solve_twr(TwrMeasurement(0.0, layout.anchor_ids, tuple(d)), prior_m=mirror))
        np.testing.assert_allclose(g.position_m, p, atol=1e-6)


def test_vertical_error_follows_vdop_not_hdop() -> None:
    """Seeded noise: the per-axis error spread matches sigma * HDOP / sqrt(2) and sigma * VDOP."""
    layout = layout_from_positions(SQUARE)
    m = Multilaterator(layout)
    rng = np.random.default_rng(11)
    sigma = 0.05
    p = np.array([0.3, -0.2, 2.0])  # 0.8 m above the anchors: the vertical is weak
    d0 = np.linalg.norm(SQUARE - p, axis=1)
    errs, fixes = [], []
    for _ in range(400):
        f = _fix(m.solve_twr(TwrMeasurement(0.0, layout.anchor_ids, tuple(d0 + rng.normal(0, sigma, 4)))))
        errs.append(f.position_m - p)
        fixes.append(f)
    e = np.array(errs)
    hdop = float(np.median([f.hdop for f in fixes]))
    vdop = float(np.median([f.vdop for f in fixes]))
    assert vdop > 1.5 * hdop / math.sqrt(2.0)  # the vertical really is the weak axis here
    std_h = float(np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2)))
    std_v = float(np.std(e[:, 2]))
    assert std_h == pytest.approx(sigma * hdop, rel=0.25)
    assert std_v == pytest.approx(sigma * vdop, rel=0.25)


def test_tag_in_the_anchor_plane_is_refused_as_bad_geometry() -> None:
    layout = layout_from_positions(SQUARE)
    p = np.array([0.0, 0.0, 1.2 + 0.02])
    d = np.linalg.norm(SQUARE - p, axis=1)
    r = Multilaterator(layout).solve_twr(TwrMeasurement(0.0, layout.anchor_ids, tuple(d)))
    assert isinstance(r, UwbRejection) and r.reason.value == "bad_geometry"


def test_six_coplanar_anchors_still_reject_an_outlier() -> None:
    pos = np.vstack([SQUARE, [[0.0, 4.0, 1.2], [0.0, -4.0, 1.2]]])
    layout = layout_from_positions(pos)
    m = Multilaterator(layout)
    rng = np.random.default_rng(2)
    for _ in range(20):
        p = np.array([rng.uniform(-1.5, 1.5), rng.uniform(-1.5, 1.5), rng.uniform(3.0, 6.0)])
        d = np.linalg.norm(pos - p, axis=1) + rng.normal(0, 0.03, len(pos))
        bad = int(rng.integers(len(pos)))
        d[bad] += rng.uniform(1.0, 3.0)
        f = _fix(m.solve_twr(TwrMeasurement(0.0, layout.anchor_ids, tuple(d))))
        assert layout.anchor_ids[bad] not in f.anchors_used
        assert f.outliers_checked
        assert np.linalg.norm(f.position_m - p) < 0.5


def test_tdoa_on_coplanar_anchors_takes_the_tag_side() -> None:
    pos = np.vstack([SQUARE, [[0.0, 4.5, 1.2], [-1.0, -4.0, 1.2]]])
    layout = layout_from_positions(pos)
    m = Multilaterator(layout)
    p = np.array([2.5, 1.0, 3.0])  # off the centre: TDoA needs the asymmetry to see the vertical
    d = np.linalg.norm(pos - p, axis=1)
    ids = layout.anchor_ids
    f = _fix(m.solve_tdoa(TdoaMeasurement(0.0, ids[0], ids[1:], tuple(d[1:] - d[0]))))
    np.testing.assert_allclose(f.position_m, p, atol=1e-4)
    assert f.vertical_weak


def test_shipped_layout_figures_are_unchanged() -> None:
    """Non-coplanar anchors: no vertical_weak flag, PDOP as before, HDOP/VDOP consistent with it."""
    layout = load_anchor_layout()
    A = layout.positions_array()
    p = np.array([0.2, 0.1, 2.0])
    d = np.linalg.norm(A - p, axis=1)
    f = _fix(Multilaterator(layout).solve_twr(TwrMeasurement(0.0, layout.anchor_ids, tuple(d))))
    assert not f.vertical_weak and f.outliers_checked
    assert f.pdop == pytest.approx(dilution_of_precision(f.position_m, A, False), rel=1e-12)
    assert dilutions_of_precision(f.position_m, A, False)[0] == pytest.approx(f.pdop, rel=1e-12)


def _ekf_at(p_world: np.ndarray) -> DeliveryEkf:
    ekf = DeliveryEkf(EkfConfig(), x0=np.concatenate([p_world, np.zeros(9)]))
    ekf.xi = True  # already on pad-local data: P is used as it is (delivery eq 12)
    return ekf


def test_ekf_gets_the_weak_vertical_and_the_isotropic_case_is_unchanged() -> None:
    T = anchor_frame_to_ned(np.array([10.0, 5.0, 0.0]), math.pi / 2)
    p_world = np.array([10.0, 5.0, -3.0])
    p_anchor = T.inverse().apply(p_world)
    weak = UwbFix(0.0, *p_anchor, 3.0, 0.0, (), "pad", hdop=1.0, vdop=2.8, outliers_checked=False, vertical_weak=True)
    iso = UwbFix(0.0, *p_anchor, 3.0, 0.0, (), "pad", hdop=1.0, vdop=2.8)
    e_weak, e_iso = _ekf_at(p_world), _ekf_at(p_world)
    P0 = e_weak.P.copy()
    assert e_weak.update_uwb(weak, T).value == "accepted"
    assert e_iso.update_uwb(iso, T).value == "accepted"
    # the weak-vertical fix informs NED down (anchor z) less than north/east
    gain_h = P0[0, 0] - e_weak.P[0, 0]
    gain_v = P0[2, 2] - e_weak.P[2, 2]
    assert e_weak.P[2, 2] > 4.0 * e_weak.P[0, 0]
    assert gain_v < gain_h
    # the isotropic case: sigma * PDOP / sqrt(3) on every axis, as before
    cfg = EkfConfig()
    sigma0 = cfg.uwb_position_sigma_m + cfg.uwb_position_sigma_gain_m_per_m * e_iso.height_above_pad_m
    sigma = sigma0 * 3.0 / math.sqrt(3)
    r = sigma * sigma
    expected = P0[0, 0] - P0[0, 0] ** 2 / (P0[0, 0] + r)
    assert e_iso.P[0, 0] == pytest.approx(expected, rel=1e-6)
    assert e_iso.P[2, 2] == pytest.approx(e_iso.P[0, 0], rel=1e-6)


def test_nearly_coplanar_tripods_are_exact_too() -> None:
    """Tripods set up 'at one height' differ by a few cm: still coplanar (below 0.1 m of spread);
    the side comes from the best-fit plane and the fit uses the true anchor heights."""
    pos = SQUARE + np.array([[0, 0, 0.0], [0, 0, 0.05], [0, 0, -0.03], [0, 0, 0.02]])
    layout = layout_from_positions(pos)
    assert layout.coplanar
    m = Multilaterator(layout)
    rng = np.random.default_rng(1)
    for _ in range(50):
        p = np.array([rng.uniform(-2, 2), rng.uniform(-2, 2), rng.uniform(1.7, 7.0)])
        d = np.linalg.norm(pos - p, axis=1)
        f = _fix(m.solve_twr(TwrMeasurement(0.0, layout.anchor_ids, tuple(d))))
        np.testing.assert_allclose(f.position_m, p, atol=1e-6)

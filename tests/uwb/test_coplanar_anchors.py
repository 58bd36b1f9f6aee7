"""Anchors at one height (the DWM1001 set-up of delivery 4.2.2): coplanar layouts are solved on
the known side of the anchors' plane, the weak vertical is reported (VDOP) and handed to the EKF,
a tag at the plane keeps its horizontal (gated on HDOP, VDOP bounded), three anchors with a known
side fix the tag exactly, only collinear or too few distinct anchors are refused."""

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
from companion.uwb.measurements import TdoaMeasurement, TwrMeasurement, UwbFix, UwbRejection
from companion.uwb.models import TWR
from companion.uwb.multilateration import Multilaterator
from companion.uwb.solver import dilution_of_precision, dilutions_of_precision

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


#: the second-order VDOP bound at the centre of SQUARE, by hand: in (x, y, u = h^2) the Jacobian
#: rows are (+-1/sqrt 2, +-1/sqrt 2, 1/(2 rho)), rho = sqrt 18 to every anchor, so J^T J =
#: diag(2, 2, 4/(4 rho^2)) = diag(2, 2, 1/18): HDOP = sqrt(1/2 + 1/2) = 1, var_u = 18 per unit
#: range error, VDOP = sqrt(sqrt(18) / 0.10) (range_sigma_m = 0.10)
CENTRE_IN_PLANE_VDOP = math.sqrt(math.sqrt(18.0) / 0.10)


@pytest.mark.parametrize("h", [0.0, 0.02])
def test_tag_in_the_anchor_plane_gets_the_horizontal_and_a_weak_bounded_vertical(h: float) -> None:
    """At the plane the linearised VDOP diverges (a PDOP gate would refuse the fix); the
    horizontal is as good as anywhere, so the fix is kept, gated on HDOP, with VDOP bounded."""
    layout = layout_from_positions(SQUARE)
    p = np.array([0.0, 0.0, 1.2 + h])
    d = np.linalg.norm(SQUARE - p, axis=1)
    assert dilutions_of_precision(p, SQUARE, TWR)[0] > 20.0 or h == 0.0  # a PDOP gate would refuse it
    f = _fix(Multilaterator(layout).solve_twr(TwrMeasurement(0.0, layout.anchor_ids, tuple(d))))
    np.testing.assert_allclose(f.position_m[:2], p[:2], atol=1e-6)
    assert 1.2 <= f.z_m <= 1.2 + 0.05  # on the tag's side, at the plane: the height is not observed
    assert f.vertical_weak and f.redundancy == 1
    assert f.hdop == pytest.approx(1.0, rel=1e-3)
    assert f.vdop == pytest.approx(CENTRE_IN_PLANE_VDOP, rel=1e-3)
    assert f.pdop == pytest.approx(math.hypot(f.hdop, f.vdop), rel=1e-9)


def test_ranges_too_short_for_any_height_collapse_onto_the_plane_with_the_horizontal_kept() -> None:
    """Ranges a little shorter than the in-plane distances (as in a real PANS line, ranging
    bias): no height fits, the least-squares height is 0; the horizontal is still right."""
    layout = layout_from_positions(SQUARE, tag_side="below")
    p = np.array([0.8, -0.5, 1.2])
    d = np.linalg.norm(SQUARE - p, axis=1) - 0.05
    f = _fix(Multilaterator(layout).solve_twr(TwrMeasurement(0.0, layout.anchor_ids, tuple(d))))
    assert np.linalg.norm(f.position_m[:2] - p[:2]) < 0.02
    assert 1.2 - 0.05 <= f.z_m <= 1.2  # the tag's side is below
    assert f.hdop < 1.5 and f.vdop > 5.0
    assert f.residual_rms_m == pytest.approx(0.05, abs=0.01)


def test_a_poor_horizontal_is_still_refused() -> None:
    """Anchors on a 0.6 m square, tag 9.5 m above: every range points the same way, the
    horizontal is not determined (HDOP 22 > max_pdop 20) -- refused, naming the figure."""
    small = np.array([[0.3, 0.3, 0.0], [-0.3, 0.3, 0.0], [-0.3, -0.3, 0.0], [0.3, -0.3, 0.0]])
    layout = layout_from_positions(small)
    d = np.linalg.norm(small - np.array([0.0, 0.0, 9.5]), axis=1)
    r = Multilaterator(layout).solve_twr(TwrMeasurement(0.0, layout.anchor_ids, tuple(d)))
    assert isinstance(r, UwbRejection) and r.reason.value == "bad_geometry"
    assert r.detail.startswith("HDOP (in the anchors' plane) 22.")


#: three anchors on the floor; the tag at (1, 1, 2): ranges^2 = 6, 14, 9. By hand: d0^2 - d1^2 =
#: 8x - 16 = -8 -> x = 1; d0^2 - d2^2 = 6y - 9 = -3 -> y = 1; h^2 = 6 - 1 - 1 = 4 -> h = 2.
TRIANGLE = np.array([[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [0.0, 3.0, 0.0]])


@pytest.mark.parametrize(("side", "z"), [("above", 2.0), ("below", -2.0)])
def test_three_anchors_at_one_height_determine_the_tag_exactly(side: str, z: float) -> None:
    layout = layout_from_positions(TRIANGLE, tag_side=side)
    assert layout.coplanar
    m = Multilaterator(layout)
    f = _fix(m.solve_twr(TwrMeasurement(0.0, layout.anchor_ids, (math.sqrt(6.0), math.sqrt(14.0), 3.0))))
    np.testing.assert_allclose(f.position_m, [1.0, 1.0, z], atol=1e-9)
    # exactly determined: no redundant range, so no outlier (nor consistency) check is possible
    assert f.redundancy == 0 and not f.outliers_checked and f.vertical_weak
    assert f.residual_rms_m < 1e-9
    # TDoA has a fourth unknown: 3 anchors are not enough
    r = m.solve_tdoa(TdoaMeasurement(0.0, "A0", ("A1", "A2"), (math.sqrt(14.0) - math.sqrt(6.0), 3.0 - math.sqrt(6.0))))
    assert isinstance(r, UwbRejection) and r.reason.value == "too_few_anchors" and "need 4" in r.detail


def test_three_anchor_ranges_that_do_not_meet_are_refused() -> None:
    """In-plane distances sqrt(2), sqrt(10), sqrt(5) from (1, 1): ranges 0.5 m shorter fit no
    point, the plain residuals (nothing is redundant) exceed the threshold."""
    layout = layout_from_positions(TRIANGLE)
    d = tuple(float(v) for v in np.sqrt([2.0, 10.0, 5.0]) - 0.5)
    r = Multilaterator(layout).solve_twr(TwrMeasurement(0.0, layout.anchor_ids, d))
    assert isinstance(r, UwbRejection) and r.reason.value == "inconsistent"
    assert "exactly determined" in r.detail


def test_three_heard_of_four_coplanar_anchors_give_a_fix_but_not_of_3d_anchors() -> None:
    layout = layout_from_positions(SQUARE)
    p = np.array([0.4, -0.7, 4.0])
    d = np.linalg.norm(SQUARE - p, axis=1)
    heard = layout.anchor_ids[:3]
    f = _fix(Multilaterator(layout).solve_twr(TwrMeasurement(0.0, heard, tuple(d[:3]))))
    np.testing.assert_allclose(f.position_m, p, atol=1e-8)
    assert f.anchors_used == heard and f.redundancy == 0
    shipped = load_anchor_layout()  # anchors at different heights: 3 ranges leave two mirror images
    assert not shipped.coplanar
    A = shipped.positions_array()
    r = Multilaterator(shipped).solve_twr(
        TwrMeasurement(0.0, shipped.anchor_ids[:3], tuple(np.linalg.norm(A[:3] - np.array([0.2, 0.1, 2.0]), axis=1)))
    )
    assert isinstance(r, UwbRejection) and r.reason.value == "too_few_anchors" and "need 4" in r.detail


def test_a_three_anchor_file_loads_and_degenerate_three_are_refused(tmp_path: Path) -> None:
    three = ONE_HEIGHT.split('[[anchors]]\nid = "A4"')[0]
    layout = AnchorLayout.from_toml(_write(tmp_path, three))
    assert len(layout.anchor_ids) == 3 and layout.coplanar
    for edit, rule in [
        (lambda t: t.replace("[-3.0, -3.0, 0.0]", "[0.0, 3.0, 0.0]"), "on one line"),
        (lambda t: t.replace("[-3.0, -3.0, 0.0]", "[3.0, 3.0, 0.0]"), "2 distinct anchor positions"),
    ]:
        path = _write(tmp_path, edit(three))
        with pytest.raises(AnchorLayoutError) as err:
            AnchorLayout.from_toml(path)
        assert err.value.key == "anchors.position_m" and rule in err.value.rule and str(path) in str(err.value)
    two = ONE_HEIGHT.split('[[anchors]]\nid = "A3"')[0]
    with pytest.raises(AnchorLayoutError) as err:
        AnchorLayout.from_toml(_write(tmp_path, two))
    assert err.value.key == "anchors" and "at least 3 anchors at one height" in err.value.rule


def test_the_ekf_hardly_uses_the_vertical_of_an_in_plane_fix() -> None:
    layout = layout_from_positions(SQUARE)
    p = np.array([0.5, 0.3, 1.2])
    f = _fix(
        Multilaterator(layout).solve_twr(
            TwrMeasurement(0.0, layout.anchor_ids, tuple(np.linalg.norm(SQUARE - p, axis=1)))
        )
    )
    T = anchor_frame_to_ned(np.array([0.0, 0.0, 0.0]), math.pi / 2)
    ekf = _ekf_at(T.apply(p))
    P0 = ekf.P.copy()
    assert ekf.update_uwb(f, T).value == "accepted"
    # from a vague prior (10 m) the update leaves the vertical at ~(sigma VDOP)^2, sigma >= 0.1 m,
    # i.e. the vertical the fix does not observe stays ~0.6 m uncertain, the horizontal ~7 cm
    assert ekf.P[2, 2] > (0.1 * f.vdop) ** 2 and ekf.P[2, 2] > 50.0 * ekf.P[0, 0]
    assert P0[0, 0] == P0[2, 2]


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
    assert f.pdop == pytest.approx(dilution_of_precision(f.position_m, A, TWR), rel=1e-12)
    assert dilutions_of_precision(f.position_m, A, TWR)[0] == pytest.approx(f.pdop, rel=1e-12)


def _ekf_at(p_world: np.ndarray) -> DeliveryEkf:
    ekf = DeliveryEkf(EkfConfig(), x0=np.concatenate([p_world, np.zeros(9)]))
    ekf.xi = True  # already on pad-local data: P is used as it is (delivery eq 12)
    return ekf


def test_ekf_gets_the_weak_vertical_and_the_isotropic_case_is_unchanged() -> None:
    T = anchor_frame_to_ned(np.array([10.0, 5.0, 0.0]), math.pi / 2)
    p_world = np.array([10.0, 5.0, -3.0])
    p_anchor = T.inverse().apply(p_world)
    x, y, z = (float(v) for v in p_anchor)
    weak = UwbFix(0.0, x, y, z, 3.0, 0.0, (), "pad", hdop=1.0, vdop=2.8, outliers_checked=False, vertical_weak=True)
    iso = UwbFix(0.0, x, y, z, 3.0, 0.0, (), "pad", hdop=1.0, vdop=2.8)
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

"""Real DWM1001 PANS ``lec`` lines: our TWR fix against the tag firmware's own ``POS``.

The lines below are data (numbers only), quoted as printed by DWM1001 tags in public set-ups and
found in public GitHub code comments and examples; they are not ours and were not simulated.
Each is parsed by :class:`LecParser`, the anchor layout is the one the line itself reports
(``anchor_layout_from_reading``, tag side as the firmware's ``POS`` puts it), and the fix is
compared with ``POS``.

The bound (3 sigma of fix - POS, per axis): the DWM1001 ranges to +-10 cm (datasheet: sigma_r =
0.10 m taken as one sigma, conservatively) and PANS quotes ~10 cm for its position horizontally,
worse vertically (sigma_POS = 0.10 m horizontally, 0.20 m vertically assumed). Our fix's own
spread is sigma_r x HDOP/sqrt 2 per horizontal axis and sigma_r x VDOP vertically (from the fix),
and PANS filters its positions while we solve each line on its own, so the two are treated as
independent: |fix - POS| < 3 sqrt((sigma_r DOP)^2 + sigma_POS^2) per axis (0.38-0.44 m
horizontally for these lines). Measured with the solver before this module (fix - POS): line 1
(-0.04, -0.15, +0.19) m, line 2 (+0.07, -0.17, -0.19), line 4 (+0.02, -0.08, +0.06), range
residuals 8, 9, 5 cm; line 3 was refused (PDOP 2.8e6), the 3-anchor cases were refused. The four
4-anchor lines' horizontal differences have an RMS of 0.095 m per axis, as the noise predicts
(~0.13 m), which is asserted too (< 0.15 m).
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.uwb.anchors import AnchorLayout
from companion.uwb.measurements import TwrMeasurement, UwbFix, UwbRejection
from companion.uwb.multilateration import Multilaterator
from companion_plugins.dwm1001 import LecParser, LineKind, anchor_layout_from_reading, explain_lec_line

#: (line, the tag's side of the anchors' plane as its POS shows it). Lines printed by DWM1001
#: tags in public set-ups (public GitHub code comments / examples).
PUBLIC_LINES = (
    # four anchors on the floor (z = 0) on an 8 m square; POS puts the tag 1.97 m below them
    (
        "DIST,4,AN0,022E,7.94,8.03,0.00,3.44,AN1,9280,7.95,0.00,0.00,5.68,AN2,DCAE,0.00,8.03,0.00,7.76,"
        "AN3,5431,0.00,0.00,0.00,8.73,POS,6.95,5.37,-1.97,52",
        "below",
    ),
    # four floor anchors on a 3 m square, tag 1.27 m above
    (
        "DIST,4,AN0,2F2F,3.05,2.68,0.00,2.21,AN1,2C9D,-0.04,2.91,0.00,2.39,AN2,2ED0,3.02,0.00,0.00,2.19,"
        "AN3,2BA2,0.00,0.00,0.00,2.56,POS,1.59,1.65,1.27,44",
        "above",
    ),
    # anchors at 2.25 m on a 5 x 8 m rectangle, tag below; the ranges put the tag almost IN the
    # anchors' plane (range to AN3 3.19 m < its horizontal distance 3.25 m to POS)
    (
        "DIST,4,AN0,1151,5.00,8.00,2.25,6.44,AN1,0CA8,0.00,8.00,2.25,6.50,AN2,111C,5.00,0.00,2.25,3.24,"
        "AN3,1150,0.00,0.00,2.25,3.19,POS,2.55,2.01,1.71,98",
        "below",
    ),
    # anchors at 2.20-2.33 m (nearly one height), tag below
    (
        "DIST,4,AN0,0E15,1.75,4.55,2.33,1.61,AN1,1516,0.00,4.55,2.20,2.15,AN2,41B1,1.75,0.00,2.20,4.23,"
        "AN3,089F,0.00,0.00,2.20,4.37,POS,1.49,4.02,0.78,59",
        "below",
    ),
)
#: three anchors heard; the line's POS is cut off in its source after y (no z, no quality factor)
THREE_ANCHOR_LINE = (
    "DIST,3,AN0,2F2F,3.05,2.68,0.00,2.20,AN1,2ED0,3.02,0.00,0.00,2.23,AN2,2BA2,0.00,0.00,0.00,3.13,POS,1.76,1.59"
)
#: garbled output at a high update rate (two lines run together)
GARBLED_LINE = (
    "DIST,4,AN0,0090,0.00,0.00,0.00,3.25,AN1,D91E,0.00,0.00,0.00,3.33,AN2,0487,0.00,0.00,0.00,0.18,"
    "AN3,15BA,0.00,0,AN3,15BA,0.00,0.00,0.00,0.00"
)

RANGE_SIGMA_M = 0.10  # DWM1001 TWR, datasheet +-10 cm
POS_SIGMA_H_M = 0.10  # PANS position, horizontally (~10 cm)
POS_SIGMA_V_M = 0.20  # PANS position, vertically ("worse")


def _within_noise(fix: UwbFix, pos: np.ndarray) -> None:
    """|fix - POS| below 3 sigma of both solutions' noise, per axis (see the module doc)."""
    d = fix.position_m - pos
    bound_h = 3.0 * math.hypot(RANGE_SIGMA_M * fix.hdop / math.sqrt(2.0), POS_SIGMA_H_M)
    bound_v = 3.0 * math.hypot(RANGE_SIGMA_M * fix.vdop, POS_SIGMA_V_M)
    assert abs(d[0]) < bound_h and abs(d[1]) < bound_h, (d, bound_h, fix)
    assert abs(d[2]) < bound_v, (d, bound_v, fix)


def _solve(line: str, side: str) -> tuple[UwbFix | UwbRejection, np.ndarray, AnchorLayout]:
    parser = LecParser()
    reading = parser.feed(line + "\r\n", time_s=1.0)
    assert reading is not None and parser.stats.readings == 1, parser.last_drop_reason
    assert reading.position_m is not None and reading.quality_factor is not None
    layout = anchor_layout_from_reading(reading, tag_side=side)
    assert layout.coplanar  # every public set-up here has its anchors at (about) one height
    return Multilaterator(layout).solve_twr(reading.to_twr_measurement()), np.array(reading.position_m), layout


@pytest.mark.parametrize(("line", "side"), PUBLIC_LINES, ids=["floor-below", "floor-above", "in-plane", "tripods"])
def test_our_fix_agrees_with_the_firmware_pos(line: str, side: str) -> None:
    fix, pos, layout = _solve(line, side)
    assert isinstance(fix, UwbFix), fix
    assert fix.vertical_weak and not fix.outliers_checked and fix.redundancy == 1
    assert fix.residual_rms_m < 0.10  # the four ranges agree with one point to the ranging noise
    _within_noise(fix, pos)
    # on the firmware's side of the anchors' plane
    assert float((fix.position_m - layout.plane_point_m) @ layout.tag_side_normal) >= 0.0


def test_the_horizontal_differences_have_the_spread_the_noise_predicts() -> None:
    d = []
    for line, side in PUBLIC_LINES:
        fix, pos, _ = _solve(line, side)
        assert isinstance(fix, UwbFix), fix
        d.extend((fix.position_m - pos)[:2])
    rms = float(np.sqrt(np.mean(np.square(d))))
    assert rms < 0.15, rms  # measured 0.095 m; expected ~sqrt((0.1 x 1.2 / sqrt 2)^2 + 0.1^2) = 0.13 m


def test_a_tag_in_the_anchor_plane_gets_a_good_horizontal_and_a_weak_vertical() -> None:
    """Line 3: the ranges are a little short for any height below the anchors, so the fitted
    height collapses onto their plane (PDOP ~2.8e6: a PDOP gate would refuse it). The
    horizontal agrees with POS to 6 cm and the vertical is reported weak (VDOP ~6, i.e. ~0.6 m
    at 10 cm ranging), which covers the 0.54 m by which POS puts the tag below the plane."""
    line, side = PUBLIC_LINES[2]
    fix, pos, _ = _solve(line, side)
    assert isinstance(fix, UwbFix), fix
    d = fix.position_m - pos
    assert math.hypot(d[0], d[1]) < 0.10
    assert fix.z_m == pytest.approx(2.25, abs=0.02)  # at the plane: the height is not observed
    assert fix.hdop < 1.5 and fix.vdop > 4.0 * fix.hdop
    assert abs(d[2]) < RANGE_SIGMA_M * fix.vdop  # within one reported sigma
    assert fix.pdop == pytest.approx(math.hypot(fix.hdop, fix.vdop), rel=1e-9)


def test_the_three_anchor_line_is_dropped_as_partial_and_its_ranges_fix_the_tag() -> None:
    """The 3-anchor line's POS is cut off: the parser drops it as PARTIAL, naming the missing
    field, without a crash. Its DIST part is complete: those three ranges (nothing added) fix the
    tag, exactly determined. That fix is 0.55 m from the x, y the cut-off POS printed -- but the
    printed POS does not fit the printed ranges: at its x, y no height brings all three ranges
    within 0.30 m (PANS filters its position; this line's POS is not the solution of this line's
    ranges), so that line is no test of agreement. The same set-up's 4-anchor line (line 2) with
    one anchor left out is."""
    parser = LecParser()
    assert parser.feed(THREE_ANCHOR_LINE + "\r\n") is None
    assert parser.stats.partial == 1 and parser.stats.dropped == 1
    assert parser.last_drop_reason == "partial: line ends before POS z (field 23)"
    dist_part = THREE_ANCHOR_LINE.split(",POS,")[0]
    reading = LecParser().feed(dist_part)
    assert reading is not None and reading.position_m is None and len(reading.anchors) == 3
    layout = anchor_layout_from_reading(reading, tag_side="above")
    assert layout.coplanar
    fix = Multilaterator(layout).solve_twr(reading.to_twr_measurement())
    assert isinstance(fix, UwbFix), fix
    assert fix.redundancy == 0 and not fix.outliers_checked
    assert fix.residual_rms_m < 1e-9  # three ranges, three unknowns: met exactly
    anchors = layout.positions_array()
    ranges = np.array([a.distance_m for a in reading.anchors])
    pos_xy = np.array([1.76, 1.59])  # the x, y the cut-off POS printed (two decimals each)
    assert np.linalg.norm(fix.position_m[:2] - pos_xy) == pytest.approx(0.59, abs=0.01)
    worst = min(
        float(np.max(np.abs(np.linalg.norm(anchors - np.array([*pos_xy, z]), axis=1) - ranges)))
        for z in np.linspace(0.0, 4.0, 4001)
    )
    assert worst > 0.30  # > 3 x the DWM1001's ranging noise: POS is not these ranges' solution


@pytest.mark.parametrize(("line", "side"), PUBLIC_LINES, ids=["floor-below", "floor-above", "in-plane", "tripods"])
def test_any_three_of_four_heard_anchors_still_fix_the_tag(line: str, side: str) -> None:
    """A 4-anchor layout with only 3 anchors heard (every choice of 3, each line's own ranges):
    an exactly determined fix, within the noise bound of POS."""
    reading = LecParser().feed(line)
    assert reading is not None and reading.position_m is not None
    m = Multilaterator(anchor_layout_from_reading(reading, tag_side=side))
    for left_out in range(4):
        heard = [a for k, a in enumerate(reading.anchors) if k != left_out]
        f = m.solve_twr(TwrMeasurement(1.0, tuple(a.anchor_id for a in heard), tuple(a.distance_m for a in heard)))
        assert isinstance(f, UwbFix), (left_out, f)
        assert f.redundancy == 0 and not f.outliers_checked and len(f.anchors_used) == 3
        _within_noise(f, np.array(reading.position_m))


def test_garbled_output_is_dropped_with_a_reason() -> None:
    parser = LecParser()
    assert parser.feed(GARBLED_LINE + "\r\n") is None
    assert parser.stats.malformed == 1 and parser.stats.dropped == 1 and parser.stats.readings == 0
    assert parser.last_drop_reason == "malformed: AN3 z (field 24) is 'AN3': a finite number expected"
    kind, reading, reason = explain_lec_line(GARBLED_LINE)
    assert kind is LineKind.MALFORMED and reading is None and "AN3 z" in reason

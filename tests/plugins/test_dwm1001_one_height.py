"""Four DWM1001 anchors at one height (the usual PANS set-up, delivery 4.2.2's four anchors
around the pad): ``lec`` lines shaped as the firmware prints them, for a tag descending over the
pad. Our TWR fix must agree with the tag firmware's own ``POS`` solution within the noise.

The synthetic lines: ranges are the true distances plus seeded Gaussian noise of the DWM1001's
TWR precision (~5 cm 1-sigma, the datasheet's +-10 cm), printed with two decimals as PANS does;
``POS`` is the firmware's location engine, modelled as the true position with its published
accuracy (~5 cm horizontally, ~10 cm vertically with anchors at one height), also two decimals,
quality factor 0-100.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.uwb.measurements import UwbFix
from companion.uwb.multilateration import Multilaterator
from companion_plugins.dwm1001 import LecParser, anchor_layout_from_reading

#: PANS anchor ids (hex) and positions: four tripods 1.0 m high on a 5 x 5 m square around the pad
ANCHORS = (
    ("1151", (-2.5, -2.5, 1.0)),
    ("0CA8", (-2.5, 2.5, 1.0)),
    ("111C", (2.5, 2.5, 1.0)),
    ("1150", (2.5, -2.5, 1.0)),
)
RANGE_SIGMA_M = 0.05
POS_SIGMA_M = np.array([0.05, 0.05, 0.10])
ROUNDING_SIGMA_M = 0.01 / math.sqrt(12.0)  # two decimals


def lec_line(p_true: np.ndarray, rng: np.random.Generator) -> str:
    parts = ["DIST", str(len(ANCHORS))]
    for k, (aid, a) in enumerate(ANCHORS):
        d = float(np.linalg.norm(p_true - np.array(a))) + float(rng.normal(0.0, RANGE_SIGMA_M))
        parts += [f"AN{k}", aid, f"{a[0]:.2f}", f"{a[1]:.2f}", f"{a[2]:.2f}", f"{d:.2f}"]
    pos = p_true + rng.normal(0.0, POS_SIGMA_M)
    qf = int(rng.integers(60, 101))
    parts += ["POS", f"{pos[0]:.2f}", f"{pos[1]:.2f}", f"{pos[2]:.2f}", str(qf)]
    return ",".join(parts)


def descent(n: int, rng: np.random.Generator) -> np.ndarray:
    """A tag on a drone descending from 6 m to 1.6 m over the pad, drifting a little."""
    z = np.linspace(6.0, 1.6, n)
    xy = np.cumsum(rng.normal(0.0, 0.03, (n, 2)), axis=0) + np.array([0.4, -0.3])
    return np.column_stack([xy, z])


def test_fix_from_lec_lines_agrees_with_the_firmware_pos() -> None:
    rng = np.random.default_rng(20261123)
    truth = descent(200, rng)
    lines = [lec_line(p, rng) for p in truth]
    assert lines[0].startswith("DIST,4,AN0,1151,-2.50,-2.50,1.00,") and ",POS," in lines[0]

    parser = LecParser()
    readings = [parser.feed(line + "\r\n", time_s=0.1 * i) for i, line in enumerate(lines)]
    assert parser.stats.readings == len(lines) and parser.stats.dropped == 0
    first = readings[0]
    assert first is not None
    layout = anchor_layout_from_reading(first)  # the positions the anchors report in the line
    assert layout.coplanar and layout.tag_side == "above"
    m = Multilaterator(layout)

    diffs, sig_h, sig_v = [], [], []
    sigma_r = math.hypot(RANGE_SIGMA_M, ROUNDING_SIGMA_M)
    for r in readings:
        assert r is not None and r.position_m is not None
        f = m.solve_twr(r.to_twr_measurement())
        assert isinstance(f, UwbFix), f
        assert f.vertical_weak and not f.outliers_checked  # four anchors: no outlier rejection
        d = f.position_m - np.array(r.position_m)
        # the expected spread of (fix - POS) per axis: our fix's (range noise x DOP) and the firmware's
        s_h = math.hypot(sigma_r * f.hdop / math.sqrt(2.0), POS_SIGMA_M[0])
        s_v = math.hypot(sigma_r * f.vdop, POS_SIGMA_M[2])
        assert abs(d[0]) < 4.5 * s_h and abs(d[1]) < 4.5 * s_h, (d, f)
        assert abs(d[2]) < 4.5 * s_v, (d, f)
        diffs.append(d)
        sig_h.append(s_h)
        sig_v.append(s_v)
    D = np.array(diffs)
    # normalised by the expected spread, the differences are ~N(0, 1) per axis: no bias, no
    # over- or under-stated DOP
    zh = D[:, :2] / np.array(sig_h)[:, None]
    zv = D[:, 2] / np.array(sig_v)
    assert abs(float(np.mean(zh))) < 0.2 and abs(float(np.mean(zv))) < 0.2
    assert 0.75 < float(np.std(zh)) < 1.25
    assert 0.75 < float(np.std(zv)) < 1.25
    # and against the truth: the horizontal error stays at the ranging noise level
    P = np.array([f for f in (m.solve_twr(r.to_twr_measurement()) for r in readings if r is not None)])
    err = np.array([p.position_m for p in P]) - truth
    assert float(np.sqrt(np.mean(err[:, 0] ** 2 + err[:, 1] ** 2))) < 0.12


@pytest.mark.parametrize("height_m", [1.6, 3.0, 6.0])
def test_vertical_is_reported_weaker_the_closer_the_tag_is_to_the_anchor_plane(height_m: float) -> None:
    rng = np.random.default_rng(7)
    line = lec_line(np.array([0.2, 0.1, height_m]), rng)
    reading = LecParser().feed(line)
    assert reading is not None
    f = Multilaterator(anchor_layout_from_reading(reading)).solve_twr(reading.to_twr_measurement())
    assert isinstance(f, UwbFix)
    # anchors 1 m high on a 5 m square: above ~4 m the vertical is the better axis, near the
    # anchors' plane it is the weak one
    if height_m <= 1.6:
        assert f.vdop > 2.0 * f.hdop
    if height_m >= 6.0:
        assert f.vdop < f.hdop

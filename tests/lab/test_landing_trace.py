"""The real landings' descent traces: written by the campaign, read back and split at the first
ground contact (lab/landing_trace.py)."""

from __future__ import annotations

import math

import pytest

from companion_firmware.truth_harness import LANDING_TRACE_FIELDS
from companion_lab.landing_trace import TraceError, bands, contact, main, read_trace, report
from companion_lab.real_campaign import _write_trace


def _row(t: float, h: float, tn: float, te: float, en: float, ee: float, vn: float = 0.0) -> tuple[float, ...]:
    values = dict.fromkeys(LANDING_TRACE_FIELDS, 0.0)
    values.update(t_s=t, truth_h_m=h, truth_n_m=tn, truth_e_m=te, est_n_m=en, est_e_m=ee, truth_vn_m_s=vn, landed=0.0)
    return tuple(values[k] for k in LANDING_TRACE_FIELDS)


def _descent() -> tuple[tuple[float, ...], ...]:
    """1 m down at 0.5 m/s, 3 cm north and believed 1 cm north of the pad; the contact at 2 s
    (4 cm north, believed 2 cm); then it slides 5 cm east before the autopilot reports it."""
    rows = [_row(0.05 * k, 1.0 - 0.025 * k, 0.03, 0.0, 0.01, 0.0, vn=0.1) for k in range(40)]
    rows.append(_row(2.0, 0.0, 0.04, 0.0, 0.02, 0.0))
    rows.append(_row(2.05, -0.1, 0.04, 0.05, 0.02, 0.0))
    return tuple(rows)


def test_the_contact_and_the_bands_by_hand(tmp_path):
    path = tmp_path / "traces" / "fusion-7.csv"
    _write_trace(path, _descent())
    tr = read_trace(path)
    c = contact("fusion-7", tr)
    assert c is not None
    assert c.error_cm == pytest.approx(4.0)
    assert c.believed_cm == pytest.approx(2.0)
    assert c.estimate_error_cm == pytest.approx((-2.0, 0.0))
    assert c.moved_after_cm == pytest.approx(5.0)  # scored at ON_GROUND, this would count
    assert c.speed_at_contact_m_s == pytest.approx(0.1)
    b = {lohi: (n, truth, est, diff) for lohi, n, truth, est, diff in bands(tr)}
    n, truth, est, diff = b[(0.5, 1.0)]
    assert n == 20 and truth == pytest.approx(3.0) and est == pytest.approx(1.0) and diff == pytest.approx(2.0)
    assert (2.0, 3.0) not in b
    text = report(path.parent)
    assert "fusion-7" in text and "mean over 1: error 4.0 cm" in text


def test_a_landing_that_never_touched_down_and_bad_input(tmp_path, capsys):
    rows = tuple(r for r in _descent() if r[LANDING_TRACE_FIELDS.index("truth_h_m")] > 0.1)
    _write_trace(tmp_path / "a.csv", rows)
    assert contact("a", read_trace(tmp_path / "a.csv")) is None
    assert "no ground contact" in report(tmp_path)
    _write_trace(tmp_path / "none.csv", ())  # a landing that never reached its descent: no file
    assert not (tmp_path / "none.csv").exists()
    (tmp_path / "b.csv").write_text("t_s,truth_h_m\n1.0,oops\n")
    with pytest.raises(TraceError, match=r"b\.csv: not a landing trace"):
        read_trace(tmp_path / "b.csv")
    assert main([str(tmp_path / "empty")]) == 2
    assert "no landing traces" in capsys.readouterr().err
    assert math.isfinite(read_trace(tmp_path / "a.csv")["t_s"][0])

import math

from companion.autopilot import PositionNed, StatusText, TelemetryCache


def test_nan_sample_rejected_and_counted_last_good_kept():
    tc = TelemetryCache()
    seen = []
    tc.add_listener(seen.append)
    good = PositionNed(1.0, 1, 2, 3, 0, 0, 0)
    assert tc.push(good)
    assert not tc.push(PositionNed(2.0, math.nan, 2, 3, 0, 0, 0))
    assert not tc.push(PositionNed(3.0, 1, 2, 3, math.inf, 0, 0))
    assert tc.position_ned is good
    assert tc.rejected["PositionNed"] == 2 and tc.received["PositionNed"] == 1
    assert "north_m" in tc.last_rejection or "north_m_s" in tc.last_rejection
    assert seen == [good]
    assert tc.push(StatusText(4.0, 6, "hello"))

import math

import pytest

from companion.autopilot import Attitude, GlobalPosition, PositionNed, StatusText, TelemetryCache


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


def test_link_latch_needs_a_heartbeat_newer_than_the_loss():
    from companion.autopilot.interface import LinkLatch

    latch = LinkLatch()
    assert latch.check(1.0, True, 0.9)
    assert not latch.check(2.0, False, 0.9)  # lost at t = 2
    assert not latch.check(2.5, True, 1.9)  # telemetry again, but no heartbeat since the loss
    assert latch.check(3.0, True, 2.8)  # fresh heartbeat: up
    assert latch.check(3.1, True, 2.8)


def test_validate_names_the_first_non_finite_field_of_each_sample_type():
    """validate() looks each dataclass's fields up once per type: every type keeps its own."""
    for _ in range(2):  # the second round runs on the names looked up in the first
        with pytest.raises(ValueError, match=r"PositionNed\.east_m is not finite"):
            PositionNed(1.0, 1.0, math.nan, 3.0, 0.0, 0.0, 0.0).validate()
        with pytest.raises(ValueError, match=r"Attitude\.pitch_rad is not finite"):
            Attitude(1.0, 0.0, math.inf, math.nan, 0.0, 0.0, 0.0).validate()
        with pytest.raises(ValueError, match=r"GlobalPosition\.time_s is not finite"):
            GlobalPosition(math.nan, 1.0, 2.0, 3.0, 4.0).validate()
        ok = GlobalPosition(1.0, 1.0, 2.0, 3.0, 4.0)
        assert ok.validate() is ok

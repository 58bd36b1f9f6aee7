"""The TIMESYNC clock-offset estimator (companion.autopilot.timesync): the min-RTT filter, the
jitter, a clock jump, and answers that are not answers to us."""

from __future__ import annotations

import numpy as np
import pytest

from companion.autopilot.timesync import (
    NS_PER_S,
    ClockJump,
    ClockOffsetEstimator,
    TimesyncError,
    TimesyncRejection,
    answer_timesync,
)

OFFSET_NS = -123_456_789_000  # autopilot boot clock minus companion monotonic
T0_NS = 500 * NS_PER_S  # the companion has been up longer than the autopilot


def exchange(
    est: ClockOffsetEstimator, t_ns: int, up_ns: int, down_ns: int, offset_ns: int = OFFSET_NS
) -> tuple[int, object]:
    """One request sent at ``t_ns``, delayed ``up_ns`` to the autopilot and ``down_ns`` back."""
    tc1, ts1 = est.request(t_ns)
    assert tc1 == 0
    answer = answer_timesync(tc1, ts1, t_ns + up_ns + offset_ns)
    assert answer is not None
    return t_ns + up_ns + down_ns, est.on_timesync(*answer, t_ns + up_ns + down_ns)


def test_firmware_answers_requests_only() -> None:
    assert answer_timesync(0, 42, 1000) == (1000, 42)
    assert answer_timesync(5, 42, 1000) is None  # an answer is never answered (ArduPilot, PX4)


def test_min_rtt_sample_gives_the_offset() -> None:
    rng = np.random.default_rng(7)
    est = ClockOffsetEstimator(window=16)
    t = T0_NS
    for _ in range(40):
        # asymmetric queueing up to 20 ms each way, a 1 ms symmetric floor
        up = 1_000_000 + int(rng.uniform(0, 20e6))
        down = 1_000_000 + int(rng.uniform(0, 20e6))
        _, out = exchange(est, t, up, down)
        assert out is None
        t += 100_000_000
    e = est.estimate
    assert e is not None and e.samples == 16
    # the error of the midpoint is (up - down) / 2 of the fastest exchange, well under its RTT / 2
    assert abs(e.offset_s * NS_PER_S - OFFSET_NS) <= e.rtt_min_s * NS_PER_S / 2
    assert e.rtt_min_s < e.rtt_median_s
    assert 0.0 < e.jitter_s < 0.02
    assert e.to_companion_s(e.to_autopilot_s(5.0)) == pytest.approx(5.0)


def test_symmetric_link_is_exact_and_jitter_free() -> None:
    est = ClockOffsetEstimator()
    t = T0_NS
    for _ in range(5):
        exchange(est, t, 3_000_000, 3_000_000)
        t += 50_000_000
    e = est.estimate
    assert e is not None
    assert e.offset_s * NS_PER_S == pytest.approx(OFFSET_NS, abs=1)
    assert e.jitter_s == 0.0 and e.rtt_min_s == pytest.approx(0.006)


def test_no_estimate_before_min_samples() -> None:
    est = ClockOffsetEstimator(min_samples=3)
    exchange(est, T0_NS, 1000, 1000)
    exchange(est, T0_NS + NS_PER_S, 1000, 1000)
    assert est.estimate is None
    exchange(est, T0_NS + 2 * NS_PER_S, 1000, 1000)
    assert est.estimate is not None


def test_clock_jump_is_confirmed_then_taken() -> None:
    est = ClockOffsetEstimator(jump_confirm=3, jump_threshold_s=0.05)
    t = T0_NS
    for _ in range(10):
        exchange(est, t, 2_000_000, 2_000_000)
        t += 100_000_000
    rebooted = OFFSET_NS - 30 * NS_PER_S  # the autopilot rebooted: its boot clock restarted
    outs = []
    for _ in range(3):
        _, out = exchange(est, t, 2_000_000, 2_000_000, rebooted)
        outs.append(out)
        t += 100_000_000
    assert outs[0] is None and outs[1] is None
    jump = outs[2]
    assert isinstance(jump, ClockJump)
    assert jump.old_offset_s * NS_PER_S == pytest.approx(OFFSET_NS, abs=1)
    assert jump.new_offset_s * NS_PER_S == pytest.approx(rebooted, abs=1)
    e = est.estimate
    assert e is not None and e.jumps == 1 and e.samples == 3
    assert e.offset_s * NS_PER_S == pytest.approx(rebooted, abs=1)


def test_a_lone_outlier_is_not_a_jump() -> None:
    est = ClockOffsetEstimator(jump_confirm=3)
    t = T0_NS
    for _ in range(10):
        exchange(est, t, 2_000_000, 2_000_000)
        t += 100_000_000
    exchange(est, t, 2_000_000, 2_000_000, OFFSET_NS + NS_PER_S)  # one bogus answer
    t += 100_000_000
    exchange(est, t, 2_000_000, 2_000_000)
    e = est.estimate
    assert e is not None and e.jumps == 0
    assert e.offset_s * NS_PER_S == pytest.approx(OFFSET_NS, abs=1)


def test_hostile_answers_are_rejected() -> None:
    est = ClockOffsetEstimator(max_rtt_s=0.5)
    _, ts1 = est.request(NS_PER_S)
    now = NS_PER_S + 1_000_000
    assert est.on_timesync(0, ts1, now) is TimesyncRejection.NOT_AN_ANSWER  # a request, not an answer
    assert est.on_timesync(-5, ts1, now) is TimesyncRejection.NEGATIVE_CLOCK
    assert est.on_timesync(2**70, ts1, now) is TimesyncRejection.NEGATIVE_CLOCK  # not an int64
    assert est.on_timesync(10**12, ts1 + 7, now) is TimesyncRejection.UNKNOWN_REQUEST  # never sent
    assert est.on_timesync(10**12, ts1, NS_PER_S - 5) is TimesyncRejection.NEGATIVE_RTT
    assert est.on_timesync(10**12, ts1, NS_PER_S) is TimesyncRejection.NEGATIVE_RTT  # zero RTT
    assert est.on_timesync(10**12, ts1, NS_PER_S + NS_PER_S) is TimesyncRejection.SLOW
    assert est.on_timesync(10**12, ts1, now) is None  # the real answer, still pending
    assert est.on_timesync(10**12, ts1, now + 5) is TimesyncRejection.UNKNOWN_REQUEST  # replayed
    assert est.accepted == 1
    assert est.rejected[TimesyncRejection.NEGATIVE_RTT] == 2
    assert sum(est.rejected.values()) == 8


def test_requests_never_reuse_a_ts1() -> None:
    est = ClockOffsetEstimator()
    a = est.request(1000)[1]
    b = est.request(1000)[1]
    c = est.request(999)[1]  # a clock read backwards: still a fresh ts1
    assert a < b < c
    with pytest.raises(TimesyncError, match="must be > 0"):
        est.request(0)


def test_absurd_but_valid_offsets_are_taken_as_they_are() -> None:
    """An autopilot whose boot clock reads far ahead (ints, no NaN) is an offset, not an error."""
    est = ClockOffsetEstimator()
    t = T0_NS
    far = 2**62
    for _ in range(3):
        exchange(est, t, 1_000_000, 1_000_000, far)
        t += NS_PER_S // 10
    e = est.estimate
    assert e is not None and e.offset_s == pytest.approx(far / NS_PER_S)


def test_pending_requests_are_bounded() -> None:
    est = ClockOffsetEstimator(pending_max=4)
    sent = [est.request(NS_PER_S + i)[1] for i in range(6)]
    # the two oldest unanswered requests were forgotten: their late answers are unknown
    assert est.on_timesync(10**12, sent[0], 2 * NS_PER_S) is TimesyncRejection.UNKNOWN_REQUEST
    assert est.on_timesync(10**12, sent[5], NS_PER_S + 1_000_000) is None


@pytest.mark.parametrize(
    "kwargs",
    [
        {"window": 1},
        {"min_samples": 0},
        {"min_samples": 20, "window": 16},
        {"max_rtt_s": 0.0},
        {"max_rtt_s": float("nan")},
        {"jump_threshold_s": -1.0},
        {"jump_confirm": 0},
    ],
)
def test_bad_settings_are_named(kwargs: dict[str, float]) -> None:
    with pytest.raises(TimesyncError):
        ClockOffsetEstimator(**kwargs)  # type: ignore[arg-type]

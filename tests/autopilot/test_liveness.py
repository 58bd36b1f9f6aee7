"""The control loop's liveness gate and its watchdog thread (companion.autopilot.liveness)."""

from __future__ import annotations

import logging
import threading
import time

import pytest

from companion.autopilot.liveness import INERT_LIVENESS, WATCHDOG_THREAD_NAME, LoopLiveness


class FakeClock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_the_gate_is_open_outside_a_watched_stretch_and_shuts_on_a_stall_beyond_the_limit(caplog):
    clock = FakeClock()
    gate = LoopLiveness(clock)
    clock.t += 1000.0  # nobody renews before the loop starts: not watched, open
    assert gate.alive and gate.may_send() and gate.poll()
    # a poll period longer than the test: only the test's poll() steps the watchdog here
    with caplog.at_level(logging.WARNING), gate.watching(0.5, poll_s=3600.0):
        assert gate.watched and gate.alive
        for _ in range(10):  # 20 Hz ticks: never stalled
            clock.t += 0.05
            gate.renew()
            assert gate.poll() and gate.may_send()
        clock.t += 0.5  # exactly the limit: still alive
        assert gate.poll()
        clock.t += 0.01
        assert not gate.alive and not gate.may_send()  # the senders stop at once, before the watchdog's poll
        assert not gate.poll() and gate.shut and gate.stalls == 1
        clock.t += 14.0
        assert not gate.poll() and gate.stalls == 1  # one stall, said once
        assert not gate.may_send() and gate.withheld == 2
        gate.renew()  # the loop is back
        assert not gate.alive  # still shut until the watchdog sees the renewal
        assert gate.poll() and gate.alive and not gate.shut
        assert gate.longest_stall_s == pytest.approx(14.51)
    assert not gate.watched and gate.alive
    said = [r.getMessage() for r in caplog.records if r.name == "companion.autopilot.liveness"]
    assert len(said) == 2
    assert said[0].startswith("control loop stalled: no guidance tick for 0.51 s (limit 0.50 s)")
    assert said[1].startswith("control loop back after a 14.51 s stall")


def test_a_gate_left_shut_by_a_loop_that_ended_is_open_again_after_the_stretch():
    clock = FakeClock()
    gate = LoopLiveness(clock)
    with gate.watching(0.5, poll_s=3600.0):
        clock.t += 2.0
        assert not gate.poll()
    assert gate.alive and not gate.shut
    with gate.watching(0.5, poll_s=3600.0):  # the next flight starts fresh
        assert gate.poll() and gate.stalls == 1


@pytest.mark.parametrize("stall_s", [0.0, -1.0, float("nan"), float("inf"), 0.01, 60.0])
def test_a_stall_limit_out_of_range_is_refused(stall_s):
    with pytest.raises(ValueError, match=r"stall_s = .*: expected 0.05 to 30.0 s"), LoopLiveness().watching(stall_s):
        pass


def test_one_loop_at_a_time():
    gate = LoopLiveness()
    with gate.watching(0.5), pytest.raises(RuntimeError, match="already watching"), gate.watching(0.5):
        pass


def test_the_inert_gate_never_shuts():
    with INERT_LIVENESS.watching(0.2):
        time.sleep(0.3)
        assert INERT_LIVENESS.alive and INERT_LIVENESS.poll()
    assert not any(t.name == WATCHDOG_THREAD_NAME for t in threading.enumerate())


def test_the_watchdog_thread_says_it_while_the_loop_is_still_blocked(caplog):
    """On the real clock: a loop blocked in time.sleep is caught by the watchdog's thread within
    the limit and a poll period, not when the sleep ends."""
    gate = LoopLiveness()
    records: list[tuple[float, str, str]] = []

    class Grab(logging.Handler):
        def emit(self, record: logging.LogRecord) -> None:
            records.append((time.monotonic(), record.threadName or "", record.getMessage()))

    handler = Grab(logging.WARNING)
    logger = logging.getLogger("companion.autopilot.liveness")
    logger.addHandler(handler)
    try:
        with gate.watching(0.3, poll_s=0.02):
            gate.renew()
            t0 = time.monotonic()
            time.sleep(1.0)  # the loop hangs
            t_back = time.monotonic()
            assert not gate.alive
            gate.renew()
            time.sleep(0.1)
            assert gate.alive
    finally:
        logger.removeHandler(handler)
    assert [r[1] for r in records] == [WATCHDOG_THREAD_NAME, WATCHDOG_THREAD_NAME]
    t_said, _, text = records[0]
    assert "stalled" in text and 0.3 <= t_said - t0 <= 0.6 and t_said < t_back
    assert "back after a 1.0" in records[1][2]
    assert not any(t.name == WATCHDOG_THREAD_NAME for t in threading.enumerate())

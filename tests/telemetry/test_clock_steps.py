"""Signed ground requests against a wall clock that is wrong or stepped: freshness and the replay
cache are judged on the vehicle clock (the wall clock carried on the monotonic clock), the
pre-flight clock verdict decides whether signed requests are taken at all, and a sender's bucket
bounds how many it may send. Each test injects the wall clock and the monotonic clock."""

from __future__ import annotations

import logging

import pytest

from companion.autopilot.preflight.report import ClockProbe, Requirements
from companion.autopilot.preflight.runner import run_checks
from companion.autopilot.preflight.sensors import clock_verdict
from companion.telemetry.auth import (
    CommandKind,
    CommandRefused,
    CommandSettings,
    CommandVerifier,
    RefusalKind,
    RefusalLog,
    sign_command,
)
from companion.telemetry.orders import OrderPad, OrderVerifier, sign_order
from companion.timebase import ClockVerdict, VehicleClock

SECRET = b"0123456789abcdef-clocks"
TRUE_NOW = 1_763_750_000.0  # the true UTC at the start of each test


class Clocks:
    """A true time that advances, a wall clock that may be off it or stepped, and a monotonic clock."""

    def __init__(self, wall_offset_s: float = 0.0) -> None:
        self.elapsed = 0.0
        self.wall_offset_s = wall_offset_s

    def wall(self) -> float:
        return TRUE_NOW + self.elapsed + self.wall_offset_s

    def mono(self) -> float:
        return 1000.0 + self.elapsed

    def true_now(self) -> float:
        return TRUE_NOW + self.elapsed


def commands(c: Clocks, **kw: object) -> tuple[CommandVerifier, VehicleClock]:
    vc = VehicleClock(c.wall, c.mono)
    return CommandVerifier("drone1", CommandSettings(enabled=True, secret=SECRET, **kw), clock=vc), vc  # type: ignore[arg-type]


def refusal(v: CommandVerifier | OrderVerifier, payload: bytes) -> CommandRefused:
    with pytest.raises(CommandRefused) as info:
        v.verify(payload)
    return info.value


def test_a_clock_30_s_ahead_at_start_is_judged_off_and_fixed_by_a_check_that_agrees() -> None:
    c = Clocks(wall_offset_s=30.0)
    v, vc = commands(c)
    fresh_land = sign_command("drone1", CommandKind.LAND, SECRET, issued_unix_s=c.true_now())
    assert refusal(v, fresh_land).kind is RefusalKind.STALE  # what the wall clock alone does
    req = Requirements("px4", 20.0, ())
    probe = ClockProbe(offset_s=-30.0)  # the autopilot's UTC minus the companion's clock
    assert clock_verdict(req, probe) is ClockVerdict.OFF
    vc.judge(clock_verdict(req, probe), probe.offset_s)
    why = refusal(v, sign_command("drone1", CommandKind.LAND, SECRET, issued_unix_s=c.true_now()))
    assert why.kind is RefusalKind.CLOCK and "-30.0 s" in why.reason
    c.wall_offset_s = 0.0  # chrony steps it right; the next pre-flight check agrees
    assert vc.judge(clock_verdict(req, ClockProbe(offset_s=0.01)), 0.01) == pytest.approx(-30.0)
    assert (
        v.verify(sign_command("drone1", CommandKind.LAND, SECRET, issued_unix_s=c.true_now())).kind is CommandKind.LAND
    )


def test_a_clock_stepped_30_s_ahead_in_flight_still_takes_a_fresh_land(caplog: pytest.LogCaptureFixture) -> None:
    c = Clocks()
    v, vc = commands(c)
    c.elapsed, c.wall_offset_s = 60.0, 30.0
    with caplog.at_level(logging.WARNING, logger="companion.telemetry.auth"):
        cmd = v.verify(sign_command("drone1", CommandKind.LAND, SECRET, issued_unix_s=c.true_now()))
        v.verify(sign_command("drone1", CommandKind.HOLD, SECRET, issued_unix_s=c.true_now()))
    assert cmd.kind is CommandKind.LAND and cmd.received_unix_s == pytest.approx(c.true_now())
    assert vc.step_s() == pytest.approx(30.0)
    steps = [r.getMessage() for r in caplog.records if "wall clock" in r.getMessage()]
    assert steps == ["the wall clock is +30.0 s from the vehicle clock (stepped since it was anchored): "
                     "signed commands are judged on the vehicle clock"]  # fmt: skip


def test_a_clock_an_hour_behind_refuses_a_captured_abort_an_hour_old() -> None:
    c = Clocks()
    captured = sign_command("drone1", CommandKind.ABORT, SECRET, issued_unix_s=c.true_now())
    v, _ = commands(c)
    c.elapsed = 3600.0
    c.wall_offset_s = -3600.0  # stepped an hour back: the wall clock now reads the capture's time
    assert refusal(v, captured).kind is RefusalKind.STALE
    # a vehicle that started an hour behind: the pre-flight check says OFF, and signed requests wait
    c2 = Clocks(wall_offset_s=-3600.0)
    v2, vc2 = commands(c2)
    vc2.judge(ClockVerdict.OFF, 3600.0)
    assert refusal(v2, captured).kind is RefusalKind.CLOCK


def test_a_step_forward_and_back_never_reopens_a_used_nonce() -> None:
    c = Clocks()
    v, _ = commands(c)
    hold = sign_command("drone1", CommandKind.HOLD, SECRET, issued_unix_s=c.true_now())
    assert v.verify(hold).kind is CommandKind.HOLD
    c.elapsed, c.wall_offset_s = 1.0, 100.0
    # a fresh command while the wall clock is 100 s ahead is taken; the old nonce stays used
    assert v.verify(sign_command("drone1", CommandKind.RETURN, SECRET, issued_unix_s=c.true_now())).sender
    c.elapsed, c.wall_offset_s = 2.0, 0.0
    assert refusal(v, hold).kind is RefusalKind.REPLAY
    c.elapsed = 11.0  # twice the window later: the nonce may go, the request is stale by then
    assert refusal(v, hold).kind is RefusalKind.STALE


def test_orders_share_the_clock_rules() -> None:
    c = Clocks()
    vc = VehicleClock(c.wall, c.mono)
    v = OrderVerifier("drone1", CommandSettings(enabled=True, secret=SECRET), clock=vc)
    order = sign_order("drone1", OrderPad(47.0, 8.0), SECRET, order_id="o-1", issued_unix_s=c.true_now())
    assert v.verify(order).order_id == "o-1"
    c.elapsed, c.wall_offset_s = 1.0, 100.0
    c.elapsed, c.wall_offset_s = 2.0, 0.0
    assert refusal(v, order).kind is RefusalKind.REPLAY
    vc.judge(ClockVerdict.OFF, 40.0)
    fresh = sign_order("drone1", OrderPad(47.0, 8.0), SECRET, order_id="o-2", issued_unix_s=c.true_now())
    assert refusal(v, fresh).kind is RefusalKind.CLOCK


def test_a_request_older_than_its_senders_newest_by_the_window_is_refused() -> None:
    c = Clocks()
    v, _ = commands(c, window_s=5.0)
    old = sign_command("drone1", CommandKind.HOLD, SECRET, issued_unix_s=c.true_now() - 4.0, sender="ops")
    v.verify(sign_command("drone1", CommandKind.HOLD, SECRET, issued_unix_s=c.true_now() + 4.0, sender="ops"))
    why = refusal(v, old)  # inside the window of the vehicle clock, 8 s before ops's newest
    assert why.kind is RefusalKind.STALE and "ops's newest" in why.reason
    v.verify(sign_command("drone1", CommandKind.HOLD, SECRET, issued_unix_s=c.true_now() - 4.0, sender="ops2"))


def test_each_sender_has_a_token_bucket() -> None:
    c = Clocks()
    v, _ = commands(c, rate_per_s=2.0, burst=3)

    def send(sender: str) -> RefusalKind | None:
        try:
            v.verify(sign_command("drone1", CommandKind.HOLD, SECRET, issued_unix_s=c.true_now(), sender=sender))
        except CommandRefused as err:
            return err.kind
        return None

    assert [send("ops") for _ in range(5)] == [None, None, None, RefusalKind.RATE, RefusalKind.RATE]
    assert send("other") is None  # another sender's bucket is full
    c.elapsed = 0.5  # one token back at 2 a second
    assert [send("ops"), send("ops")] == [None, RefusalKind.RATE]


def test_the_refusal_log_counts_every_refusal_and_samples_one_a_second() -> None:
    t = [0.0]
    rl = RefusalLog("order", 1.0, lambda: t[0])
    samples = []
    for i in range(10_000):
        t[0] = i * 0.002  # 10,000 in 20 s
        skipped = rl.note(RefusalKind.AUTHENTICATION if i % 2 else RefusalKind.MALFORMED, "x")
        if skipped is not None:
            samples.append(skipped)
    assert rl.total == 10_000 and rl.counts()[RefusalKind.AUTHENTICATION] == 5_000
    # one line a second, each saying how many went unlogged before it; the last 499 wait for the next
    assert len(samples) == 20 and samples[0] == 0 and sum(samples) + len(samples) == 10_000 - 499


def test_the_preflight_report_carries_the_clock_verdict() -> None:
    req = Requirements("px4", 20.0, ())
    for probe, verdict in [
        (None, ClockVerdict.NOT_CHECKED),
        (ClockProbe(error="no SYSTEM_TIME"), ClockVerdict.UNKNOWN),
        (ClockProbe(offset_s=0.5), ClockVerdict.AGREES),
        (ClockProbe(offset_s=-30.0), ClockVerdict.OFF),
    ]:
        report = run_checks(req, {}, clock=probe)
        assert report.clock is verdict and verdict.accepts_signed_requests is (verdict is not ClockVerdict.OFF)


def test_beyond_the_request_budget_a_request_is_refused_unread() -> None:
    c = Clocks()
    v, _ = commands(c, max_requests_per_s=20.0)
    forged = sign_command("drone1", CommandKind.LAND, b"not-the-secret-0123456789", issued_unix_s=c.true_now())
    kinds = [refusal(v, forged).kind for _ in range(25)]
    assert kinds == [RefusalKind.AUTHENTICATION] * 20 + [RefusalKind.OVERLOAD] * 5
    c.elapsed = 0.5  # half a second: ten more read
    good = sign_command("drone1", CommandKind.HOLD, SECRET, issued_unix_s=c.true_now())
    assert v.verify(good).kind is CommandKind.HOLD


def test_a_vehicle_clock_reanchored_backwards_keeps_the_nonces_it_left_behind() -> None:
    c = Clocks(wall_offset_s=100.0)  # started 100 s ahead, and so was the sender
    v, vc = commands(c)
    early = sign_command("drone1", CommandKind.HOLD, SECRET, issued_unix_s=c.wall())
    v.verify(early)
    c.elapsed, c.wall_offset_s = 80.0, 0.0  # chrony steps the wall clock right; a check agrees
    assert vc.judge(ClockVerdict.AGREES, 0.0) == pytest.approx(-100.0)
    v.verify(sign_command("drone1", CommandKind.RETURN, SECRET, issued_unix_s=c.true_now(), sender="ops"))
    c.elapsed = 98.0  # early's issued time is fresh again on the corrected clock: its nonce is kept
    assert refusal(v, early).kind is RefusalKind.REPLAY

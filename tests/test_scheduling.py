import asyncio
import errno
import os
import threading

import pytest

from companion import scheduling
from companion.scheduling import LoopClock, RateLoop, restore_thread_policy, set_thread_realtime, thread_policy
from companion_sitl.clock import run_virtual


class FakeClock:
    def __init__(self):
        self.t = 0.0
        self.extra = {}

    def now(self):
        return self.t

    async def sleep_until(self, t):
        self.t = max(self.t, t)


def test_rate_loop_has_no_drift():
    c = FakeClock()
    loop = RateLoop(c, 20.0)

    async def go():
        ts = []
        for _ in range(1000):
            ts.append(await loop.tick())
            c.t += 0.013  # work shorter than a period
        return ts

    ts = asyncio.run(go())
    assert abs(ts[-1] - 1000 * 0.05) < 1e-9 and loop.overruns == 0


def test_rate_loop_counts_overruns_and_skips_missed_ticks():
    c = FakeClock()
    loop = RateLoop(c, 10.0)

    async def go():
        await loop.tick()  # t = 0.1
        c.t += 0.35  # stalled for 3.5 periods
        return await loop.tick()

    t = asyncio.run(go())
    assert loop.overruns >= 2
    assert abs(t / 0.1 - round(t / 0.1)) < 1e-9  # still on the original grid


def test_virtual_time_runs_fast_and_in_order():
    async def go():
        clock = LoopClock()
        order = []

        async def ticker(name, hz, n):
            r = RateLoop(clock, hz)
            for _ in range(n):
                order.append((await r.tick(), name))

        await asyncio.gather(ticker("a", 10, 100), ticker("b", 4, 40))
        return clock.now(), order

    now, order = run_virtual(go())  # 10 s of virtual time, no real waiting
    assert abs(now - 10.0) < 1e-6 and len(order) == 140
    times = [t for t, _ in order]
    assert times == sorted(times)


def test_tick_or_ticks_early_on_the_event_and_keeps_the_schedule():
    async def go():
        clock = LoopClock()
        r = RateLoop(clock, 20.0)  # t0 = 0, deadlines 0.05, 0.10, ...
        ev = asyncio.Event()
        got = []

        async def fire(at_s):
            await asyncio.sleep(at_s - clock.now())
            ev.set()

        asyncio.get_running_loop().create_task(fire(0.062))
        for _ in range(4):
            got.append(await r.tick_or(ev))
        return got, r

    got, r = run_virtual(go())
    times = [round(t, 9) for t, _ in got]
    assert times == [0.05, 0.062, 0.1, 0.15]  # the early tick in between; the grid unchanged
    assert [e for _, e in got] == [False, True, False, False]
    assert r.early_ticks == 1 and r.ticks == 3 and r.overruns == 0


def test_tick_or_with_the_event_set_at_a_deadline_ticks_once():
    """An event already set when the deadline is reached is consumed by that tick (no extra tick)."""
    c = FakeClock()
    r = RateLoop(c, 10.0)

    async def go():
        ev = asyncio.Event()
        c.t = 0.1  # exactly at the first deadline
        ev.set()
        first = await r.tick_or(ev)
        second = await r.tick_or(ev)
        return first, second, ev.is_set()

    first, second, still_set = asyncio.run(go())
    assert first == (0.1, False) and second == (0.2, False) and not still_set
    assert r.early_ticks == 0 and r.ticks == 2


def test_tick_or_counts_overruns_once():
    c = FakeClock()
    r = RateLoop(c, 10.0)

    async def go():
        ev = asyncio.Event()
        await r.tick_or(ev)  # 0.1
        c.t += 0.35  # stalled 3.5 periods
        ev.set()  # the early path must not count the missed ticks, the taken tick counts them once
        t1, early = await r.tick_or(ev)
        t2, _ = await r.tick_or(ev)
        return t1, early, t2

    t1, early, t2 = asyncio.run(go())
    assert not early  # the event came after the (missed) deadline: a periodic tick
    assert r.overruns == 2
    assert abs(t2 - t1 - 0.1) < 1e-9


def _in_thread(fn):
    out: dict = {}

    def run():
        try:
            out["value"] = fn()
        except BaseException as err:  # re-raised on the test's thread
            out["error"] = err

    t = threading.Thread(target=run)
    t.start()
    t.join()
    if "error" in out:
        raise out["error"]
    return out["value"]


def test_a_real_time_thread_preempts_and_its_threads_inherit_then_it_is_restored():
    def go():
        before = thread_policy()
        why = set_thread_realtime(7)
        if why is not None:
            pytest.skip(f"SCHED_RR refused on this machine: {why}")
        during = thread_policy()
        child = _in_thread(thread_policy)  # a thread started now
        restore_thread_policy(before)
        return before, during, child, thread_policy()

    before, during, child, after = _in_thread(go)
    assert (during.policy, during.priority) == (os.SCHED_RR, 7)
    assert (child.policy, child.priority) == (os.SCHED_RR, 7) and child.tid != during.tid
    assert (after.policy, after.priority) == (before.policy, before.priority)
    assert thread_policy().policy == os.SCHED_OTHER  # the test's own thread never changed


def test_a_refused_real_time_policy_says_what_it_needs(monkeypatch):
    def refuse(*_args):
        raise PermissionError(errno.EPERM, "Operation not permitted")

    monkeypatch.setattr(scheduling.os, "sched_setscheduler", refuse)
    why = set_thread_realtime(20)
    assert why is not None and "CAP_SYS_NICE" in why and "RLIMIT_RTPRIO >= 20" in why
    assert thread_policy().policy == os.SCHED_OTHER


@pytest.mark.parametrize("prio", [0, 100, -1])
def test_a_real_time_priority_out_of_range_is_an_error(prio):
    with pytest.raises(ValueError, match=r"expected 1\.\.99"):
        set_thread_realtime(prio)


def test_a_policy_is_restored_only_on_its_own_thread():
    saved = _in_thread(thread_policy)
    with pytest.raises(ValueError, match="restored on thread"):
        restore_thread_policy(saved)


def test_the_loop_thread_is_real_time_only_on_the_wall_clock():
    async def on_the_loop():
        return scheduling.realtime_loop_thread(asyncio.get_running_loop(), 11)

    saved, said = run_virtual(on_the_loop())  # lock-step: runs flat out, must not take the core
    assert (saved, said) == (None, "not applied: virtual time")
    assert scheduling.realtime_loop_thread(None, 0) == (None, "")  # type: ignore[arg-type]

    def on_a_thread():
        saved, said = asyncio.run(on_the_loop())
        during = thread_policy()
        if saved is not None:
            restore_thread_policy(saved)
        return saved, said, during, thread_policy()

    saved, said, during, after = _in_thread(on_a_thread)
    if said.startswith("refused"):
        assert saved is None and "CAP_SYS_NICE" in said
    else:
        assert said == "SCHED_RR 11" and (during.policy, during.priority) == (os.SCHED_RR, 11)
        assert (after.policy, after.priority) == (saved.policy, saved.priority) == (os.SCHED_OTHER, 0)

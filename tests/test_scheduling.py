import asyncio

from companion.scheduling import LoopClock, RateLoop
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

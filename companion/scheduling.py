"""Clocks and fixed-rate loops for the asyncio shell.

Fixed-rate loops use absolute deadlines (t0 + k * period) on an injectable clock, count
overruns and never drift. The clock is the running loop's ``time()``: the real monotonic clock
in flight, the simulated clock under ``companion_sitl.clock.VirtualTimeEventLoop``.
"""

from __future__ import annotations

import asyncio
import contextlib
import math
from typing import Protocol


class Clock(Protocol):
    def now(self) -> float: ...

    async def sleep_until(self, t_s: float) -> None: ...


class LoopClock:
    """The running asyncio loop's clock (monotonic, or virtual in simulation)."""

    def now(self) -> float:
        return asyncio.get_running_loop().time()

    async def sleep_until(self, t_s: float) -> None:
        dt = t_s - self.now()
        await asyncio.sleep(dt if dt > 0 else 0)


class RateLoop:
    """Ticks at ``rate_hz`` on absolute deadlines.

    ``await tick()`` returns the scheduled tick time. When the caller is late by more than a
    period, the missed ticks are skipped (counted in ``overruns``) instead of bursting to catch
    up, and the schedule stays anchored to t0 (no drift).
    """

    def __init__(self, clock: Clock, rate_hz: float, start_s: float | None = None):
        if not (rate_hz > 0 and math.isfinite(rate_hz)):
            raise ValueError(f"rate_hz = {rate_hz}: must be a positive number")
        self.clock = clock
        self.period_s = 1.0 / rate_hz
        self._t0 = clock.now() if start_s is None else start_s
        self._k = 0
        self.overruns = 0
        self.ticks = 0
        self.early_ticks = 0

    def _next_deadline(self) -> tuple[int, float, int]:
        """The next tick's index and deadline, skipping ticks missed by more than a period, and
        how many were skipped (counted in ``overruns`` when the tick is taken)."""
        k = self._k + 1
        deadline = self._t0 + k * self.period_s
        now = self.clock.now()
        missed = 0
        if now > deadline + self.period_s:
            missed = math.floor((now - deadline) / self.period_s)
            k += missed
            deadline = self._t0 + k * self.period_s
        return k, deadline, missed

    async def tick(self) -> float:
        self._k, deadline, missed = self._next_deadline()
        self.overruns += missed
        await self.clock.sleep_until(deadline)
        self.ticks += 1
        return deadline

    async def tick_or(self, event: asyncio.Event) -> tuple[float, bool]:
        """The next tick, or earlier if ``event`` is set first: ``(time, early)``. An early tick
        returns the clock's time and leaves the schedule as it was (the periodic tick still comes
        at its deadline); ``event`` is cleared."""
        k, deadline, missed = self._next_deadline()
        if not event.is_set():
            timeout = deadline - self.clock.now()
            if timeout > 0:
                with contextlib.suppress(TimeoutError):
                    await asyncio.wait_for(event.wait(), timeout)
        if event.is_set():
            event.clear()
            now = self.clock.now()
            if now < deadline:
                self.early_ticks += 1
                return now, True
        self._k = k
        self.overruns += missed
        await self.clock.sleep_until(deadline)
        self.ticks += 1
        return deadline, False

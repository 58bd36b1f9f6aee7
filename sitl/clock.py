"""Virtual time for asyncio: the same async shell code, run in lock-step far faster than real time.

:class:`VirtualTimeEventLoop` is a normal selector event loop whose ``time()`` is a simulated
clock. When every task is waiting on a timer (``asyncio.sleep``, ``wait_for`` timeouts, ...) and
no I/O is ready, the loop jumps its clock to the next timer instead of blocking. Everything that
reads ``loop.time()`` (our :class:`companion.scheduling.LoopClock`, the simulated autopilot's
physics task, timeouts) sees the simulated clock, so a flight of minutes takes seconds and is
deterministic: tasks ready at the same instant run in FIFO order, as in any asyncio loop.

Real I/O still works (the selector is polled without blocking first); if the loop has nothing
scheduled at all it blocks on I/O as usual.
"""

from __future__ import annotations

import asyncio
import selectors
from collections.abc import Coroutine
from typing import Any, TypeVar

T = TypeVar("T")


class _VirtualSelector(selectors.BaseSelector):
    def __init__(self, loop: VirtualTimeEventLoop):
        self._real = selectors.DefaultSelector()
        self._loop = loop

    def register(self, fileobj: Any, events: int, data: Any = None) -> selectors.SelectorKey:
        return self._real.register(fileobj, events, data)

    def unregister(self, fileobj: Any) -> selectors.SelectorKey:
        return self._real.unregister(fileobj)

    def modify(self, fileobj: Any, events: int, data: Any = None) -> selectors.SelectorKey:
        return self._real.modify(fileobj, events, data)

    def get_map(self) -> Any:
        return self._real.get_map()

    def close(self) -> None:
        self._real.close()

    def select(self, timeout: float | None = None) -> list[tuple[selectors.SelectorKey, int]]:
        events = self._real.select(0)
        if events:
            return events
        if timeout is None:
            return self._real.select(None)  # nothing scheduled: wait for real I/O
        if timeout > 0:
            self._loop.advance(timeout)
        return []


class VirtualTimeEventLoop(asyncio.SelectorEventLoop):
    def __init__(self, start_s: float = 0.0) -> None:
        self._virtual_now = float(start_s)
        super().__init__(selector=_VirtualSelector(self))

    def time(self) -> float:
        return self._virtual_now

    def advance(self, dt_s: float) -> None:
        if dt_s > 0:
            self._virtual_now += dt_s


def run_virtual(coro: Coroutine[Any, Any, T], start_s: float = 0.0) -> T:
    """Run ``coro`` to completion on a fresh virtual-time loop (like ``asyncio.run``)."""
    with asyncio.Runner(loop_factory=lambda: VirtualTimeEventLoop(start_s)) as runner:
        return runner.run(coro)

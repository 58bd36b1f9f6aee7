"""The ArduPilot backend's reader thread hands its calls to the event loop in bursts (LoopPoster,
the backend's _post): every call runs on the loop, in the order posted, one raising call does not
stop the others, and calls posted before the loop gets to them share one wake-up."""

from __future__ import annotations

import asyncio
import threading
from typing import Any

import pytest

from companion.autopilot.ardupilot.link import LoopPoster


def _poster(loop: asyncio.AbstractEventLoop) -> LoopPoster:
    p = LoopPoster()
    p.bind(loop)  # what the backend's connect() does; no link is opened here
    return p


def test_posts_run_on_the_loop_in_order_and_share_wakeups(caplog: pytest.LogCaptureFixture) -> None:
    async def main() -> tuple[list[Any], set[int], int]:
        loop = asyncio.get_running_loop()
        poster = _poster(loop)
        seen: list[Any] = []
        threads: set[int] = set()

        def record(x: int) -> None:
            threads.add(threading.get_ident())
            seen.append(x)

        def boom() -> None:
            raise RuntimeError("a bad callback")

        wakeups = 0
        orig = loop.call_soon_threadsafe

        def counting(*args: Any) -> Any:
            nonlocal wakeups
            wakeups += 1
            return orig(*args)

        loop.call_soon_threadsafe = counting  # type: ignore[method-assign]

        def reader() -> None:  # two bursts of 50, the second after the loop has drained the first
            for k in range(50):
                poster.post(record, k)
                if k == 10:
                    poster.post(boom)
            drained.wait(5.0)
            for k in range(50, 100):
                poster.post(record, k)

        drained = threading.Event()
        t = threading.Thread(target=reader)
        t.start()
        while len(seen) < 50:
            await asyncio.sleep(0.001)
        drained.set()
        while len(seen) < 100:
            await asyncio.sleep(0.001)
        await asyncio.to_thread(t.join)
        return seen, threads, wakeups

    seen, threads, wakeups = asyncio.run(main())
    assert seen == list(range(100))
    assert threads == {threading.get_ident()}  # the loop's thread (asyncio.run's), not the reader's
    # at most one wake-up per burst in flight; fewer than the 101 calls posted
    assert 2 <= wakeups < 101
    assert "a bad callback" in caplog.text or "posted from the MAVLink reader" in caplog.text


def test_a_closed_loop_drops_posts_and_a_new_loop_gets_them() -> None:
    loop = asyncio.new_event_loop()
    poster = _poster(loop)
    loop.close()
    poster.post(print, "never")  # the loop is closed: nothing scheduled, nothing kept
    assert poster.pending == 0 and not poster.drain_scheduled

    async def main() -> list[int]:
        poster.bind(asyncio.get_running_loop())
        got: list[int] = []
        poster.post(got.append, 1)
        await asyncio.sleep(0.01)
        return got

    assert asyncio.run(main()) == [1]

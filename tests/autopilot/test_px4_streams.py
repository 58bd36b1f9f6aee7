"""Px4Autopilot's telemetry streams: one that ends or raises is subscribed again, never lost."""

import asyncio
import logging

import pytest

from companion.autopilot.px4 import Px4Autopilot
from companion.autopilot.px4 import telemetry as px4_telemetry


async def test_a_stream_that_raises_or_ends_is_subscribed_again_and_said_once_each_time(monkeypatch, caplog):
    monkeypatch.setattr(px4_telemetry, "STREAM_RESUBSCRIBE_S", 0.01)
    ap = Px4Autopilot("udpin://127.0.0.1:14599")
    got: list[int] = []
    closed: list[int] = []
    subscriptions = 0

    async def stream():
        nonlocal subscriptions
        subscriptions += 1
        n = subscriptions
        try:
            yield 10 * n
            if n == 1:
                raise RuntimeError("native stream broke")
            if n == 2:
                return  # ends
            while True:
                await asyncio.sleep(0.001)
                yield 10 * n + 1
        finally:
            closed.append(n)

    def on_landed(item: int) -> None:
        got.append(item)

    caplog.set_level(logging.WARNING, logger="companion.autopilot.px4")
    task = asyncio.get_running_loop().create_task(ap._consume(stream, on_landed))
    while 31 not in got:
        await asyncio.sleep(0.005)
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert got[:3] == [10, 20, 30] and set(got[3:]) == {31}
    assert ap.streams_restarted == 2 and closed == [1, 2, 3]  # the third closed on cancel, not restarted
    msgs = [r.getMessage() for r in caplog.records]
    assert msgs == [
        "MAVSDK stream on_landed failed (RuntimeError: native stream broke): subscribing again in 0.0 s",
        "MAVSDK stream on_landed ended: subscribing again in 0.0 s",
    ]


async def test_a_sample_that_does_not_decode_is_logged_and_the_stream_goes_on(caplog):
    ap = Px4Autopilot("udpin://127.0.0.1:14599")
    got: list[int] = []

    async def stream():
        for i in range(3):
            yield i
        await asyncio.sleep(3600)

    def on_pos(item: int) -> None:
        if item == 1:
            raise ValueError("bad field")
        got.append(item)

    task = asyncio.get_running_loop().create_task(ap._consume(stream, on_pos))
    while len(got) < 2:
        await asyncio.sleep(0.005)
    task.cancel()
    with pytest.raises(asyncio.CancelledError):
        await task
    assert got == [0, 2] and ap.streams_restarted == 0
    assert any("error decoding on_pos" in r.getMessage() for r in caplog.records)

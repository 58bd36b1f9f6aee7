"""Zenoh payload size and rate against the session limits (``ZenohSettings.max_message_bytes``,
here Zenoh's smallest, 64 KiB): two real sessions on loopback, the sender unbounded; each input
a burst of puts of fuzzed sizes (empty, at the limit, one past it, many times it) and counts (one
to a few hundred back to back), then a marker.

Rule: every payload within the limit reaches the subscriber whole and in order; every one past it
is dropped by Zenoh before Python sees a byte of it; the session lives on (the marker arrives)."""

from __future__ import annotations

import dataclasses
import threading
import time
from typing import Any

import pytest
import zenoh
from hypothesis import strategies as st

from companion.telemetry.loopback import free_tcp_port, loopback_settings

from . import harness

pytestmark = pytest.mark.fuzz

SURFACE = "zenoh payload size and rate"
LIMIT = 64 * 1024
KEY = "companion/fuzz/limits"
#: what a sample carries besides its payload bytes (attachment and framing are Zenoh's, not ours):
#: a payload this close to the limit may go either way, so none is drawn there
MARGIN = 256
_SIZES = st.one_of(
    st.integers(0, LIMIT - MARGIN),
    st.sampled_from([0, 1, LIMIT - MARGIN, LIMIT + 1, 2 * LIMIT, 16 * LIMIT]),
    st.integers(LIMIT + MARGIN, 8 * LIMIT),
)
BURSTS = st.lists(st.tuples(_SIZES, st.integers(1, 50)), min_size=1, max_size=4)


def _payload(n: int, size: int) -> bytes:
    head = n.to_bytes(4, "big")
    return (head * (size // 4 + 1))[:size] if size >= 4 else b"\xff" * size


class _Pair:
    def __init__(self) -> None:
        port = free_tcp_port()
        self.vehicle = dataclasses.replace(loopback_settings(listen_port=port), max_message_bytes=LIMIT).open()
        self.sender = dataclasses.replace(loopback_settings(connect_port=port), max_message_bytes=1 << 30).open()
        self.got: list[bytes] = []
        self.cond = threading.Condition()
        self.sub = self.vehicle.declare_subscriber(KEY, self._on)
        self.pub = self.sender.declare_publisher(KEY, congestion_control=zenoh.CongestionControl.BLOCK)
        self.n = 0
        deadline = time.monotonic() + 10.0
        while not self._marker(1.0):
            assert time.monotonic() < deadline, "the two sessions never met"

    def _on(self, sample: Any) -> None:
        with self.cond:
            self.got.append(sample.payload.to_bytes())
            self.cond.notify_all()

    def _marker(self, timeout_s: float) -> bool:
        self.n += 1
        mark = b"marker %d" % self.n
        self.pub.put(mark)
        with self.cond:
            return self.cond.wait_for(lambda: mark in self.got, timeout_s)

    def burst(self, bursts: list[tuple[int, int]]) -> str:
        with self.cond:
            self.got.clear()
        sent: list[bytes] = []
        for size, count in bursts:
            for _ in range(count):
                self.n += 1
                p = _payload(self.n, size)
                sent.append(p)
                self.pub.put(p)
        assert self._marker(10.0), "the session did not live on: the marker never came"
        with self.cond:
            got = [g for g in self.got if not g.startswith(b"marker ")]
        want = [p for p in sent if len(p) <= LIMIT]
        assert not [g for g in got if len(g) > LIMIT], "a payload over the limit reached Python"
        assert got == want, f"{len(want)} payloads within the limit sent, {len(got)} arrived (or not whole)"
        return "some dropped by Zenoh" if len(want) < len(sent) else "all delivered"

    def close(self) -> None:
        self.sub.undeclare()
        self.pub.undeclare()
        self.sender.close()
        self.vehicle.close()


def test_payload_sizes_and_rates(fuzz_budget: int) -> None:
    pair = _Pair()
    try:
        for bursts in ([(LIMIT - MARGIN, 1), (LIMIT + 1, 1), (1, 1)], [(16 * LIMIT, 3), (10, 300)], [(0, 5)]):
            harness.check(SURFACE, pair.burst, bursts, ())
        harness.run(BURSTS, lambda b: harness.check(SURFACE, pair.burst, b, ()), fuzz_budget)
    finally:
        pair.close()
    c = harness.COUNTS[SURFACE]
    assert c.outcomes["some dropped by Zenoh"] and c.outcomes["all delivered"], c.outcomes

"""MAVLink bytes into the ArduPilot backend's receive path: the reader thread's loop
(``ArduPilotLink._read_loop``: pymavlink's parser, then the telemetry decoder) over a port that
hands out the fuzzed bytes.

Rule: malformed bytes are counted (``bad_data`` / ``signature_rejects``; a read error in
``read_errors``, a message the decoder cannot take in ``decode_errors``), never raised; every
BAD_DATA pymavlink reports is counted."""

from __future__ import annotations

import pytest

from companion.autopilot.ardupilot.autopilot import ArduPilotAutopilot
from companion.autopilot.ardupilot.dialect import mavlink, mavutil

from . import harness
from .mavlink_corpus import from_autopilot

pytestmark = pytest.mark.fuzz

SEEDS = from_autopilot()


class _Done(Exception):
    pass


class _BytesPort(mavutil.mavfile):  # type: ignore[misc]
    """A pymavlink port whose reads return ``data``; once it is read, the link's loop stops."""

    def __init__(self, data: bytes, link: ArduPilotAutopilot) -> None:
        self.data = bytearray(data)
        self.link = link
        mavutil.mavfile.__init__(self, None, "fuzz", source_system=255, source_component=191)
        self.mav.robust_parsing = True

    def recv(self, n: int | None = None) -> bytes:
        k = max(1, n or 1)
        chunk = bytes(self.data[:k])
        del self.data[:k]
        return chunk

    def select(self, timeout: float) -> bool:
        if not self.data:
            self.link._running = False
            raise _Done
        return True

    def write(self, buf: bytes) -> None:
        pass


def _expected_bad(data: bytes) -> tuple[int, int]:
    """BAD_DATA reports (other than signatures) and messages pymavlink's parser gives for
    ``data`` read as pymavlink's ``recv_msg`` reads a port (``bytes_needed`` at a time)."""
    mav = mavlink.MAVLink(None)
    mav.robust_parsing = True
    bad = msgs = 0
    rest = data
    while True:
        chunk, rest = rest[: max(1, mav.bytes_needed())], rest[max(1, mav.bytes_needed()) :]
        m = mav.parse_char(chunk)
        if m is None:
            if not chunk:
                return bad, msgs
            continue
        if m.get_type() == "BAD_DATA":
            bad += getattr(m, "reason", "") != "Invalid signature"
        else:
            msgs += 1


def feed(data: bytes) -> str:
    ap = ArduPilotAutopilot("udpin:127.0.0.1:14550")
    ap._conn = _BytesPort(data, ap)
    ap._running = True
    ap._read_loop()
    c = ap.counters
    assert c.read_errors == 1, f"read errors {c.read_errors - 1} beyond the end of the input"
    assert c.decode_errors == 0, "the decoder raised on a message pymavlink accepted"
    bad, msgs = _expected_bad(data)
    assert c.bad_data == bad, f"{bad} malformed packets, {c.bad_data} counted"
    assert c.messages + c.heartbeats <= msgs
    return "messages" if c.messages + c.heartbeats else ("bad data (counted)" if c.bad_data else "no packet yet")


def test_mavlink_bytes_into_the_ardupilot_backend(fuzz_budget) -> None:
    for data in SEEDS:
        harness.check("mavlink -> ardupilot backend", feed, data, ())
    harness.run(
        harness.fuzz_bytes(SEEDS, max_random=1024),
        lambda d: harness.check("mavlink -> ardupilot backend", feed, d, ()),
        fuzz_budget,
    )

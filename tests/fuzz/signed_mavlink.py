"""Signed MAVLink 2 bytes for the fuzz modules of the signed ArduPilot link and the GCS component:
packets signed with our key, with another key, unsigned, replayed (the same signed packet twice,
or a timestamp older than the stream's), and a new stream more than 60 s behind our timestamp;
a port that hands bytes to the backend's reader loop; and a twin parser that says what
pymavlink, signing as the link does, lets through."""

from __future__ import annotations

import hashlib
from typing import Any

from companion.autopilot.ardupilot.autopilot import ArduPilotAutopilot
from companion.autopilot.ardupilot.dialect import mavlink, mavutil
from companion.autopilot.signing import SigningKey, SigningSetup, apply_to_mavlink

KEY = SigningKey(hashlib.sha256(b"fuzz: our key").digest(), "<fuzz key>")
OTHER_KEY = SigningKey(hashlib.sha256(b"fuzz: somebody else's key").digest(), "<other key>")
T0 = 400_000_000_000  # our signing timestamp at the start (2027-ish, 10 us units since 2015)


def packer(system: int, component: int, key: SigningKey | None, timestamp: int, link_id: int = 1) -> Any:
    """A MAVLink encoder for (system, component) that signs with ``key`` from ``timestamp`` on."""
    mav = mavlink.MAVLink(None, srcSystem=system, srcComponent=component)
    if key is not None:
        mav.signing.secret_key = key.secret
        mav.signing.link_id = link_id
        mav.signing.sign_outgoing = True
        mav.signing.timestamp = timestamp
    return mav


def pack(mav: Any, msgs: list[Any]) -> bytes:
    return b"".join(m.pack(mav) for m in msgs)


def signed_packets(seeds: list[bytes]) -> list[bytes]:
    """Every packet in ``seeds`` whose signature is :data:`KEY`'s, whatever its timestamp (the
    only bytes a message verified with our key may come from)."""
    out = []
    for data in seeds:
        mav = mavlink.MAVLink(None)
        mav.robust_parsing = True
        for m in mav.parse_buffer(data) or []:
            buf = bytes(m.get_msgbuf()) if m.get_type() != "BAD_DATA" else b""
            signed = len(buf) > 13 and buf[0] == 0xFD and buf[2] & 0x01
            if signed and hashlib.sha256(KEY.secret + buf[:-6]).digest()[:6] == buf[-6:]:
                out.append(buf)
    return out


class Done(Exception):
    pass


class BytesPort(mavutil.mavfile):  # type: ignore[misc]
    """A pymavlink port whose reads return ``data``; once it is read, the link's loop stops. It
    signs and checks as the link's own port does (``apply_to_mavlink`` from :data:`T0`)."""

    def __init__(self, data: bytes, link: ArduPilotAutopilot, setup: SigningSetup | None) -> None:
        self.data = bytearray(data)
        self.link = link
        mavutil.mavfile.__init__(self, None, "fuzz", source_system=255, source_component=191)
        self.mav.robust_parsing = True
        if setup is not None:
            apply_to_mavlink(self.mav, setup, T0)
        self.sent: list[bytes] = []

    def recv(self, n: int | None = None) -> bytes:
        k = max(1, n or 1)
        chunk = bytes(self.data[:k])
        del self.data[:k]
        return chunk

    def select(self, timeout: float) -> bool:
        if not self.data:
            self.link._running = False
            raise Done
        return True

    def write(self, buf: bytes) -> None:
        self.sent.append(bytes(buf))


def twin_parse(data: bytes, setup: SigningSetup | None) -> list[Any]:
    """The messages (BAD_DATA included) pymavlink gives for ``data`` read as the link reads its
    port (``bytes_needed`` at a time), signing as the link does. The link's own packets move its
    timestamp on by one each, far less than any window a seed is built to test."""
    mav = mavlink.MAVLink(None)
    mav.robust_parsing = True
    if setup is not None:
        apply_to_mavlink(mav, setup, T0)
    out: list[Any] = []
    rest = data
    while True:
        k = max(1, mav.bytes_needed())
        chunk, rest = rest[:k], rest[k:]
        m = mav.parse_char(chunk)
        if m is None:
            if not chunk:
                return out
            continue
        out.append(m)


def read_through(ap: ArduPilotAutopilot, data: bytes, setup: SigningSetup | None) -> BytesPort:
    """Run the backend's reader loop (in this thread) over ``data``."""
    port = BytesPort(data, ap, setup)
    ap._conn = port
    ap._running = True
    errors = ap.counters.read_errors
    ap._read_loop()
    assert ap.counters.read_errors == errors + 1, "a read error beyond the end of the input"
    assert ap.counters.decode_errors == 0, "the decoder raised on a message pymavlink accepted"
    return port

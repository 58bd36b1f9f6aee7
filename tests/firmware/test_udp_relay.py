"""The link-cutting UDP relay used by the real-firmware link-loss test."""

from __future__ import annotations

import socket
import time

from companion_firmware.udp_relay import UdpRelay


def _sock() -> socket.socket:
    s = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    s.bind(("127.0.0.1", 0))
    s.settimeout(1.0)
    return s


def test_relay_forwards_both_ways_and_drops_everything_while_cut():
    autopilot, companion = _sock(), _sock()
    listen = _sock()
    port = listen.getsockname()[1]
    listen.close()
    with UdpRelay(port, companion.getsockname()[1]) as relay:
        autopilot.sendto(b"hb1", ("127.0.0.1", port))
        data, back = companion.recvfrom(100)
        assert data == b"hb1"
        companion.sendto(b"sp1", back)  # the reply goes to wherever the autopilot sent from
        assert autopilot.recvfrom(100)[0] == b"sp1"
        relay.cut(0.3)
        assert relay.is_cut
        autopilot.sendto(b"lost", ("127.0.0.1", port))
        companion.sendto(b"lost too", back)
        time.sleep(0.1)
        assert relay.dropped == 2
        time.sleep(0.3)
        autopilot.sendto(b"hb2", ("127.0.0.1", port))
        assert companion.recvfrom(100)[0] == b"hb2"  # nothing of the outage arrives late
        deadline = time.monotonic() + 1.0  # the relay thread counts just after its send returns
        while relay.forwarded < 3 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert relay.forwarded == 3
    autopilot.close()
    companion.close()

"""MAVLink datagrams into the MAVLink sim vehicle's receive path (``MavlinkLink._parse``, as its
thread calls it per datagram), both dialects.

Rule: a datagram's malformed bytes are counted (``bad_data``, ``garbage_bytes``,
``signature_rejects``), accepted messages counted by type, and handling one never raises
(``handle_errors`` stays 0); the vehicle's clock stays on the wall clock (no hang)."""

from __future__ import annotations

import socket
import time

import pytest

from companion.config import shipped_params_path
from companion_sitl.mavlink.factory import mavlink_sim_vehicle
from companion_sitl.params import load_simulated_config

from . import harness
from .mavlink_corpus import from_ground

pytestmark = pytest.mark.fuzz

SEEDS = from_ground()


@pytest.mark.parametrize("dialect", ["px4", "ardupilot"])
def test_mavlink_datagrams_into_the_sim_vehicle(dialect, fuzz_budget) -> None:
    cfg = load_simulated_config(shipped_params_path("sitl_short.toml")).sim
    sim = mavlink_sim_vehicle(cfg, dialect, params={"ardupilot": {"GRIP_ENABLE": 1.0}, "px4": {}}[dialect])
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    sock.bind(("127.0.0.1", 0))
    sim._sock = sock  # replies are encoded, sent nowhere (no peer)
    sim._t0 = time.monotonic() - sim.vehicle.time_s
    surface = f"mavlink -> sim vehicle ({dialect})"

    def feed(data: bytes) -> str:
        s = sim.stats
        before = (s.messages_in, s.bad_data, s.signature_rejects, s.handle_errors, sum(s.by_type_in.values()))
        sim._parse(data)
        after = (s.messages_in, s.bad_data, s.signature_rejects, s.handle_errors, sum(s.by_type_in.values()))
        d_msgs, d_bad, d_sig, d_err, d_types = (a - b for a, b in zip(after, before, strict=True))
        assert d_err == 0, "handling an accepted message raised"
        assert d_msgs == d_types
        assert sim._rx.buf_len() == 0, "bytes left in the parser after a datagram"
        return "messages" if d_msgs else ("dropped (counted)" if d_bad + d_sig else "own echo / empty")

    try:
        for data in SEEDS:
            harness.check(surface, feed, data, ())
        harness.run(
            harness.fuzz_bytes(SEEDS, max_random=1024), lambda d: harness.check(surface, feed, d, ()), fuzz_budget
        )
    finally:
        sock.close()

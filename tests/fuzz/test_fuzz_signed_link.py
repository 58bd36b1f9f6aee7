"""Signed MAVLink 2 bytes into the ArduPilot backend's reader: the vehicle's streams signed with
our key, with another key, unsigned, replayed (a timestamp that does not grow), a new stream more
than 60 s behind our timestamp, the radios' unsigned RADIO_STATUS; on a link that refuses
unsigned packets and on one that lets them through.

Rule: every packet pymavlink refuses for its signature is counted in ``signature_rejects``,
every other malformed one in ``bad_data``; the vehicle's messages the backend takes in are
exactly those let through; where unsigned packets are refused, nothing our key did not sign
reaches the backend's telemetry except RADIO_STATUS / RADIO (as on ArduPilot)."""

from __future__ import annotations

import math
from typing import Any

import pytest
from hypothesis import strategies as st

from companion.autopilot.ardupilot.autopilot import ArduPilotAutopilot
from companion.autopilot.ardupilot.dialect import mavlink
from companion.autopilot.signing import ACCEPT_UNSIGNED_IDS, SigningSetup

from . import harness
from .mavlink_corpus import nasty
from .signed_mavlink import KEY, OTHER_KEY, T0, pack, packer, read_through, signed_packets, twin_parse

pytestmark = pytest.mark.fuzz

SETUPS = {
    "unsigned refused": SigningSetup(KEY, allow_unsigned=False),
    "unsigned let through": SigningSetup(KEY, allow_unsigned=True),
}
S = 100_000  # signing timestamp units per second
SURFACE = "signed mavlink -> ardupilot backend"


def _stream() -> list[Any]:
    return [
        mavlink.MAVLink_heartbeat_message(
            mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 209, 5, mavlink.MAV_STATE_ACTIVE, 3
        ),
        mavlink.MAVLink_attitude_message(1000, 0.01, -0.02, 1.2, 0.0, 0.0, 0.1),
        mavlink.MAVLink_local_position_ned_message(1000, 1.0, 2.0, -10.0, 0.1, 0.2, -0.3),
        mavlink.MAVLink_sys_status_message(0x10000000, 0x10000000, 0x10000000, 10, 12000, -1, 76, 0, 0, 0, 0, 0, 0),
        mavlink.MAVLink_statustext_message(6, b"Takeoff detected"),
        mavlink.MAVLink_attitude_message(1000, math.nan, math.inf, -math.inf, 0.0, 0.0, 0.0),
    ]


def _seeds() -> list[bytes]:
    msgs = _stream()
    radio = mavlink.MAVLink_radio_status_message(200, 190, 80, 20, 10, 0, 0)
    good = pack(packer(1, 1, KEY, T0 + 10 * S), msgs)
    return [
        good,
        pack(packer(1, 1, OTHER_KEY, T0 + 10 * S), msgs),
        pack(packer(1, 1, None, 0), msgs),
        good + good,  # replayed as a whole
        pack(packer(1, 1, KEY, T0 + 20 * S), msgs[:2]) + pack(packer(1, 1, KEY, T0 + 19 * S), msgs[2:]),
        pack(packer(1, 1, KEY, T0 - 61 * S), msgs),  # a new stream more than 60 s behind ours
        pack(packer(1, 1, KEY, T0 - 59 * S), msgs),  # within the minute: accepted
        pack(packer(1, 1, KEY, T0 + 30 * S, link_id=0), msgs[:3]) + pack(packer(1, 1, KEY, T0 + 5 * S), msgs[3:]),
        pack(packer(1, 1, None, 0), [radio, msgs[1]]) + pack(packer(1, 1, OTHER_KEY, T0), [radio]),
        pack(packer(1, 1, KEY, (1 << 48) - 2), msgs[:3]),  # the largest timestamps there are
        pack(packer(2, 1, KEY, T0 + 40 * S), msgs[:2]) + pack(packer(1, 1, KEY, T0 + 41 * S), msgs[:2]),
        *nasty(good),
    ]


SEEDS = _seeds()
OURS = set(signed_packets(SEEDS))


def feed(case: tuple[str, bytes]) -> str:
    name, data = case
    setup = SETUPS[name]
    ap = ArduPilotAutopilot("udpin:127.0.0.1:14550", target_system=1, signing=setup)
    read_through(ap, data, setup)
    got = twin_parse(data, setup)
    bad = [m for m in got if m.get_type() == "BAD_DATA"]
    sig = sum(getattr(m, "reason", "") == "Invalid signature" for m in bad)
    c = ap.counters
    assert c.signature_rejects == sig, f"{sig} packets refused for their signature, {c.signature_rejects} counted"
    assert c.bad_data == len(bad) - sig, f"{len(bad) - sig} malformed packets, {c.bad_data} counted"
    vehicle = [m for m in got if m.get_type() not in ("BAD_DATA", "COMMAND_LONG") and m.get_srcSystem() == 1]
    hb = [m for m in vehicle if m.get_type() == "HEARTBEAT"]
    assert c.messages == len(vehicle) - len(hb), f"{len(vehicle) - len(hb)} vehicle messages, {c.messages} taken"
    assert c.heartbeats <= len(hb)
    if not setup.allow_unsigned:
        forged = [m for m in vehicle if bytes(m.get_msgbuf()) not in OURS and m.get_msgId() not in ACCEPT_UNSIGNED_IDS]
        assert not forged, f"took in a message our key did not sign: {forged[0]}"
        assert c.signed_from_vehicle == sum(bool(m.get_signed()) for m in vehicle)
    if sig:
        return "signature refused (counted)"
    return "messages" if c.messages + c.heartbeats else ("bad data (counted)" if c.bad_data else "no packet yet")


def test_signed_bytes_into_the_ardupilot_backend(fuzz_budget: int) -> None:
    assert feed(("unsigned refused", SEEDS[0])) == "messages"  # our key's stream is heard
    assert feed(("unsigned refused", SEEDS[1])) == "signature refused (counted)"  # another key's is not
    for name in SETUPS:
        for data in SEEDS:
            harness.check(SURFACE, feed, (name, data), ())
    harness.run(
        st.tuples(st.sampled_from(list(SETUPS)), harness.fuzz_bytes(SEEDS, max_random=256)),
        lambda case: harness.check(SURFACE, feed, case, ()),
        fuzz_budget,
    )
    c = harness.COUNTS[SURFACE]
    assert c.outcomes["signature refused (counted)"] and c.outcomes["messages"], c.outcomes

"""COMMAND_LONGs from the operator's GCS into the companion's own MAVLink component: bytes through
the ArduPilot backend's reader (signing off, signing that refuses unsigned packets, signing that
lets them through), the component (``GcsComponent``, ``[gcs] command_system_ids``) and a real
mission flying its outbound leg.

Rule: every COMMAND_LONG addressed to our component that pymavlink lets through is either refused
(from a system not allowed, or unsigned / not verified by our key on a signed link: counted in
``refused``, never answered, the mission's phase and summary as they were) or answered with one
COMMAND_ACK (only then may the mission act); nothing else reaches the mission, and nothing that
our key did not sign is acted on where the link signs."""

from __future__ import annotations

import asyncio
import copy
import math
from typing import Any

import pytest
from hypothesis import strategies as st

from companion.autopilot.ardupilot.autopilot import ArduPilotAutopilot
from companion.autopilot.ardupilot.dialect import mavlink
from companion.autopilot.signing import SigningSetup
from companion.config import CompanionConfig, GcsConfig
from companion.delivery.gcs import GcsComponent
from companion.delivery.mission import CommandReply, DeliveryMission
from companion.events import CommandKind, Phase

from . import harness
from .signed_mavlink import KEY, OTHER_KEY, T0, pack, packer, read_through, signed_packets, twin_parse

pytestmark = pytest.mark.fuzz

SETUPS: dict[str, SigningSetup | None] = {
    "unsigned link": None,
    "signed, unsigned refused": SigningSetup(KEY, allow_unsigned=False),
    "signed, unsigned let through": SigningSetup(KEY, allow_unsigned=True),
}
US = (1, 191)  # the vehicle's system id and our component id
S = 100_000  # signing timestamp units per second


def _cmd(command: int, p1: float = 0.0, target: tuple[int, int] = US, p7: float = 0.0) -> Any:
    return mavlink.MAVLink_command_long_message(target[0], target[1], command, 0, p1, 0, 0, 0, 0, 0, p7)


def _seeds() -> list[bytes]:
    hold, ret, land = _cmd(17), _cmd(20), _cmd(21)
    gcs = packer(255, 190, KEY, T0 + 10 * S)
    good = pack(gcs, [hold])
    vehicle_hb = mavlink.MAVLink_heartbeat_message(
        mavlink.MAV_TYPE_QUADROTOR, mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 209, 5, mavlink.MAV_STATE_ACTIVE, 3
    )
    v1 = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    v1.WIRE_PROTOCOL_VERSION = "1.0"
    return [
        good,
        pack(packer(255, 190, KEY, T0 + 20 * S), [ret, land]),
        pack(packer(255, 190, KEY, T0 + 30 * S), [_cmd(193, 0.0), _cmd(193, 1.0), _cmd(400), _cmd(17, math.nan)]),
        pack(packer(255, 190, KEY, T0 + 40 * S), [_cmd(20, target=(1, 1)), _cmd(21, target=(2, 191))]),
        pack(packer(255, 190, None, 0), [ret]),  # unsigned, from the allowed system
        pack(packer(255, 190, OTHER_KEY, T0 + 50 * S), [land]),  # another key
        pack(packer(66, 190, KEY, T0 + 60 * S), [ret]),  # our key, but a system not allowed
        good + good,  # replayed: the same timestamp twice
        pack(packer(255, 190, KEY, T0 + 70 * S), [hold]) + pack(packer(255, 190, KEY, T0 + 69 * S), [land]),
        pack(packer(255, 190, KEY, T0 - 61 * S), [ret]),  # a new stream more than 60 s behind ours
        pack(packer(255, 190, KEY, T0 + 80 * S, link_id=7), [land, _cmd(20, math.inf, p7=-math.inf)]),
        pack(packer(1, 1, KEY, T0 + 5 * S), [vehicle_hb]) + pack(packer(255, 190, KEY, T0 + 90 * S), [ret]),
        _cmd(21).pack(v1),  # MAVLink 1: cannot be signed
        # a forged packet with a far timestamp, then the real one: pymavlink sets the stream's
        # timestamp before it checks the signature, so the real command is then refused too
        pack(packer(255, 190, OTHER_KEY, T0 + 900 * S), [hold]) + pack(packer(255, 190, KEY, T0 + 95 * S), [ret]),
    ]


SEEDS = _seeds()
OURS = set(signed_packets(SEEDS))


def _kind(m: Any) -> CommandKind | None:
    c, p1 = int(m.command), m.param1
    table = {17: CommandKind.HOLD, 20: CommandKind.RETURN, 21: CommandKind.LAND}
    return table.get(c) or (CommandKind.HOLD if c == 193 and p1 == 0 else None)


async def _through_component(setup_name: str, data: bytes) -> str:
    setup = SETUPS[setup_name]
    ap = ArduPilotAutopilot("udpin:127.0.0.1:14550", target_system=1, signing=setup)
    ap.attach_loop(asyncio.get_running_loop())
    mission = DeliveryMission(CompanionConfig().mission)
    mission.phase = Phase.OUTBOUND
    calls: list[CommandKind] = []

    def command(kind: CommandKind, sender: str) -> CommandReply:
        calls.append(kind)
        return mission.command(0.0, kind, sender)

    port = read_through(ap, b"", setup)  # connected: open_component needs the port
    comp = GcsComponent(GcsConfig(status_rate_hz=10.0), ap, command)
    assert comp.open() and comp.ids == US
    before = (mission.phase, copy.deepcopy(mission.summary))
    try:
        port = read_through(ap, data, setup)
        await asyncio.sleep(0)  # the reader's posted calls run on the loop
    finally:
        await comp.close()
    ours = [m for m in twin_parse(data, setup) if m.get_type() == "COMMAND_LONG"]
    ours = [m for m in ours if (m.target_system, m.target_component) == US]
    allowed = [m for m in ours if m.get_srcSystem() == 255 and (setup is None or m.get_signed())]
    assert ap.component_commands == len(ours), f"{len(ours)} COMMAND_LONGs for us, {ap.component_commands} seen"
    assert comp.refused == len(ours) - len(allowed), f"{len(ours) - len(allowed)} to refuse, {comp.refused} counted"
    assert len(comp.commands) == len(allowed), "an allowed command not answered"
    acks = [m for m in twin_parse(b"".join(port.sent), None) if m.get_type() == "COMMAND_ACK"]
    assert len(acks) == len(allowed), f"{len(acks)} COMMAND_ACKs for {len(allowed)} allowed commands"
    assert calls == [k for k in map(_kind, allowed) if k], f"the mission got {calls}"
    if setup is not None:
        forged = [m for m in allowed if bytes(m.get_msgbuf()) not in OURS]
        assert not forged, f"acted on a command our key did not sign: {forged[0]}"
    if not calls:
        assert (mission.phase, mission.summary) == before, "a refused command changed the mission"
        return "refused (counted)" if comp.refused else ("answered, mission unchanged" if allowed else "none for us")
    return "answered, mission acted"


def test_gcs_commands_into_the_component(fuzz_budget: int) -> None:
    loop = asyncio.new_event_loop()

    def feed(case: tuple[str, bytes]) -> str:
        return loop.run_until_complete(_through_component(*case))

    try:
        for name in SETUPS:
            for data in SEEDS:
                harness.check("gcs COMMAND_LONG -> component", feed, (name, data), ())
        harness.run(
            st.tuples(st.sampled_from(list(SETUPS)), harness.fuzz_bytes(SEEDS, max_random=256)),
            lambda case: harness.check("gcs COMMAND_LONG -> component", feed, case, ()),
            fuzz_budget,
        )
    finally:
        loop.close()
    c = harness.COUNTS["gcs COMMAND_LONG -> component"]
    assert c.outcomes["refused (counted)"] and c.outcomes["answered, mission acted"], c.outcomes

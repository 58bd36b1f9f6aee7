"""MAVLink 2 signing against a real ArduCopter SITL build (GCS_Signing.cpp).

The companion's link is SERIAL2 (udpclient to us: MAVLink channel 2). Older ArduPilot trusted
channel 0 (USB; TCP 5760 in SITL) and took unsigned packets there even when signing was on; 4.7
SITL does not (tested below). Over SERIAL2 the key is pushed with SETUP_SIGNING while the
vehicle does not sign yet, then: an unsigned companion is ignored, a wrong key is refused, the
signed companion arms, takes off, flies GUIDED velocity and lands; SERIAL0 refuses unsigned too.
Every SITL start has a fresh eeprom.bin, so no key survives the module.
"""

from __future__ import annotations

import asyncio
import hashlib

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.interface import CommandRejected
from companion.autopilot.signing import SigningError, SigningKey, SigningSetup
from companion.autopilot.types import FlightMode, LandedState
from companion.guidance.setpoint import VelocitySetpoint
from companion_firmware.ardupilot_sitl import ArduCopterSitl

from .conftest import free_udp_port, wait_for

pytestmark = pytest.mark.firmware

KEY = SigningKey(hashlib.sha256(b"companion sitl signing test").digest(), "<test>")
OTHER = SigningKey(hashlib.sha256(b"not the vehicle's key").digest(), "<other>")
FEW_STREAMS = {30: 10.0, 33: 10.0, 1: 2.0, 245: 2.0}  # ATTITUDE, GLOBAL_POSITION_INT, SYS_STATUS, EXT_SYS_STATE


@pytest.fixture(scope="module")
def signing_copter(ardupilot_root, tmp_path_factory):
    """SITL with SERIAL2 sending to a UDP port of ours; the key pushed over that link."""
    port = free_udp_port()
    log_dir = tmp_path_factory.mktemp("arducopter-signing")
    sitl = ArduCopterSitl(
        ardupilot_root, serials={2: f"udpclient:127.0.0.1:{port}"}, log_path=log_dir / "arducopter.log"
    )
    with sitl:

        async def push() -> None:
            ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{port}", stream_rates_hz={})
            await ap.connect(timeout_s=15.0)
            try:
                await ap.push_signing_key(KEY, timeout_s=6.0)  # waits for a heartbeat signed with KEY
            finally:
                await ap.close()

        asyncio.run(push())
        yield sitl, f"udpin:127.0.0.1:{port}"


async def test_unsigned_and_wrong_key_companions_are_ignored(signing_copter):
    _sitl, link = signing_copter
    ap = ArduPilotAutopilot(link, stream_rates_hz=FEW_STREAMS, link_timeout_s=3.0)
    await ap.connect(timeout_s=10.0)  # its signed heartbeats reach an unsigned parser...
    try:
        assert ap._vehicle_signs
        with pytest.raises(CommandRejected, match=r"signs its packets .* ignores our unsigned"):
            await ap.arm()  # ...but our unsigned commands are dropped
    finally:
        await ap.close()
    ap = ArduPilotAutopilot(link, signing=SigningSetup(OTHER, link_id=2))
    with pytest.raises(SigningError, match=r"signing refused \d+ packets"):
        await ap.connect(timeout_s=4.0)


async def test_signed_companion_arms_takes_off_flies_guided_velocity_and_lands(signing_copter):
    _sitl, link = signing_copter
    ap = ArduPilotAutopilot(link, arm_timeout_s=90.0, signing=SigningSetup(KEY, link_id=2))
    await ap.connect(timeout_s=10.0)
    try:
        await ap.arm()  # GUIDED; refused until EKF3 uses GPS, retried
        await ap.takeoff(4.0)
        await wait_for(
            lambda: ap.telemetry.global_position is not None and ap.telemetry.global_position.alt_rel_m > 3.7,
            20.0,
            "take off to 4 m",
        )
        await ap.start_offboard()
        for _ in range(40):  # 2 s east at 2 m/s
            ap.set_velocity_ned(VelocitySetpoint(0.0, 2.0, 0.0, 0.0))
            await asyncio.sleep(0.05)
        assert ap.mode is FlightMode.OFFBOARD
        pos = ap.telemetry.position_ned
        assert pos is not None and pos.east_m_s > 1.0, pos
        await ap.land()
        await wait_for(
            lambda: (st := ap.telemetry.status) is not None and st.landed is LandedState.ON_GROUND and not st.armed,
            40.0,
            "landed and disarmed",
        )
        # every heartbeat we took was signed with the key; nothing of the vehicle's failed our check
        assert ap.counters.signed_heartbeats == ap.counters.heartbeats > 10
        assert ap.counters.signature_rejects == 0
    finally:
        await ap.close()


async def test_serial0_refuses_unsigned_too(signing_copter):
    """ArduCopter 4.7 SITL: with a key set, SERIAL0 (TCP 5760, MAVLink channel 0) drops unsigned
    packets like every other link (older GCS_Signing.cpp trusted channel 0 always). Turning
    signing off again with the zero key is not tested (docs/signing.md)."""
    sitl, _link = signing_copter
    ap0 = ArduPilotAutopilot(sitl.connection, stream_rates_hz={})  # SERIAL0 = channel 0, unsigned
    await ap0.connect(timeout_s=10.0)  # its heartbeats (signed) still parse
    try:
        assert await ap0.read_param("SYSID_THISMAV", timeout_s=1.0, tries=2) is None  # refused unsigned
    finally:
        await ap0.close()

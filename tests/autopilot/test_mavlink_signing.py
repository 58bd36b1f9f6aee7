"""MAVLink 2 signing between the ArduPilot backend and the signing sim vehicle (real time, loopback)."""

from __future__ import annotations

import asyncio
import hashlib
import os
from typing import Any

import pytest

from companion.autopilot import AutopilotError, FlightMode
from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.interface import CommandRejected
from companion.autopilot.signing import (
    TIMESTAMP_UNITS_PER_S,
    SigningError,
    SigningKey,
    SigningSetup,
    clock_timestamp,
    read_timestamp_file,
    setup_signing_message,
)
from companion.guidance.setpoint import VelocitySetpoint

KEY = SigningKey(hashlib.sha256(b"companion test key").digest(), "<test>")
OTHER = SigningKey(hashlib.sha256(b"another key").digest(), "<other>")
FEW_STREAMS = {30: 20.0, 33: 10.0}  # ATTITUDE, GLOBAL_POSITION_INT: a short connect
# a vehicle that ignores us streams nothing but its 1 Hz heartbeat: a link timeout above that
IGNORED: dict[str, Any] = {"stream_rates_hz": FEW_STREAMS, "link_timeout_s": 3.0}


def _ap(port: int, setup: SigningSetup | None = None, **kwargs: Any) -> ArduPilotAutopilot:
    return ArduPilotAutopilot(f"udpin:127.0.0.1:{port}", signing=setup, **kwargs)


async def _arm_takeoff_velocity_land(mav, ap, sim) -> None:
    await mav.wait_for(lambda: sim.vehicle.healthy, 5.0, "healthy")
    await ap.arm()
    await ap.takeoff(2.5)
    await mav.wait_for(lambda: sim.vehicle.mode is FlightMode.HOLD and sim.vehicle.pd < -2.0, 8.0, "takeoff done")
    for _ in range(20):
        ap.set_velocity_ned(VelocitySetpoint(1.0, 0.0, 0.0, 0.0))
        await asyncio.sleep(0.05)
    assert sim.vehicle.mode is FlightMode.OFFBOARD and sim.vehicle.vn > 0.3
    await ap.land()
    await mav.wait_for(lambda: sim.vehicle.mode is FlightMode.LAND, 2.0, "LAND")


async def test_signed_companion_flies_a_signing_vehicle(mav, udp_port):
    config = mav.short_config()
    with mav.sim_vehicle(config, "ardupilot", udp_port, signing_key=KEY.secret) as sim:
        ap = _ap(udp_port, SigningSetup(KEY, link_id=7))
        await ap.connect(timeout_s=3.0)
        await _arm_takeoff_velocity_land(mav, ap, sim)
        await ap.close()
    # everything the vehicle took from us was signed with the key, nothing was refused either way
    assert sim.stats.signature_rejects == 0 and ap.counters.signature_rejects == 0
    assert sim.stats.signed_in == sim.stats.messages_in and sim.stats.setpoints >= 20
    assert ap.counters.signed_heartbeats == ap.counters.heartbeats > 0


async def test_a_kept_timestamp_lets_a_restarted_companion_start_where_it_left_off(mav, udp_port, tmp_path):
    """The vehicle's signing timestamp is an hour ahead of our clock (a companion without a
    real-time clock is behind): a new stream more than 60 s behind it is dropped. Our first
    heartbeat is; pymavlink then takes the vehicle's timestamp from its first verified packet and
    the rest pass. Kept in signing.timestamp_file, the next start begins 60 s past it: nothing is
    dropped."""
    config = mav.short_config()
    ahead = clock_timestamp() + 3600 * TIMESTAMP_UNITS_PER_S
    ts_file = tmp_path / "signing.ts"
    with mav.sim_vehicle(config, "ardupilot", udp_port, signing_key=KEY.secret, signing_timestamp=ahead) as sim:
        vehicle = f"udpout:127.0.0.1:{sim.address[1]}"  # udpout: we speak first
        for start in range(2):
            rejects = sim.stats.signature_rejects
            ap = ArduPilotAutopilot(
                vehicle, signing=SigningSetup(KEY, timestamp_file=ts_file), stream_rates_hz=FEW_STREAMS
            )
            await ap.connect(timeout_s=3.0)
            await mav.wait_for(lambda: sim.vehicle.healthy, 5.0, "healthy")
            await ap.arm()
            await ap.disarm()
            assert (ap.signing_timestamp or 0) > ahead  # ours followed the vehicle's
            await ap.close()
            kept = read_timestamp_file(ts_file)
            assert kept is not None and kept > ahead
            if start == 0:
                assert sim.stats.signature_rejects - rejects >= 1  # the first heartbeat, behind
            else:
                assert sim.stats.signature_rejects == rejects  # started 60 s past the kept one


async def test_unsigned_companion_is_ignored_by_a_signing_vehicle(mav, udp_port):
    config = mav.short_config()
    with mav.sim_vehicle(config, "ardupilot", udp_port, signing_key=KEY.secret) as sim:
        ap = _ap(udp_port, **IGNORED)
        await ap.connect(timeout_s=3.0)  # we hear it (an unsigned parser ignores signatures)...
        await mav.wait_for(lambda: sim.vehicle.healthy, 5.0, "healthy")
        with pytest.raises(CommandRejected, match=r"the vehicle signs its packets .* ignores our unsigned"):
            await ap.arm()  # ...but it drops every unsigned packet of ours
        await ap.close()
    assert not sim.vehicle.armed and sim.stats.commands == {} and sim.stats.messages_in == 0
    assert sim.stats.signature_rejects > 5


async def test_wrong_key_is_refused_both_ways(mav, udp_port):
    config = mav.short_config()
    with mav.sim_vehicle(config, "ardupilot", udp_port, signing_key=KEY.secret) as sim:
        ap = _ap(udp_port, SigningSetup(OTHER))
        with pytest.raises(SigningError, match=r"signing refused \d+ packets .*another key than " + OTHER.fingerprint):
            await ap.connect(timeout_s=1.5)
        # accepting unsigned (its packets fail our key): we hear it, it still ignores us
        ap = _ap(udp_port, SigningSetup(OTHER, allow_unsigned=True), **IGNORED)
        await ap.connect(timeout_s=3.0)
        await mav.wait_for(lambda: sim.vehicle.healthy, 5.0, "healthy")
        with pytest.raises(CommandRejected, match=r"signatures fail our key .* signs with another key"):
            await ap.arm()
        await ap.close()
    assert not sim.vehicle.armed and sim.stats.commands == {} and sim.stats.signature_rejects > 5


async def test_a_companion_requiring_signatures_refuses_an_unsigned_vehicle(mav, udp_port):
    config = mav.short_config()
    with mav.sim_vehicle(config, "ardupilot", udp_port) as sim:
        ap = _ap(udp_port, SigningSetup(KEY))
        with pytest.raises(SigningError, match=r"MAVLink signing refused \d+ packets \(unsigned"):
            await ap.connect(timeout_s=1.5)
        assert ap.counters.signature_rejects >= 1 and ap.counters.heartbeats == 0
        # sign outgoing only: the unsigned vehicle takes our signed packets
        ap = _ap(udp_port, SigningSetup(KEY, allow_unsigned=True), stream_rates_hz=FEW_STREAMS)
        await ap.connect(timeout_s=3.0)
        await mav.wait_for(lambda: sim.vehicle.healthy, 5.0, "healthy")
        await ap.arm()
        assert sim.vehicle.armed and sim.signing_key is None
        await ap.close()


async def test_push_the_key_then_fly_signed_and_turn_it_off(mav, udp_port):
    config = mav.short_config()
    with mav.sim_vehicle(config, "ardupilot", udp_port) as sim:
        ap = _ap(udp_port)
        await ap.connect(timeout_s=3.0)
        await ap.push_signing_key(KEY, timeout_s=3.0)
        assert sim.signing_key == KEY.secret and ap.signing is not None and ap.signing.key == KEY
        n_in, n_signed = sim.stats.messages_in, sim.stats.signed_in
        await mav.wait_for(lambda: sim.vehicle.healthy, 5.0, "healthy")
        await ap.arm()
        # armed: ArduPilot refuses SETUP_SIGNING (we refuse to send it, the vehicle ignores it)
        with pytest.raises(SigningError, match="armed"):
            await ap.push_signing_key(OTHER)
        texts = []
        ap.telemetry.add_listener(lambda sample: texts.append(getattr(sample, "text", "")))
        ap._send(lambda m: m.send(setup_signing_message(m, sim.system_id, 1, OTHER, 1)))
        await mav.wait_for(lambda: "ERROR: Won't setup signing when armed" in texts, 2.0, "refusal text")
        assert sim.signing_key == KEY.secret and sim.vehicle.armed
        await ap.takeoff(2.5)
        await mav.wait_for(lambda: sim.vehicle.mode is FlightMode.HOLD and sim.vehicle.pd < -2.0, 8.0, "takeoff done")
        for _ in range(20):
            ap.set_velocity_ned(VelocitySetpoint(0.0, 1.0, 0.0, 0.0))
            await asyncio.sleep(0.05)
        assert sim.vehicle.mode is FlightMode.OFFBOARD and sim.vehicle.ve > 0.3
        await ap.land()
        signed = sim.stats.signed_in - n_signed
        assert signed == sim.stats.messages_in - n_in and signed > 20  # all signed since the push
        assert ap.counters.signed_heartbeats > 0 and sim.stats.signature_rejects == 0
        await mav.wait_for(lambda: not sim.vehicle.armed, 15.0, "landed and disarmed")
        await mav.wait_for(lambda: ap.telemetry.status is not None and not ap.telemetry.status.armed, 3.0, "disarm")
        await ap.push_signing_key(None)  # the zero key, signed with ours
        await mav.wait_for(lambda: sim.signing_key is None, 2.0, "signing off")
        assert ap.signing is None
        await ap.close()


async def test_the_signing_vehicle_takes_radio_status_unsigned_only(mav, udp_port):
    os.environ["MAVLINK20"] = "1"
    from pymavlink import mavutil

    config = mav.short_config()
    with mav.sim_vehicle(config, "ardupilot", udp_port, signing_key=KEY.secret) as sim:
        conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{udp_port}", dialect="ardupilotmega", source_system=51)
        try:
            assert conn.wait_heartbeat(timeout=3.0) is not None
            for _ in range(3):
                conn.mav.radio_status_send(200, 190, 50, 10, 5, 0, 0)
                conn.mav.heartbeat_send(6, 8, 0, 0, 4)
                conn.mav.command_long_send(1, 1, 400, 0, 1, 0, 0, 0, 0, 0, 0)  # arm
            await mav.wait_for(lambda: sim.stats.signature_rejects >= 6, 2.0, "rejects")
        finally:
            conn.close()
    assert sim.stats.by_type_in == {"RADIO_STATUS": 3} and not sim.vehicle.armed


def test_px4_backend_cannot_sign(mav):
    from companion.config import ConfigError, config_from_dict

    with pytest.raises(ConfigError, match=r"signing.enabled = true with autopilot = 'px4'.*mavsdk 4.1"):
        config_from_dict({"autopilot": "px4", "signing": {"enabled": True, "key_file": "k.hex"}})
    with pytest.raises(ValueError, match="'px4' sim vehicle does not sign"):
        mav.sim_vehicle(mav.short_config(), "px4", 1, signing_key=KEY.secret).__enter__()


def test_config_builds_the_signed_backend(mav, tmp_path):
    path = tmp_path / "key.hex"
    path.write_text(KEY.hex + "\n")
    path.chmod(0o600)
    config = mav.short_config().model_copy(
        update={"autopilot": "ardupilot", "connection": "udpin:127.0.0.1:1"},
    )
    from companion.config import config_from_dict

    data = config.model_dump()
    data["signing"] = {"enabled": True, "key_file": str(path), "link_id": 9}
    ap = ArduPilotAutopilot.from_config(config_from_dict(data))
    assert ap.signing == SigningSetup(SigningKey(KEY.secret, str(path)), 9, False, None)
    bad_ts = tmp_path / "bad.ts"
    bad_ts.write_text("yesterday\n")
    data["signing"]["timestamp_file"] = str(bad_ts)
    with pytest.raises(AutopilotError, match=r"bad\.ts: 'yesterday' is not an integer"):
        ArduPilotAutopilot.from_config(config_from_dict(data))  # before any link is opened
    data["signing"]["timestamp_file"] = None
    data["signing"]["key_file"] = str(tmp_path / "missing.hex")
    with pytest.raises(AutopilotError, match=r"missing\.hex: not found"):
        ArduPilotAutopilot.from_config(config_from_dict(data))

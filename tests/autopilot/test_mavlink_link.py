"""Link behaviour of the MAVLink backends against the MAVLink sim vehicle (real time, loopback)."""

from __future__ import annotations

import asyncio
import logging
import os
import socket

import pytest

from companion.autopilot import Autopilot, AutopilotError, FlightMode
from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.ardupilot.link import parse_connection
from companion.autopilot.px4 import Px4Autopilot
from companion.autopilot.px4.telemetry import px4_flight_mode as px4_decode
from companion.cli.fly import make_autopilot
from companion.guidance.setpoint import VelocitySetpoint
from companion_sitl.mavlink.ardupilot import COPTER_GUIDED, copter_flight_mode
from companion_sitl.mavlink.factory import mavlink_sim_vehicle
from companion_sitl.mavlink.px4 import px4_custom_mode, px4_flight_mode


def test_px4_custom_mode_round_trip():
    for mode in FlightMode:
        if mode is not FlightMode.UNKNOWN:
            assert px4_flight_mode(px4_custom_mode(mode)) is mode
            assert px4_decode(px4_custom_mode(mode)) is mode
    assert copter_flight_mode(COPTER_GUIDED) is FlightMode.OFFBOARD


def test_parse_connection_urls():
    assert parse_connection("udpin://0.0.0.0:14550") == ("udpin:0.0.0.0:14550", 57600, "udpin")
    assert parse_connection("udp://:14540")[0] == "udpin:0.0.0.0:14540"
    assert parse_connection("udpout:127.0.0.1:14550")[0] == "udpout:127.0.0.1:14550"
    assert parse_connection("tcpout://127.0.0.1:5760")[0] == "tcp:127.0.0.1:5760"
    assert parse_connection("serial:///dev/ttyACM0:921600") == ("/dev/ttyACM0", 921600, "serial")
    assert parse_connection("/dev/ttyUSB0", baud=115200) == ("/dev/ttyUSB0", 115200, "serial")
    with pytest.raises(AutopilotError):
        parse_connection("udpin:nohostport")


def test_factory_picks_the_backend(mav):
    config = mav.short_config()
    assert type(make_autopilot(config)).__name__ == "SimAutopilot"
    px4 = make_autopilot(config.model_copy(update={"autopilot": "px4"}))
    ap = make_autopilot(config.model_copy(update={"autopilot": "ardupilot", "connection": "udpin:127.0.0.1:1"}))
    assert isinstance(px4, Px4Autopilot) and isinstance(ap, ArduPilotAutopilot)
    assert isinstance(px4, Autopilot) and ap.link_timeout_s == config.runtime.link_timeout_s


async def test_serial_device_that_does_not_exist_is_a_clear_error():
    with pytest.raises(AutopilotError, match="serial device /dev/ttyNOPE42 does not exist"):
        await ArduPilotAutopilot("/dev/ttyNOPE42:57600").connect(timeout_s=1.0)
    with pytest.raises(AutopilotError, match="serial device /dev/ttyNOPE42 does not exist"):
        await Px4Autopilot("serial:///dev/ttyNOPE42:57600").connect(timeout_s=1.0)


async def test_nothing_answering_is_a_clear_error(mav):
    port = mav.free_udp_port()
    with pytest.raises(AutopilotError, match="no heartbeat"):
        await ArduPilotAutopilot(f"udpin:127.0.0.1:{port}").connect(timeout_s=0.5)
    with pytest.raises(AutopilotError, match="no PX4 autopilot answered"):
        await Px4Autopilot(f"udpin://127.0.0.1:{port}").connect(timeout_s=0.5)
    with pytest.raises(AutopilotError, match="cannot open"):
        await ArduPilotAutopilot(f"tcp:127.0.0.1:{mav.free_tcp_port()}").connect(timeout_s=0.5)


async def test_garbage_bytes_on_the_link_are_counted_and_ignored(mav, udp_port):
    config = mav.short_config()
    with mav.sim_vehicle(config, "ardupilot", udp_port) as sim:
        ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}")
        await ap.connect(timeout_s=3.0)
        junk = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        try:
            rnd = os.urandom(4000)
            for i in range(40):  # noise at both ends, some of it starting with the MAVLink 2 magic
                chunk = (b"\xfd" if i % 2 else b"") + rnd[i * 100 : (i + 1) * 100]
                junk.sendto(chunk, ("127.0.0.1", udp_port))
                junk.sendto(chunk, sim.address)
                await asyncio.sleep(0.005)
        finally:
            junk.close()
        n0 = ap.telemetry.received.get("Attitude", 0)
        await asyncio.sleep(0.5)
        assert ap.telemetry.received["Attitude"] - n0 > 10  # telemetry still flows
        assert ap.counters.bad_data > 0 and sim.stats.bad_data > 0 and sim.stats.garbage_bytes > 1000
        await mav.wait_for(lambda: sim.vehicle.healthy, 5.0, "healthy")
        await ap.arm()  # commands still work
        assert sim.vehicle.armed and ap.link_ok
        await ap.close()


async def test_ardupilot_arm_waits_for_the_ekf_and_guided_velocity_times_out(mav, udp_port):
    config = mav.short_config()
    with mav.sim_vehicle(config, "ardupilot", udp_port, ekf_delay_s=3.0) as sim:
        ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}", arm_timeout_s=8.0)
        await ap.connect(timeout_s=3.0)
        assert not sim.vehicle.healthy
        await ap.arm()  # refused while the EKF waits for GPS, retried until accepted
        assert sim.vehicle.armed and sim.vehicle.time_s >= 3.0 and sim.copter_mode == COPTER_GUIDED
        await ap.takeoff(2.5)
        await mav.wait_for(lambda: sim.vehicle.mode is FlightMode.HOLD, 6.0, "takeoff done")
        for _ in range(10):
            ap.set_velocity_ned(VelocitySetpoint(1.0, 0.0, 0.0, 0.0))
            await asyncio.sleep(0.05)
        assert sim.vehicle.mode is FlightMode.OFFBOARD
        await asyncio.sleep(3.3)  # GUIDED velocity timeout: the vehicle stops, still GUIDED
        assert sim.vehicle.mode is FlightMode.HOLD and sim.copter_mode == COPTER_GUIDED
        assert ap.mode is FlightMode.OFFBOARD
        await ap.land()
        await ap.close()


async def test_px4_offboard_refused_without_prior_setpoints(mav, udp_port):
    config = mav.short_config()
    with mav.sim_vehicle(config, "px4", udp_port) as sim:
        ap = Px4Autopilot(f"udpin://127.0.0.1:{udp_port}")
        await ap.connect(timeout_s=5.0)
        await mav.wait_for(lambda: ap.telemetry.status is not None and ap.telemetry.status.healthy, 6.0, "healthy")
        await ap.arm()
        await ap.takeoff(2.5)
        await mav.wait_for(lambda: sim.vehicle.mode is FlightMode.HOLD and sim.vehicle.pd < -2.0, 6.0, "takeoff")
        with pytest.raises(AutopilotError, match="no setpoints streamed"):
            await ap.start_offboard()
        for _ in range(12):  # stream first, then it is accepted
            ap.set_velocity_ned(VelocitySetpoint(0.0, 0.0, 0.0, 0.0))
            await asyncio.sleep(0.05)
        await ap.start_offboard()
        await mav.wait_for(lambda: ap.telemetry.status.mode is FlightMode.OFFBOARD, 2.0, "offboard")
        await ap.land()
        await ap.close()


async def test_hil_state_quaternion_truth_on_request(mav, udp_port):
    os.environ["MAVLINK20"] = "1"
    from pymavlink import mavutil

    config = mav.short_config()
    with mav.sim_vehicle(config, "px4", udp_port):
        conn = mavutil.mavlink_connection(f"udpin:127.0.0.1:{udp_port}", dialect="ardupilotmega", source_system=200)
        try:
            assert conn.wait_heartbeat(timeout=3) is not None
            conn.mav.command_long_send(1, 1, 511, 0, 115, 100000, 0, 0, 0, 0, 0)
            ack = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=2)
            truth = conn.recv_match(type="HIL_STATE_QUATERNION", blocking=True, timeout=2)
            conn.mav.command_long_send(1, 1, 31000, 0, 0, 0, 0, 0, 0, 0, 0)  # a command nobody knows
            unknown = conn.recv_match(type="COMMAND_ACK", blocking=True, timeout=2)
            lp = conn.recv_match(type="LOCAL_POSITION_NED", blocking=True, timeout=5)
        finally:
            conn.close()
    assert ack.result == 0 and truth is not None and abs(truth.lat / 1e7 - config.sim.home.lat_deg) < 1e-4
    assert unknown.command == 31000 and unknown.result == 3  # MAV_RESULT_UNSUPPORTED
    assert lp is not None and lp.z != 0.0  # PX4's z at rest is a few cm, not exactly 0


def test_sim_vehicle_rejects_an_unknown_dialect():
    from companion_sitl.params import SimConfig

    with pytest.raises(ValueError, match="dialect"):
        mavlink_sim_vehicle(SimConfig(), "inav")  # type: ignore[arg-type]


async def test_mavsdk_own_log_lines_go_to_python_logging_not_stdout(mav, caplog, capfd):
    """MAVSDK prints its lines (debug included) to stdout itself; the backend routes them to the
    ``companion.autopilot.px4.mavsdk`` logger, so ``companion -vv`` shows its debug lines and the
    default level none."""
    port = mav.free_udp_port()
    with (
        caplog.at_level(logging.DEBUG, logger="companion.autopilot.px4.mavsdk"),
        pytest.raises(AutopilotError, match="no PX4 autopilot answered"),
    ):
        await Px4Autopilot(f"udpin://127.0.0.1:{port}").connect(timeout_s=0.3)
    lines = [r for r in caplog.records if r.name == "companion.autopilot.px4.mavsdk"]
    assert any("MAVSDK version" in r.getMessage() and r.levelno == logging.INFO for r in lines)
    out = capfd.readouterr()
    assert "MAVSDK version" not in out.out and "MAVSDK version" not in out.err

"""Whole delivery missions over real MAVLink on loopback UDP, in real time, against the MAVLink
sim vehicle: PX4 dialect through MAVSDK, ArduPilot dialect through pymavlink."""

from __future__ import annotations

import math
import os
import threading

import pytest

from companion.autopilot import FlightMode
from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.px4 import Px4Autopilot
from companion.config import shipped_params_path
from companion.events import EventKind, Phase
from companion.flightlog.tlog import read_tlog
from companion.flightlog.tlog_writer import open_tlog
from companion.scheduling import thread_policy
from companion_sitl.params import load_simulated_config

pytestmark = pytest.mark.flight


def _tlog_by_source(path):
    out: dict[tuple[int, int], list] = {}
    for m in read_tlog(path):
        out.setdefault((m.get_srcSystem(), m.get_srcComponent()), []).append(m)
    return out


def _setpoints(msgs):
    return [(m.vx, m.vy, m.vz, m.yaw) for m in msgs if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]


def _types(msgs):
    return {m.get_type() for m in msgs}


def _turned_to_the_path(sent, vehicle_msgs) -> None:
    """The vehicle flew the setpoints' yaw (the path's heading), not its take-off heading: the
    setpoint's type_mask leaves the yaw in."""
    yaw_sp = sent[len(sent) // 2][3]
    assert abs(yaw_sp) > 0.2, yaw_sp  # the path is not due north, or holding yaw 0 would pass
    att = [m for m in vehicle_msgs if m.get_type() == "ATTITUDE"]
    err = [abs((m.yaw - yaw_sp + math.pi) % (2 * math.pi) - math.pi) for m in att]
    assert min(err) < math.radians(3.0), math.degrees(min(err))


def _pad_error(sim, config):
    td = [t for t in sim.vehicle.touchdowns if not t.payload_released]
    assert td, "no touchdown on the pad"
    return math.hypot(td[0].north_m - config.mission.pad.north_m, td[0].east_m - config.mission.pad.east_m)


async def test_full_delivery_ardupilot_over_udp(mav, udp_port, tmp_path):
    # runtime.realtime_priority: the loop's thread and the threads it starts (the link's reader)
    # fly SCHED_RR, and the loop's thread is back to its policy afterwards
    config = load_simulated_config(
        shipped_params_path("sitl_short.toml"), overrides={"runtime": {"realtime_priority": 9}}
    )
    received = []  # what reached the vehicle
    policies: dict[str, tuple[int, int]] = {}
    before = thread_policy()

    async def watch(shell):
        await mav.wait_for(lambda: shell.mission.phase is Phase.OUTBOUND, 60.0, "the way out")
        p = thread_policy()
        policies["loop"] = (p.policy, p.priority)
        reader = next(t for t in threading.enumerate() if t.name == "ardupilot-reader")
        p = thread_policy(reader.native_id)
        policies["reader"] = (p.policy, p.priority)

    with mav.sim_vehicle(config, "ardupilot", udp_port) as sim:
        sim.on_message = received.append
        ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}", tlog=open_tlog(tmp_path / "flight.tlog"))
        shell, summary = await mav.fly(config, ap, watch)
    assert summary.delivered and summary.returned and shell.mission.phase is Phase.DONE, summary.failure
    if shell.stats.realtime.startswith("refused"):  # no CAP_SYS_NICE here: said, and the flight is the same
        assert "CAP_SYS_NICE" in shell.stats.realtime and policies["loop"][0] == os.SCHED_OTHER
    else:
        assert shell.stats.realtime == "SCHED_RR 9"
        assert policies == {"loop": (os.SCHED_RR, 9), "reader": (os.SCHED_RR, 9)}
    after = thread_policy()
    assert (after.policy, after.priority) == (before.policy, before.priority)
    assert _pad_error(sim, config) < 1.0
    assert len(sim.vehicle.touchdowns) == 2 and not sim.vehicle.armed
    assert sim.stats.setpoints > 300 and sim.stats.bad_data == 0
    assert ap.counters.bad_data == 0 and shell.stats.requests_failed == 0
    assert sim.stats.commands[511] >= 8  # message intervals were requested (ArduPilot streams nothing unasked)

    # the .tlog holds both directions, as they crossed the link
    log = _tlog_by_source(tmp_path / "flight.tlog")
    ours, vehicle = log.pop((ap.source_system, ap.source_component)), log.pop((sim.system_id, sim.component_id))
    # the companion's own component (docs/gcs.md): the vehicle's system id, its heartbeat, the
    # mission's events and the computer's status
    component = log.pop((sim.system_id, 191))
    assert {"HEARTBEAT", "STATUSTEXT", "ONBOARD_COMPUTER_STATUS"} <= _types(component)
    assert not log  # nobody else on the link
    sent = _setpoints(ours)
    assert len(sent) == ap.counters.setpoints_sent and sent == _setpoints(received)
    _turned_to_the_path(sent, vehicle)
    commands = [(m.command, m.param1) for m in ours if m.get_type() == "COMMAND_LONG"]
    assert commands == [(m.command, m.param1) for m in received if m.get_type() == "COMMAND_LONG"]
    assert {"HEARTBEAT", "SET_POSITION_TARGET_LOCAL_NED", "COMMAND_LONG"} <= _types(ours)
    wanted = {"HEARTBEAT", "ATTITUDE", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "GPS_RAW_INT", "COMMAND_ACK"}
    assert wanted <= _types(vehicle)
    assert sum(m.get_type() == "HEARTBEAT" for m in vehicle) == ap.counters.heartbeats
    assert len(vehicle) == ap.counters.messages + ap.counters.heartbeats  # every packet received is there


async def test_full_delivery_px4_over_mavsdk(mav, udp_port, tmp_path):
    config = mav.short_config()
    received = []
    with mav.sim_vehicle(config, "px4", udp_port) as sim:
        sim.on_message = received.append
        ap = Px4Autopilot(f"udpin://127.0.0.1:{udp_port}", tlog=open_tlog(tmp_path / "flight.tlog"))
        shell, summary = await mav.fly(config, ap)
    assert summary.delivered and summary.returned and shell.mission.phase is Phase.DONE, summary.failure
    assert _pad_error(sim, config) < 1.0
    assert len(sim.vehicle.touchdowns) == 2 and not sim.vehicle.armed
    assert sim.stats.setpoints > 300
    assert shell.stats.requests_failed == 0
    assert ap.telemetry.received["Attitude"] > 500 and ap.telemetry.received["PositionNed"] > 300

    # the .tlog: every message MAVSDK received and sent, re-encoded from its decoded fields
    log = _tlog_by_source(tmp_path / "flight.tlog")
    vehicle = log.pop((sim.system_id, sim.component_id))
    (mavsdk_id, ours), *others = log.items()
    assert not others and mavsdk_id == (ap.system_id, 191)  # MAVSDK speaks as the companion's component
    assert {"STATUSTEXT", "ONBOARD_COMPUTER_STATUS"} <= _types(ours)
    sent = _setpoints(ours)
    assert len(sent) == ap.setpoints_sent and sent == _setpoints(received)
    _turned_to_the_path(sent, vehicle)
    assert {"HEARTBEAT", "COMMAND_LONG"} <= _types(ours)  # MAVSDK's own traffic (Action, intervals) too
    wanted = {"HEARTBEAT", "ATTITUDE", "HIGHRES_IMU", "LOCAL_POSITION_NED", "GLOBAL_POSITION_INT", "COMMAND_ACK"}
    assert wanted <= _types(vehicle)
    attitudes = sum(m.get_type() in ("ATTITUDE", "ATTITUDE_QUATERNION") for m in vehicle)
    assert attitudes >= ap.telemetry.received["Attitude"]  # MAVSDK's attitude stream derives from these


async def test_pilot_takeover_px4_mode_switch_on_the_vehicle(mav, udp_port):
    config = mav.short_config(return_home=False)
    seen = {}

    async def monitor(shell):
        await mav.wait_for(lambda: shell.mission.phase is Phase.OUTBOUND, 30.0, "outbound")
        sim.pilot_set_mode(FlightMode.POSITION)
        seen["n0"] = sim.stats.setpoints
        seen["t"] = shell.now()
        await mav.wait_for(lambda: shell.mission.phase is Phase.PILOT, 3.0, "pilot phase")
        seen["t_pilot"] = shell.now()

    with mav.sim_vehicle(config, "px4", udp_port) as sim:
        ap = Px4Autopilot(f"udpin://127.0.0.1:{udp_port}")
        shell, summary = await mav.fly(config, ap, monitor, timeout_s=40.0)
        n_after = sim.stats.setpoints - seen["n0"]
        mode = sim.vehicle.mode
    ev = next(e for e in shell.events if e.kind is EventKind.PILOT_TAKEOVER)
    assert ev.time_s - seen["t"] <= 1.3  # PX4 heartbeat (mode) at 1 Hz + one guidance period
    assert "pilot took over" in summary.failure
    assert n_after <= 30  # streaming stops once the takeover is seen
    assert mode is FlightMode.POSITION  # never switched back


async def test_pilot_takeover_ardupilot_rc_mode_switch(mav, udp_port):
    config = mav.short_config(return_home=False)
    seen = {}

    async def monitor(shell):
        await mav.wait_for(lambda: shell.mission.phase is Phase.OUTBOUND, 30.0, "outbound")
        ap.send_rc_override([1500, 1500, 1500, 1500, 1425, 0, 0, 0])  # FLTMODE3 = LOITER
        seen["t"] = shell.now()
        await mav.wait_for(lambda: shell.mission.phase is Phase.PILOT, 3.0, "pilot phase")

    with mav.sim_vehicle(config, "ardupilot", udp_port) as sim:
        ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}")
        _shell, summary = await mav.fly(config, ap, monitor, timeout_s=40.0)
        copter_mode = sim.copter_mode
        rc5 = sim.rc_channels[4]
        # The shell ends on the HEARTBEAT's mode, which may come before the next RC_CHANNELS (5 Hz):
        # read the override back on a fresh link to the same vehicle instead of racing the stream.
        reader = ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}")
        try:
            await reader.connect(timeout_s=10.0)
            await mav.wait_for(
                lambda: bool(reader.rc_channels) and reader.rc_channels[4] == 1425,
                5.0,
                "RC_CHANNELS carrying the override",
            )
        finally:
            await reader.close()
    assert "pilot took over (position)" in summary.failure
    assert copter_mode == 5 and rc5 == 1425


async def test_link_loss_and_reconnect_px4(mav, udp_port):
    config = mav.short_config(return_home=False)
    out = {}

    async def monitor(shell):
        await mav.wait_for(lambda: shell.mission.phase is Phase.OUTBOUND, 30.0, "outbound")
        sim.set_link(False)
        n0 = sim.stats.setpoints
        await mav.wait_for(lambda: not ap.link_ok, 2.0, "link_ok false")
        out["detect"] = True
        # PX4 v1.16 with COM_OBL_RC_ACT = 0 goes to POSCTL on SIH, as the sim vehicle does
        await mav.wait_for(lambda: sim.vehicle.mode is FlightMode.POSITION, 3.0, "offboard-loss failsafe")
        out["mode_during_loss"] = sim.vehicle.mode
        out["setpoints_during_loss"] = sim.stats.setpoints - n0
        sim.set_link(True)

    with mav.sim_vehicle(config, "px4", udp_port) as sim:
        ap = Px4Autopilot.from_config(config.model_copy(update={"connection": f"udpin://127.0.0.1:{udp_port}"}))
        shell, summary = await mav.fly(config, ap, monitor, timeout_s=60.0)
    kinds = [e.kind for e in shell.events]
    assert EventKind.LINK_LOST in kinds and EventKind.LINK_RESTORED in kinds
    assert out["setpoints_during_loss"] == 0 and out["mode_during_loss"] is FlightMode.POSITION
    assert summary.delivered, summary.failure


async def test_ardupilot_gripper_refused_is_reported_once_and_the_vehicle_flies_home_with_the_parcel(mav, udp_port):
    """ArduCopter with its gripper library off (GRIP_ENABLE = 0, the firmware default) answers
    DO_GRIPPER with FAILED: one request, one warning, then the return leg with the parcel."""
    config = mav.short_config()
    with mav.sim_vehicle(config, "ardupilot", udp_port, params={"GRIP_ENABLE": 0.0}) as sim:
        ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}")
        _, summary = await mav.fly(config, ap)
    assert summary.returned and not summary.delivered
    refused = "parcel not released: release refused: release (gripper): FAILED"
    assert summary.failure.startswith(refused), summary.failure
    assert sim.stats.commands[211] == 1  # MAV_CMD_DO_GRIPPER sent once, not at 20 Hz
    failed = [e for e in summary.events if e.kind is EventKind.REQUEST_FAILED]
    assert len(failed) == 1 and "not retried" in failed[0].detail
    assert len(sim.vehicle.touchdowns) == 2 and all(not t.payload_released for t in sim.vehicle.touchdowns)


@pytest.mark.parametrize("dialect", ["px4", "ardupilot"])
async def test_the_final_descent_sends_its_acceleration_on_both_dialects(mav, udp_port, dialect):
    """With landing_xy_accel_feedforward the final descent's setpoints carry an acceleration: through
    MAVSDK (PX4) as a position-velocity-acceleration setpoint whose position is NaN, which PX4's
    receiver leaves uncontrolled; through pymavlink (ArduPilot) with the position bits set. The sim
    vehicle flies both as velocity + acceleration and the delivery lands on the pad."""
    config = mav.short_config(landing_xy_accel_feedforward=1.0, return_home=False)
    received = []
    with mav.sim_vehicle(config, dialect, udp_port) as sim:
        sim.on_message = received.append
        flown = []  # the accelerations of the setpoints the vehicle took
        take = sim.vehicle.set_velocity

        def spy(sp):
            flown.append(sp.accel_ne_m_s2)
            take(sp)

        sim.vehicle.set_velocity = spy
        ap = (
            Px4Autopilot(f"udpin://127.0.0.1:{udp_port}")
            if dialect == "px4"
            else ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}")
        )
        _shell, summary = await mav.fly(config, ap)
    assert summary.delivered, summary.failure
    assert _pad_error(sim, config) < 0.5
    sps = [m for m in received if m.get_type() == "SET_POSITION_TARGET_LOCAL_NED"]
    accel_bits = 0b111000000
    with_acc = [m for m in sps if not m.type_mask & accel_bits]
    assert len(with_acc) > 20 and any(abs(m.afx) + abs(m.afy) > 0.01 for m in with_acc)
    assert sum(a is not None for a in flown) >= len(with_acc) - 5  # all but a few sent after the landing
    for m in with_acc:
        assert all(math.isnan(x) for x in (m.x, m.y, m.z)) or (m.type_mask & 0b111) == 0b111
    assert any(m.type_mask & accel_bits == accel_bits for m in sps)  # velocity only before the descent

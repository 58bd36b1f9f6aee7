"""The companion as a MAVLink component the operator's GCS sees and commands (docs/gcs.md): event
severities, the command table and its answers against the real mission, the host status, and both
backends against the MAVLink sim vehicle routing between the companion and a GCS socket."""

from __future__ import annotations

import asyncio
import os
import socket
import time

import pytest

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.component import ComponentCommand, statustext_chunks
from companion.autopilot.px4 import Px4Autopilot
from companion.config import CompanionConfig, GcsConfig
from companion.delivery.gcs import (
    MAV_RESULT_ACCEPTED,
    MAV_RESULT_DENIED,
    MAV_RESULT_TEMPORARILY_REJECTED,
    MAV_RESULT_UNSUPPORTED,
    GcsComponent,
    GcsOnly,
    ack_result,
    event_severity,
    event_text,
    mission_kind,
)
from companion.delivery.host_status import HostStatusReader, onboard_computer_status
from companion.delivery.mission import CommandOutcome, CommandReply, DeliveryMission
from companion.events import CommandKind, EventKind, MissionEvent, Phase


def _cmd(command: int, p1: float = 0.0) -> ComponentCommand:
    return ComponentCommand(0.0, 255, 190, command, 0, (p1, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0))


def test_event_severities_and_texts():
    ev = MissionEvent(1.0, EventKind.PHASE, Phase.OUTBOUND, "outbound")
    assert event_severity(ev) == 6 and event_text(ev) == "phase outbound"
    assert event_severity(MissionEvent(1.0, EventKind.ABORT, Phase.OUTBOUND, "x")) == 4
    assert event_severity(MissionEvent(1.0, EventKind.REQUEST_FAILED, Phase.ARMING, "x")) == 4
    assert event_severity(MissionEvent(1.0, EventKind.PHASE, Phase.ABORT_HOLD, "abort_hold")) == 4
    assert event_severity(MissionEvent(1.0, EventKind.PHASE, Phase.FAILED, "failed")) == 2
    assert event_severity(MissionEvent(1.0, EventKind.DELIVERED, Phase.RELEASE, "")) == 5
    assert event_text(MissionEvent(1.0, EventKind.ABORT, Phase.OUTBOUND, "link lost")) == "abort: link lost"
    # every kind and phase has a severity no quieter than INFO
    for kind in EventKind:
        for phase in Phase:
            assert 2 <= event_severity(MissionEvent(0.0, kind, phase, "d")) <= 6


def test_long_texts_are_chunked():
    text = "x" * 120
    chunks = statustext_chunks(text)
    assert [len(c) for c in chunks] == [50, 50, 20] and "".join(chunks) == text
    assert statustext_chunks("é") == ["?"]


def test_command_table():
    assert mission_kind(_cmd(17)) is CommandKind.HOLD
    assert mission_kind(_cmd(193, 0.0)) is CommandKind.HOLD
    assert mission_kind(_cmd(193, 1.0)) is GcsOnly.CONTINUE
    assert mission_kind(_cmd(20)) is CommandKind.RETURN
    assert mission_kind(_cmd(21)) is CommandKind.LAND
    assert mission_kind(_cmd(400)) is None


def test_ack_results_follow_the_mission_replies():
    """The mission's own replies, phase by phase, give the MAV_RESULTs the GCS sees."""
    m = DeliveryMission(CompanionConfig().mission)
    assert ack_result(m.command(0.0, CommandKind.RETURN, "gcs")) == MAV_RESULT_TEMPORARILY_REJECTED  # pre-flight
    assert ack_result(m.command(0.0, CommandKind.HOLD, "gcs")) == MAV_RESULT_TEMPORARILY_REJECTED  # on the ground
    m.phase = Phase.OUTBOUND
    assert ack_result(m.command(1.0, CommandKind.RETURN, "gcs")) == MAV_RESULT_ACCEPTED
    assert m.phase is Phase.INBOUND
    assert ack_result(m.command(2.0, CommandKind.LAND, "gcs")) == MAV_RESULT_ACCEPTED
    assert m.phase is Phase.ABORT_LAND
    m.phase = Phase.DONE
    assert ack_result(m.command(3.0, CommandKind.HOLD, "gcs")) == MAV_RESULT_DENIED
    # every outcome the mission can reply with has its MAV_RESULT
    assert {ack_result(CommandReply(o, "")) for o in CommandOutcome} <= {
        MAV_RESULT_ACCEPTED,
        MAV_RESULT_DENIED,
        MAV_RESULT_TEMPORARILY_REJECTED,
    }


async def test_an_unsupported_command_and_continue_never_reach_the_mission():
    """Not a mission command: UNSUPPORTED, and DO_PAUSE_CONTINUE's continue DENIED, both decided
    here; only the hold reaches the mission, as the kind it is."""
    asked: list[CommandKind] = []
    link = _Link()
    comp = GcsComponent(
        GcsConfig(), link, lambda kind, sender: asked.append(kind) or CommandReply(CommandOutcome.ACCEPTED, "ok")
    )
    assert comp.open()
    try:
        link.on_command(ComponentCommand(0.0, 255, 190, 400, 0, (0.0,) * 7, None))
        link.on_command(ComponentCommand(0.0, 255, 190, 193, 0, (1.0,) + (0.0,) * 6, None))
        link.on_command(ComponentCommand(0.0, 255, 190, 193, 0, (0.0,) * 7, None))
    finally:
        await comp.close()
    assert asked == [CommandKind.HOLD]
    assert [r for _, r, _ in comp.commands] == [MAV_RESULT_UNSUPPORTED, MAV_RESULT_DENIED, MAV_RESULT_ACCEPTED]


def test_host_status_from_proc_files(tmp_path):
    proc, thermal = tmp_path / "proc", tmp_path / "thermal"
    proc.mkdir()
    (thermal / "thermal_zone0").mkdir(parents=True)
    (thermal / "thermal_zone1").mkdir(parents=True)
    (thermal / "thermal_zone0" / "temp").write_text("47500\n")
    (thermal / "thermal_zone1" / "temp").write_text("52000\n")
    (proc / "uptime").write_text("1234.5 999.0\n")
    (proc / "meminfo").write_text("MemTotal: 4096000 kB\nMemFree: 100 kB\nMemAvailable: 1024000 kB\n")
    (proc / "stat").write_text("cpu 10 0 10 80 0\ncpu0 5 0 5 40 0\ncpu1 5 0 5 40 0\n")
    r = HostStatusReader(proc, thermal)
    assert r.read().cpu_load_pct == ()  # no load before two readings
    (proc / "stat").write_text("cpu 10 0 10 80 0\ncpu0 55 0 5 90 0\ncpu1 5 0 5 140 0\n")
    s = r.read()
    assert s.uptime_s == 1234.5 and s.cpu_load_pct == (50, 0)
    assert s.temperature_board_c == 47.5 and s.temperature_cores_c == (52.0,)
    assert (s.ram_used_mib, s.ram_total_mib) == (3000, 4000)
    fields = onboard_computer_status(s, 123)
    msg = mavlink.MAVLink_onboard_computer_status_message(**fields)
    packed = msg.pack(mavlink.MAVLink(None, 1, 191))
    back = mavlink.MAVLink(None).decode(bytearray(packed))
    assert back.uptime == 1234500 and list(back.cpu_cores[:3]) == [50, 0, 255] and back.temperature_board == 48
    assert back.ram_usage == 3000 and back.ram_total == 4000 and back.temperature_core[0] == 52


def test_unreadable_host_says_unknown(tmp_path):
    s = HostStatusReader(tmp_path / "none", tmp_path / "none").read()
    assert s.temperature_board_c is None and s.ram_total_mib is None and s.uptime_s >= 0.0
    f = onboard_computer_status(s, 0)
    assert f["temperature_board"] == 127 and f["ram_total"] == 0xFFFFFFFF and f["cpu_cores"] == [255] * 8


class _Gcs:
    """A GCS on a UDP socket talking to the sim vehicle, as QGroundControl would: heartbeats as
    255/190, reads what the vehicle routes to it, sends COMMAND_LONGs."""

    def __init__(self, vehicle_addr: tuple[str, int]) -> None:
        self.addr = vehicle_addr
        self.sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.sock.bind(("127.0.0.1", 0))
        self.sock.setblocking(False)
        self.enc = mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
        self.rx = mavlink.MAVLink(None)
        self.rx.robust_parsing = True
        self.got: list = []

    def send(self, msg) -> None:
        self.sock.sendto(msg.pack(self.enc), self.addr)

    def heartbeat(self) -> None:
        self.send(self.enc.heartbeat_encode(mavlink.MAV_TYPE_GCS, mavlink.MAV_AUTOPILOT_INVALID, 0, 0, 0))

    def drain(self) -> None:
        while True:
            try:
                data = self.sock.recv(65535)
            except BlockingIOError:
                return
            self.got.extend(m for m in (self.rx.parse_buffer(data) or []) if m.get_type() != "BAD_DATA")

    def from_(self, sysid: int, compid: int, kind: str) -> list:
        src = (sysid, compid)
        return [m for m in self.got if m.get_type() == kind and (m.get_srcSystem(), m.get_srcComponent()) == src]


@pytest.mark.parametrize("dialect", ["px4", "ardupilot"])
async def test_gcs_sees_and_commands_the_companion(mav, udp_port, dialect):
    """Through the vehicle's routing, the GCS receives the companion's heartbeat (an onboard
    controller, 1/191), its STATUSTEXTs and ONBOARD_COMPUTER_STATUS; its RTL addressed to 1/191
    reaches the mission as "return" from "gcs" and is answered with a COMMAND_ACK from 1/191."""
    config = mav.short_config()
    asked: list[tuple[CommandKind, str]] = []

    def command(kind: CommandKind, sender: str) -> CommandReply:
        asked.append((kind, sender))
        if kind is CommandKind.RETURN:
            return CommandReply(CommandOutcome.ACCEPTED, "returning home along the path")
        return CommandReply(CommandOutcome.NOT_NOW, "ignored: cannot hold from preflight")

    with mav.sim_vehicle(config, dialect, udp_port, route_peers=True) as sim:
        if dialect == "px4":
            ap = Px4Autopilot(f"udpin://127.0.0.1:{udp_port}", component_id=191)
        else:
            ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}")
        gcs = _Gcs(sim.address)
        await ap.connect(timeout_s=5.0)
        comp = GcsComponent(GcsConfig(status_rate_hz=5.0), ap, command)
        try:
            gcs.heartbeat()
            assert comp.open() and comp.ids == (1, 191)
            comp.on_events([MissionEvent(0.0, EventKind.ABORT, Phase.OUTBOUND, "battery " + "low " * 20)])
            t0 = time.monotonic()
            sent_rtl = sent_hold = False
            while time.monotonic() - t0 < 6.0:
                gcs.heartbeat()
                gcs.drain()
                if gcs.from_(1, 191, "HEARTBEAT") and not sent_rtl:
                    gcs.send(gcs.enc.command_long_encode(1, 191, 20, 0, 0, 0, 0, 0, 0, 0, 0))
                    sent_rtl = True
                elif sent_rtl and not sent_hold and gcs.from_(1, 191, "COMMAND_ACK"):
                    gcs.send(gcs.enc.command_long_encode(1, 191, 17, 0, 0, 0, 0, 0, 0, 0, 0))
                    gcs.send(gcs.enc.command_long_encode(1, 191, 400, 0, 1, 0, 0, 0, 0, 0, 0))
                    sent_hold = True
                if len(gcs.from_(1, 191, "COMMAND_ACK")) >= 3 and gcs.from_(1, 191, "ONBOARD_COMPUTER_STATUS"):
                    break
                await asyncio.sleep(0.05)
        finally:
            await comp.close()
            await ap.close()
    hb = gcs.from_(1, 191, "HEARTBEAT")
    assert hb and hb[0].type == mavlink.MAV_TYPE_ONBOARD_CONTROLLER and hb[0].autopilot == mavlink.MAV_AUTOPILOT_INVALID
    texts = [(m.severity, m.text, m.id, m.chunk_seq) for m in gcs.from_(1, 191, "STATUSTEXT")]
    assert any(t[1] == "companion component 191 up" for t in texts), texts
    abort = [t for t in texts if t[2] != 0]  # the long abort text, in chunks with one id
    assert [t[3] for t in abort] == [0, 1] and all(t[0] == 4 for t in abort)
    assert "".join(t[1] for t in abort).startswith("abort: battery low")
    acks = [(m.command, m.result, m.target_system, m.target_component) for m in gcs.from_(1, 191, "COMMAND_ACK")]
    assert acks == [(20, 0, 255, 190), (17, 1, 255, 190), (400, 3, 255, 190)], acks
    assert asked == [(CommandKind.RETURN, "gcs"), (CommandKind.HOLD, "gcs")]
    # the mission's reply follows each answer: NOTICE when it acted, WARNING when not
    assert (5, "returning home along the path") in [t[:2] for t in texts]
    assert (4, "ignored: cannot hold from preflight") in [t[:2] for t in texts]
    status = gcs.from_(1, 191, "ONBOARD_COMPUTER_STATUS")[-1]
    assert status.uptime > 0 and status.ram_total > 0
    # the vehicle itself acted on none of it (addressed to the companion)
    assert sim.stats.commands[20] == 0 and sim.stats.commands[17] == 0
    assert status.time_usec > 1.6e15  # the Unix clock, microseconds


class _Forger(_Gcs):
    """Someone else on the link: speaks as whatever (system, component) it likes."""

    def as_(self, sysid: int, compid: int) -> _Forger:
        self.enc = mavlink.MAVLink(None, srcSystem=sysid, srcComponent=compid)
        return self


# what a forger claims: the vehicle in companion control, armed (each dialect's custom mode)
_FORGED_HEARTBEAT = {
    "px4": (mavlink.MAV_AUTOPILOT_PX4, 6 << 16),  # OFFBOARD
    "ardupilot": (mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, 4),  # GUIDED
}


@pytest.mark.parametrize("dialect", ["px4", "ardupilot"])
async def test_commands_and_heartbeats_from_anyone_else_change_nothing(mav, udp_port, dialect, caplog):
    """On the sim vehicle's routed link: a COMMAND_LONG RTL to 1/191 from system 200 reaches the
    companion but not the mission (refused, counted, logged, not answered), while the same from the
    GCS (255) does; HEARTBEATs claiming an armed vehicle in companion control from (1, 190) and
    from (2, 1) never change the vehicle's mode or armed state as the backend reports them."""
    config = mav.short_config()
    asked: list[tuple[CommandKind, str]] = []

    def command(kind: CommandKind, sender: str) -> CommandReply:
        asked.append((kind, sender))
        return CommandReply(CommandOutcome.ACCEPTED, "returning home along the path")

    with mav.sim_vehicle(config, dialect, udp_port, route_peers=True) as sim:
        if dialect == "px4":
            ap = Px4Autopilot(f"udpin://127.0.0.1:{udp_port}", component_id=191)
        else:
            ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{udp_port}")
        gcs, forger = _Gcs(sim.address), _Forger(sim.address)
        await ap.connect(timeout_s=5.0)
        comp = GcsComponent(GcsConfig(), ap, command)
        autopilot_type, custom_mode = _FORGED_HEARTBEAT[dialect]
        seen: list[tuple[str, bool]] = []
        forged = 0
        try:
            assert comp.open()
            await mav.wait_for(
                lambda: ap.telemetry.status is not None and ap.telemetry.status.mode.value != "unknown",
                5.0,
                "the vehicle's mode",
            )
            real_mode = ap.telemetry.status.mode
            assert real_mode.value not in ("offboard", "unknown") and not ap.telemetry.status.armed
            t0 = time.monotonic()
            while time.monotonic() - t0 < 3.0:  # 3 of the vehicle's heartbeats, 30 forged of each
                gcs.heartbeat()
                forger.heartbeat()  # a GCS heartbeat from 200 (as a forger would look)
                for ids in ((1, 190), (2, 1)):
                    hb = forger.as_(*ids).enc.heartbeat_encode(
                        mavlink.MAV_TYPE_QUADROTOR,
                        autopilot_type,
                        mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED | mavlink.MAV_MODE_FLAG_SAFETY_ARMED,
                        custom_mode,
                        mavlink.MAV_STATE_ACTIVE,
                    )
                    forger.send(hb)
                forger.as_(200, 190).send(forger.enc.command_long_encode(1, 191, 20, 0, 0, 0, 0, 0, 0, 0, 0))
                forged += 1
                gcs.drain()
                forger.drain()
                st = ap.telemetry.status
                seen.append((st.mode.value, st.armed))
                await asyncio.sleep(0.1)
            await mav.wait_for(lambda: comp.refused == forged, 2.0, "every forged command refused")
            gcs.send(gcs.enc.command_long_encode(1, 191, 20, 0, 0, 0, 0, 0, 0, 0, 0))
            await mav.wait_for(lambda: asked, 3.0, "the GCS's RTL to reach the mission")
            for _ in range(10):
                gcs.drain()
                forger.drain()
                await asyncio.sleep(0.05)
        finally:
            await comp.close()
            await ap.close()
    assert set(seen) == {(real_mode.value, False)}, set(seen)
    assert asked == [(CommandKind.RETURN, "gcs")]  # the GCS's, not system 200's
    assert forged >= 20 and comp.refused == forged and comp.refused_by_system == {200: forged}
    assert [(m.command, m.result) for m in gcs.from_(1, 191, "COMMAND_ACK")] == [(20, MAV_RESULT_ACCEPTED)]
    assert not [m for m in forger.got if m.get_type() == "COMMAND_ACK" and m.target_system == 200]
    said = [r.getMessage() for r in caplog.records if "refused" in r.getMessage() and "system 200" in r.getMessage()]
    assert len(said) == 2, said  # sampled: the first and the 10th
    # counted: (1, 190)'s, and (2, 1)'s where the backend hears another system (the GCS's and 200's
    # are GCS heartbeats, not counted)
    print(f"\n{dialect}: {forged} forged of each, {ap.foreign_heartbeats} foreign autopilot heartbeats counted")
    assert ap.foreign_heartbeats >= forged - 2


class _Link:
    """The component side of a backend, recording what the component sends; ``deliver`` hands a
    command over as the backend's reader would."""

    def __init__(self) -> None:
        self.sent: list[tuple[str, dict]] = []
        self.on_command = None

    def open_component(self, component_id: int, system_id: int, on_command) -> tuple[int, int]:
        self.on_command = on_command
        return 1, component_id

    def send_from_component(self, name: str, fields: dict) -> bool:
        self.sent.append((name, fields))
        return True

    def close_component(self) -> None:
        self.on_command = None


@pytest.mark.parametrize(
    ("source_system", "signed", "acted"),
    [
        (255, None, True),
        (255, True, True),
        (255, False, False),
        (200, None, False),
        (200, True, False),
        (42, None, True),
    ],
)
async def test_only_configured_systems_and_signed_commands_on_a_signed_link_reach_the_mission(
    source_system, signed, acted
):
    asked: list[CommandKind] = []
    link = _Link()
    comp = GcsComponent(
        GcsConfig(command_system_ids=(255, 42)),
        link,
        lambda kind, sender: asked.append(kind) or CommandReply(CommandOutcome.ACCEPTED, "ok"),
    )
    assert comp.open()
    try:
        link.on_command(ComponentCommand(0.0, source_system, 190, 20, 0, (0.0,) * 7, signed))
    finally:
        await comp.close()
    acks = [f for name, f in link.sent if name == "COMMAND_ACK"]
    assert (asked == [CommandKind.RETURN]) is acted and (len(acks) == 1) is acted
    assert comp.refused == (0 if acted else 1)

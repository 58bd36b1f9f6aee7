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


def test_relay_keeps_the_commands_the_companion_sent_to_the_autopilot():
    from pymavlink import mavutil

    mav = mavutil.mavlink.MAVLink(None, srcSystem=255, srcComponent=190)
    mav.robust_parsing = True
    grip = mav.command_long_encode(1, 1, 211, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav)  # DO_GRIPPER release
    arm = mav.command_int_encode(1, 1, 0, 400, 0, 0, 1, 0, 0, 0, 0, 0, 0).pack(mav)  # ARM_DISARM
    hb = mav.heartbeat_encode(18, 8, 0, 0, 0).pack(mav)
    autopilot, companion = _sock(), _sock()
    listen = _sock()
    port = listen.getsockname()[1]
    listen.close()
    with UdpRelay(port, companion.getsockname()[1], watch_commands=True) as relay:
        autopilot.sendto(grip, ("127.0.0.1", port))  # from the autopilot's side: not the companion's command
        _, back = companion.recvfrom(300)
        for packet in (hb, grip, arm, b"\xfd\x00garbage"):
            companion.sendto(packet, back)
            autopilot.recvfrom(300)
        relay.cut(1.0)
        companion.sendto(grip, back)  # dropped: never reached the autopilot
        deadline = time.monotonic() + 1.0
        while relay.dropped < 1 and time.monotonic() < deadline:
            time.sleep(0.01)
        assert [c for _, c in relay.commands_to_autopilot] == [211, 400]
    autopilot.close()
    companion.close()


def test_fly_params_lay_the_short_mission_over_a_shipped_file(tmp_path):
    from companion.config import shipped_params_path
    from companion_firmware.companion_kill import SHORT_MISSION, write_fly_params
    from companion_sitl.params import load_simulated_config

    shipped = load_simulated_config(shipped_params_path("ardupilot_quad.toml"))
    path = write_fly_params(shipped_params_path("ardupilot_quad.toml"), tmp_path / "f.toml", {"mission": SHORT_MISSION})
    cfg = load_simulated_config(path)
    assert (cfg.mission.pad.north_m, cfg.mission.pad.east_m, cfg.mission.height_m) == (14.0, 14.0, 8.0)
    # everything else is what ships
    assert cfg.runtime == shipped.runtime and cfg.limits == shipped.limits and cfg.payload == shipped.payload
    assert cfg.mission.land_speed_m_s == shipped.mission.land_speed_m_s and cfg.connection == shipped.connection

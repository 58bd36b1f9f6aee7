"""TCP and serial links, not just UDP: the MAVLink sim vehicle is reached through a byte relay
(a TCP server, or a pseudo-terminal standing in for the autopilot's UART), and each backend
connects, sees telemetry and gets its commands acknowledged across it."""

from __future__ import annotations

import contextlib
import os
import select
import socket
import threading
import tty

import pytest

from companion.autopilot import LandedState
from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.px4 import Px4Autopilot

pytestmark = pytest.mark.flight


class Relay(threading.Thread):
    """Copies bytes both ways between a stream (TCP connection or pty master) and the vehicle's
    UDP endpoint, in whatever chunks they arrive (MAVLink frames may be split or merged)."""

    def __init__(self, udp_port: int, vehicle_addr_fn):
        super().__init__(daemon=True, name="relay")
        self.udp = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        self.udp.bind(("127.0.0.1", udp_port))
        self.vehicle_addr_fn = vehicle_addr_fn
        self.stop_evt = threading.Event()
        self.bytes_up = self.bytes_down = 0
        self.read_stream = self.write_stream = None  # callables set by the subclass set-up
        self.stream_fd = None

    def run(self) -> None:
        while not self.stop_evt.is_set():
            fds = [self.udp] + ([self.stream_fd] if self.stream_fd is not None else [])
            r, _, _ = select.select(fds, [], [], 0.05)
            for f in r:
                if f is self.udp:
                    data = self.udp.recv(65535)
                    if self.write_stream is not None:
                        with contextlib.suppress(OSError):
                            self.write_stream(data)
                            self.bytes_down += len(data)
                else:
                    try:
                        data = self.read_stream()
                    except OSError:
                        data = b""
                    if data:
                        self.udp.sendto(data, self.vehicle_addr_fn())
                        self.bytes_up += len(data)

    def stop(self) -> None:
        self.stop_evt.set()
        self.join(2.0)
        self.udp.close()


@contextlib.contextmanager
def tcp_relay(mav, sim, udp_port):
    srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    srv.bind(("127.0.0.1", 0))
    srv.listen(1)
    relay = Relay(udp_port, lambda: sim.address)

    def accept():
        conn, _ = srv.accept()
        relay.read_stream = lambda: conn.recv(4096)
        relay.write_stream = conn.sendall
        relay.stream_fd = conn

    t = threading.Thread(target=accept, daemon=True)
    t.start()
    relay.start()
    try:
        yield srv.getsockname()[1], relay
    finally:
        relay.stop()
        srv.close()


@contextlib.contextmanager
def pty_relay(sim, udp_port):
    master, slave = os.openpty()
    tty.setraw(slave)
    relay = Relay(udp_port, lambda: sim.address)
    relay.read_stream = lambda: os.read(master, 4096)
    relay.write_stream = lambda b: os.write(master, b)
    relay.stream_fd = master
    relay.start()
    try:
        yield os.ttyname(slave), relay
    finally:
        relay.stop()
        os.close(master)
        os.close(slave)


async def _exercise(ap, mav, sim, relay=None) -> None:
    """connect, telemetry, an acknowledged command each way (arm, disarm); with ``relay``, until
    more than a few messages went each way through it (a fast run on a loaded machine can finish
    the commands within the first kilobyte)."""
    try:
        await ap.connect(timeout_s=15.0)
        await mav.wait_for(lambda: ap.telemetry.position_ned is not None, 10.0, "local position")
        await mav.wait_for(lambda: ap.telemetry.status is not None and ap.telemetry.status.healthy, 15.0, "healthy")
        await ap.arm()
        await mav.wait_for(lambda: sim.vehicle.armed, 5.0, "vehicle armed")
        await ap.disarm()
        await mav.wait_for(lambda: not sim.vehicle.armed, 5.0, "vehicle disarmed")
        # EXTENDED_SYS_STATE streams at its own rate after the intervals are requested
        await mav.wait_for(lambda: ap.telemetry.status.landed is LandedState.ON_GROUND, 5.0, "landed state reported")
        assert ap.link_ok
        if relay is not None:
            await mav.wait_for(
                lambda: relay.bytes_up > 100 and relay.bytes_down > 1000, 5.0, "traffic through the relay"
            )
    finally:
        await ap.close()


@pytest.mark.parametrize("dialect", ["px4", "ardupilot"])
async def test_tcp_link(mav, udp_port, dialect):
    config = mav.short_config()
    with (
        mav.sim_vehicle(config, dialect, udp_port, ekf_delay_s=1.0) as sim,
        tcp_relay(mav, sim, udp_port) as (
            port,
            relay,
        ),
    ):
        ap = (
            Px4Autopilot(f"tcpout://127.0.0.1:{port}")
            if dialect == "px4"
            else ArduPilotAutopilot(f"tcpout://127.0.0.1:{port}")
        )
        await _exercise(ap, mav, sim, relay)
    assert relay.bytes_up > 100 and relay.bytes_down > 1000
    assert sim.stats.bad_data == 0


@pytest.mark.parametrize("dialect", ["px4", "ardupilot"])
async def test_serial_link_over_a_pseudo_terminal(mav, udp_port, dialect):
    config = mav.short_config()
    with (
        mav.sim_vehicle(config, dialect, udp_port, ekf_delay_s=1.0) as sim,
        pty_relay(sim, udp_port) as (
            dev,
            relay,
        ),
    ):
        ap = (
            Px4Autopilot(f"serial://{dev}:921600") if dialect == "px4" else ArduPilotAutopilot(f"serial://{dev}:921600")
        )
        await _exercise(ap, mav, sim, relay)
    assert relay.bytes_up > 100 and relay.bytes_down > 1000

"""``companion_plugins.mavproxy_companion`` in a real MAVProxy against a pymavlink peer playing the
vehicle (1/1) and the companion (1/191) (docs/gcs.md, "In MAVProxy"): MAVProxy keeps targeting
1/1, the module prints the companion's texts (a chunked one joined) and ACK, and ``companion land``
goes to 1/191. The flight on real ArduCopter: tests/real_ardupilot/test_arducopter_mavproxy.py."""

from __future__ import annotations

import importlib.util
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest
from pymavlink import mavutil

from companion_sitl.mavlink.link import free_udp_port

pytestmark = pytest.mark.skipif(importlib.util.find_spec("MAVProxy") is None, reason="MAVProxy is not installed")

LONG = "abort: the pad is not clear: an obstacle on the pad, holding at the approach point"


def test_mavproxy_module_prints_the_companion_and_commands_it(tmp_path: Path) -> None:
    port = free_udp_port()
    script = Path(sys.executable).with_name("mavproxy.py")
    argv = [sys.executable, "-u", str(script), f"--master=udpin:127.0.0.1:{port}", "--nowait"]
    argv += [
        f"--state-basedir={tmp_path}",
        "--default-modules=cmdlong",
        "--cmd=module load companion_plugins.mavproxy_companion",
    ]
    proc = subprocess.Popen(
        argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, cwd=tmp_path
    )
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(proc.stdout or []), daemon=True)
    reader.start()
    peer = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1)
    mav = peer.mav

    def as_companion(send) -> None:
        mav.srcComponent = 191
        try:
            send()
        finally:
            mav.srcComponent = 1

    def beat() -> None:
        mav.heartbeat_send(2, 3, 0, 0, 4)  # QUADROTOR, ARDUPILOTMEGA: the vehicle
        as_companion(lambda: mav.heartbeat_send(18, 8, 0, 0, 4))  # ONBOARD_CONTROLLER, INVALID

    def printed(text: str) -> bool:
        return any(text in line for line in list(lines))

    def until(cond, what: str, timeout_s: float = 20.0) -> None:
        t0 = time.monotonic()
        while not cond():
            assert time.monotonic() - t0 < timeout_s, f"{what}; MAVProxy printed:\n{''.join(lines)}"
            beat()
            time.sleep(0.2)

    try:
        until(lambda: printed("companion: component 1/191 online"), "the companion never came online")
        as_companion(lambda: mav.statustext_send(6, b"phase outbound", 0, 0))
        chunks = [LONG[i : i + 50] for i in range(0, len(LONG), 50)]
        for seq, chunk in enumerate(chunks):
            as_companion(lambda c=chunk, s=seq: mav.statustext_send(4, c.encode(), 7, s))
        mav.statustext_send(6, b"EKF3 IMU0 is using GPS", 0, 0)  # the autopilot's own, MAVProxy's AP: line
        until(lambda: printed(f"companion: {LONG}") and printed("companion: phase outbound"), "no companion texts")
        until(lambda: printed("AP: EKF3 IMU0 is using GPS"), "the autopilot's text not printed")
        assert not printed("AP: phase outbound")

        assert proc.stdin is not None
        proc.stdin.write("companion land\n")
        proc.stdin.flush()
        t0 = time.monotonic()
        cmd = None
        while cmd is None and time.monotonic() - t0 < 10.0:
            beat()
            cmd = peer.recv_match(type="COMMAND_LONG", blocking=True, timeout=0.3)
        assert cmd is not None, "".join(lines)
        assert (cmd.target_system, cmd.target_component, cmd.command) == (1, 191, 21)  # NAV_LAND
        as_companion(lambda: mav.command_ack_send(21, 0, 0, 0, cmd.get_srcSystem(), cmd.get_srcComponent()))
        until(lambda: printed("companion: land ACCEPTED"), "the ACK was not printed")
    finally:
        proc.terminate()
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait(10)
        peer.close()

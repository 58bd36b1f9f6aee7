"""The truth link's PX4 shell line (MavlinkTruth.shell, the GNSS-loss harness's ``sensor_gps_sim
stop``): sent once as SERIAL_CONTROL to the shell device, answered by the output up to the prompt,
over a loopback UDP link with a peer that answers as PX4's MAVLink shell does."""

from __future__ import annotations

import threading
import time

import pytest
from pymavlink import mavutil

from companion_firmware.truth_feed import SERIAL_CONTROL_DEV_SHELL, MavlinkTruth
from companion_sitl.mavlink.link import free_udp_port


def _px4_shell_peer(port: int, stop: threading.Event, lines: list[bytes], answer: bool) -> None:
    conn = mavutil.mavlink_connection(f"udpout:127.0.0.1:{port}", source_system=1, source_component=1)
    last_hb = 0.0
    while not stop.is_set():
        if time.monotonic() - last_hb > 0.2:
            conn.mav.heartbeat_send(2, 12, 0, 0, 0)
            last_hb = time.monotonic()
        m = conn.recv_match(type="SERIAL_CONTROL", blocking=True, timeout=0.05)
        if m is None or m.device != SERIAL_CONTROL_DEV_SHELL:
            continue
        line = bytes(m.data[: m.count])
        lines.append(line)
        if answer:  # PX4 echoes the line, prints, then the prompt, in pieces
            for piece in (line, b"INFO  [gps] stopped\n", b"pxh> "):
                data = list(piece.ljust(70, b"\0"))
                conn.mav.serial_control_send(SERIAL_CONTROL_DEV_SHELL, 0, 0, 0, len(piece), data)
    conn.close()


@pytest.mark.parametrize("answer", [True, False])
def test_a_shell_line_goes_once_and_returns_the_output_to_the_prompt(answer: bool) -> None:
    port = free_udp_port()
    stop, lines = threading.Event(), list[bytes]()
    truth = MavlinkTruth(f"udpin:127.0.0.1:{port}")
    with truth:
        peer = threading.Thread(target=_px4_shell_peer, args=(port, stop, lines, answer), daemon=True)
        peer.start()
        try:
            t_end = time.monotonic() + 5.0
            while truth._target is None and time.monotonic() < t_end:
                time.sleep(0.02)
            if answer:
                out = truth.shell("sensor_gps_sim stop")
                assert "stopped" in out and out.rstrip().endswith("pxh>")
            else:
                with pytest.raises(TimeoutError, match="sensor_gps_sim stop"):
                    truth.shell("sensor_gps_sim stop", timeout_s=1.2)
            assert lines == [b"sensor_gps_sim stop\n"]  # once, never resent
            with pytest.raises(ValueError, match="70"):
                truth.shell("x" * 80)
        finally:
            stop.set()
            peer.join(2.0)

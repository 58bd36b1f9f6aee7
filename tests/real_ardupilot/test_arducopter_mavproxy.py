"""On a real ArduCopter SITL with a real MAVProxy on SERIAL2 (as an operator runs it) and the
companion on SERIAL0: MAVProxy, left targeting the autopilot (1/1), prints the companion's
STATUSTEXTs through our module (``companion_plugins.mavproxy_companion``): a delivery's phases,
``delivered`` and return; then, on a second flight, the operator's ``companion return`` typed into
MAVProxy reaches the companion (1/191) and brings the vehicle home (docs/gcs.md, "In MAVProxy").
Skipped without MAVProxy (it is in the ``test`` extra)."""

from __future__ import annotations

import asyncio
import contextlib
import importlib.util
import math
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.delivery.shell import DeliveryShell
from companion.events import Phase
from companion_firmware.ardupilot_sitl import ArduCopterSitl
from companion_sitl.mavlink.link import free_udp_port

from .conftest import GRIPPER_SERVO9

pytestmark = [
    pytest.mark.firmware,
    pytest.mark.skipif(importlib.util.find_spec("MAVProxy") is None, reason="MAVProxy is not installed"),
]


class MavProxy:
    """``mavproxy.py`` as a subprocess on ``udpin:127.0.0.1:port``, our module loaded; its stdout
    collected line by line, commands written to its stdin as the operator types them."""

    def __init__(self, port: int, folder: Path) -> None:
        self.lines: list[str] = []
        self._lock = threading.Lock()
        script = Path(sys.executable).with_name("mavproxy.py")
        argv = [sys.executable, "-u", str(script), f"--master=udpin:127.0.0.1:{port}", "--nowait"]
        argv += [f"--state-basedir={folder}", "--cmd=module load companion_plugins.mavproxy_companion"]
        self.proc = subprocess.Popen(
            argv,
            stdin=subprocess.PIPE,
            stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT,
            text=True,
            cwd=folder,
            start_new_session=True,  # its own process group: MAVProxy's forked helpers go with it
        )
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            with self._lock:
                self.lines.append(line.rstrip("\n"))

    def type(self, command: str) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write(command + "\n")
        self.proc.stdin.flush()

    def output(self) -> list[str]:
        with self._lock:
            return list(self.lines)

    def has(self, text: str) -> bool:
        return any(text in line for line in self.output())

    def __enter__(self) -> MavProxy:
        return self

    def __exit__(self, *exc: object) -> None:
        # the whole group: a process MAVProxy forked outlived the terminated one (seen after runs)
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.proc.pid, signal.SIGTERM)
        try:
            self.proc.wait(10)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(10)
        time.sleep(0.5)  # a forked helper may linger past its parent: the group is killed again
        with contextlib.suppress(ProcessLookupError):
            os.killpg(self.proc.pid, signal.SIGKILL)


async def _fly(config, on_tick=None) -> tuple[DeliveryShell, float]:
    """One companion flight; and how far from its take-off it landed."""
    ap = ArduPilotAutopilot.from_config(config, arm_timeout_s=30.0)
    shell = DeliveryShell(config, ap, on_tick=on_tick)
    try:
        await shell.run(timeout_s=300.0)
        pos, start = ap.telemetry.position_ned, shell.mission.start_ned
        home_error = (
            math.hypot(pos.north_m - start[0], pos.east_m - start[1])
            if pos is not None and start is not None
            else math.inf
        )
    finally:
        await ap.close()
    return shell, home_error


async def _printed(proxy: MavProxy, text: str, timeout_s: float = 10.0) -> bool:
    """The last texts are on their way through ArduPilot and MAVProxy when a flight ends."""
    deadline = time.monotonic() + timeout_s
    while not proxy.has(text) and time.monotonic() < deadline:
        await asyncio.sleep(0.2)
    return proxy.has(text)


async def test_mavproxy_prints_the_companion_and_returns_it(ardupilot_root, tmp_path, mav):
    gcs_port = free_udp_port()
    sitl = ArduCopterSitl(
        ardupilot_root,
        extra_params=dict(GRIPPER_SERVO9),
        serials={2: f"udpclient:127.0.0.1:{gcs_port}"},
        log_path=tmp_path / "arducopter.log",
    )
    t0 = time.monotonic()
    with sitl, MavProxy(gcs_port, tmp_path) as proxy:
        config = mav.firmware_config("ardupilot", sitl.connection, 120.0)  # EKF3 uses GPS ~41 s after boot
        # flight 1: a delivery, watched in MAVProxy
        delivery, delivery_home_error = await _fly(config)
        assert await _printed(proxy, "companion: mission done"), proxy.output()[-40:]
        after_delivery = len(proxy.output())

        # flight 2, same SITL: the operator returns it from MAVProxy on the way out
        sent: list[float] = []

        def tick(sh: DeliveryShell, out) -> None:
            if out.phase is Phase.OUTBOUND and sh.mission.sector >= 2 and not sent:
                sent.append(time.monotonic())
                proxy.type("companion return")  # what the operator types; MAVProxy still targets 1/1

        shell, home_error = await _fly(config, tick)
        await _printed(proxy, "companion: mission ended")
        out = proxy.output()
    (tmp_path / "mavproxy.out").write_text("\n".join(out) + "\n")
    mine = [line for line in out if "companion:" in line]
    print(f"\n{time.monotonic() - t0:.0f} s; MAVProxy printed {len(mine)} companion lines:\n" + "\n".join(mine))

    d = delivery.mission.summary
    assert d.delivered and d.returned and not d.failure, d
    assert delivery_home_error < 1.5, delivery_home_error
    first = out[:after_delivery]
    for text in (
        "companion: component 1/191 online",
        "companion: phase outbound",
        "companion: phase landing_pad",
        "companion: delivered: parcel released on the pad",
        "companion: phase inbound",
        "companion: returned",
        "companion: mission done: delivered, home",
    ):
        assert any(text in line for line in first), (text, mine)

    assert sent, "the flight never reached sector 2"
    s = shell.mission.summary
    assert s.returned and not s.delivered and s.failure == "returned on ground command", s
    assert home_error < 1.5, home_error
    second = out[after_delivery:]
    assert any("companion: phase outbound" in line for line in second), mine
    assert any("companion: return sent to 1/191" in line for line in second), mine
    assert any("companion: return ACCEPTED" in line for line in second), mine  # COMMAND_ACK from 1/191
    assert any("companion: warning: ground command from gcs: return" in line for line in second), mine
    assert any("companion: returned" in line for line in second), mine
    assert not any("companion: delivered" in line for line in second), mine
    # the autopilot's own texts still printed as MAVProxy's "AP:" (it still targets 1/1)
    assert any(line.startswith("AP: ") or " AP: " in line for line in out), out[-40:]
    # no second vehicle: the backend's own heartbeat from 255:191 is of type GCS
    detected = [line for line in out if "Detected vehicle" in line]
    assert not [line for line in detected if "Detected vehicle 255:" in line], detected

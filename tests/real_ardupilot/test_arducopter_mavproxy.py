"""On a real ArduCopter SITL with a real MAVProxy on SERIAL2 (as an operator runs it) and the
companion on SERIAL0: MAVProxy, left targeting the autopilot (1/1), prints the companion's
STATUSTEXTs through our module (``companion_plugins.mavproxy_companion``), and the operator's
``companion return`` typed into MAVProxy reaches the companion (1/191) and brings the vehicle home
(docs/gcs.md, "MAVProxy"). Skipped without MAVProxy (it is in the ``test`` extra)."""

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
        sent: list[float] = []

        def tick(sh: DeliveryShell, out) -> None:
            if out.phase is Phase.OUTBOUND and sh.mission.sector >= 2 and not sent:
                sent.append(time.monotonic())
                proxy.type("companion return")  # what the operator types; MAVProxy still targets 1/1

        ap = ArduPilotAutopilot.from_config(config, arm_timeout_s=30.0)
        shell = DeliveryShell(config, ap, on_tick=tick)
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
        deadline = time.monotonic() + 10.0  # the last texts on their way through ArduPilot and MAVProxy
        while not proxy.has("companion: mission ended") and time.monotonic() < deadline:
            await asyncio.sleep(0.2)
        out = proxy.output()
    (tmp_path / "mavproxy.out").write_text("\n".join(out) + "\n")
    mine = [line for line in out if "companion:" in line]
    print(f"\n{time.monotonic() - t0:.0f} s; MAVProxy printed {len(mine)} companion lines:\n" + "\n".join(mine))

    assert sent, "the flight never reached sector 2"
    s = shell.mission.summary
    assert s.returned and not s.delivered and s.failure == "returned on ground command", s
    assert home_error < 1.5, home_error
    assert any("companion: component 1/191 online" in line for line in out), mine
    assert any("companion: phase outbound" in line for line in out), mine
    assert any("companion: return sent to 1/191" in line for line in out), mine
    assert any("companion: return ACCEPTED" in line for line in out), mine  # COMMAND_ACK from 1/191
    assert any("companion: warning: ground command from gcs: return" in line for line in out), mine
    assert any("companion: returned" in line for line in out), mine
    # the autopilot's own texts still printed as MAVProxy's "AP:" (it still targets 1/1)
    assert any(line.startswith("AP: ") or " AP: " in line for line in out), out[-40:]
    # no second vehicle: the backend's own heartbeat from 255:191 is of type GCS
    detected = [line for line in out if "Detected vehicle" in line]
    assert not [line for line in detected if "Detected vehicle 255:" in line], detected

"""Start a built PX4 SITL (SIH quad, headless) and stop it cleanly. Never builds PX4.

The build is looked up in ``$PX4_DIR`` else ``~/PX4-Autopilot``:
``build/px4_sitl_default/bin/px4`` run with ``-d`` and the build's ``etc`` as data directory from
``rootfs/<instance>`` (parameters cleared first unless ``clean=False``) and
``PX4_SIM_MODEL=sihsim_quadx``; ``params`` are set at boot through the SITL's ``PX4_PARAM_<name>``
environment variables (rcS sets them after the airframe's defaults). PX4 then sends MAVLink to
udp 14540 (the onboard/offboard link).
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import socket
import subprocess
import time
from dataclasses import dataclass, field
from pathlib import Path

log = logging.getLogger(__name__)

OFFBOARD_PORT = 14540


class Px4NotFound(RuntimeError):
    """No PX4 SITL build was found (the reason says where it looked)."""


def find_px4(px4_dir: str | os.PathLike[str] | None = None) -> Path:
    """The PX4 source tree holding a built SITL binary, or :class:`Px4NotFound`."""
    root = Path(px4_dir or os.environ.get("PX4_DIR") or Path.home() / "PX4-Autopilot").expanduser()
    binary = root / "build" / "px4_sitl_default" / "bin" / "px4"
    if not binary.is_file():
        raise Px4NotFound(f"no PX4 SITL build at {binary} (set PX4_DIR to a PX4 tree with a built SITL)")
    return root


@dataclass
class Px4Sitl:
    """A running PX4 SITL process (SIH quad). Use as a context manager."""

    root: Path
    model: str = "sihsim_quadx"
    instance: int = 0
    log_path: Path | None = None
    clean: bool = True
    params: dict[str, float] = field(default_factory=dict)
    proc: subprocess.Popen[bytes] | None = None

    @property
    def build_dir(self) -> Path:
        return self.root / "build" / "px4_sitl_default"

    def start(self, heartbeat_timeout_s: float = 20.0) -> Px4Sitl:
        port = OFFBOARD_PORT + self.instance
        if wait_for_heartbeat(port, 1.2):  # PX4 heartbeats at 1 Hz
            raise RuntimeError(
                f"an autopilot is already sending heartbeats to udp {port} (a PX4 SITL left running?): "
                f"stop it first (pkill -f 'px4 -d'); a second PX4 instance {self.instance} would only attach to it"
            )
        rootfs = self.build_dir / "rootfs" / str(self.instance)
        rootfs.mkdir(parents=True, exist_ok=True)
        if self.clean:
            # parameters and mission storage persist between runs: start as a fresh vehicle
            for name in ("parameters.bson", "parameters_backup.bson", "dataman"):
                (rootfs / name).unlink(missing_ok=True)
        env = dict(os.environ, PX4_SIM_MODEL=self.model, HEADLESS="1")
        env.update({f"PX4_PARAM_{name}": f"{value:g}" for name, value in self.params.items()})
        out = open(self.log_path, "wb") if self.log_path else subprocess.DEVNULL  # noqa: SIM115
        self.proc = subprocess.Popen(
            # the data directory argument makes px4 link rootfs/etc to the build's etc
            [str(self.build_dir / "bin" / "px4"), "-d", "-i", str(self.instance), str(self.build_dir / "etc")],
            cwd=rootfs,
            env=env,
            stdin=subprocess.DEVNULL,
            stdout=out,
            stderr=subprocess.STDOUT,
            start_new_session=True,
        )
        log.info("PX4 SITL pid %d (%s) in %s", self.proc.pid, self.model, rootfs)
        if not wait_for_heartbeat(OFFBOARD_PORT + self.instance, heartbeat_timeout_s):
            self.stop()
            raise TimeoutError(
                f"PX4 SITL sent no heartbeat to udp {OFFBOARD_PORT + self.instance} within {heartbeat_timeout_s} s"
            )
        return self

    def stop(self, timeout_s: float = 10.0) -> None:
        p, self.proc = self.proc, None
        stop_process_group(p, timeout_s)

    def __enter__(self) -> Px4Sitl:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def stop_process_group(p: subprocess.Popen[bytes] | None, timeout_s: float = 10.0) -> None:
    """SIGINT to a SITL's process group (PX4 and ArduCopter both shut down cleanly on it), then
    SIGKILL if it has not exited within ``timeout_s``."""
    if p is None or p.poll() is not None:
        return
    with contextlib.suppress(ProcessLookupError):
        os.killpg(p.pid, signal.SIGINT)
    try:
        p.wait(timeout_s)
    except subprocess.TimeoutExpired:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(p.pid, signal.SIGKILL)
        p.wait(5.0)


def wait_for_heartbeat(port: int, timeout_s: float) -> bool:
    """True once any MAVLink 2 packet with message id 0 arrives on udp ``port`` (loopback)."""
    end = time.monotonic() + timeout_s
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", port))
        while time.monotonic() < end:
            s.settimeout(max(0.05, end - time.monotonic()))
            try:
                data, _ = s.recvfrom(2048)
            except TimeoutError:
                return False
            if len(data) >= 10 and data[0] == 0xFD and data[7:10] == b"\x00\x00\x00":
                return True
    return False

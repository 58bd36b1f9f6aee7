"""Start a built ArduCopter SITL (its own physics, no MAVProxy) and stop it cleanly. Never builds
ArduPilot.

The build is looked up in ``$ARDUPILOT_DIR`` else ``~/ardupilot``: ``build/sitl/bin/arducopter``
with the defaults ``Tools/autotest/default_params/copter.parm``. Every start runs in a fresh
temporary directory (a clean ``eeprom.bin``, so no parameter survives from an earlier run) with
``--defaults copter.parm,<our extra parm file>``: parameters that need a reboot (GRIP_ENABLE,
PLND_ENABLED, SERVOn_FUNCTION, ...) are in place from boot. MAVLink: SERIAL0 on tcp
``5760 + 10 * instance`` (the companion's link); ``serials`` adds links, e.g.
``{1: "udpclient:127.0.0.1:14551"}`` for a ground-truth reader.

ArduCopter 4.7 SITL: first heartbeat ~1 s after start, streams nothing until message intervals
are requested, arms only once EKF3 uses GPS (~41 s after start, STATUSTEXT "EKF3 IMU0 is using
GPS"; :func:`wait_ekf_ready` waits for it).
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import socket
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

from companion_sitl.px4_sitl import stop_process_group

log = logging.getLogger(__name__)

SERIAL0_PORT = 5760
# ArduPilot's SITL default location (CMAC, Tools/autotest/locations.txt): lat, lon, alt AMSL, heading
CMAC_HOME = (-35.363261, 149.165230, 584.0, 353.0)


class ArduPilotNotFound(RuntimeError):
    """No ArduCopter SITL build was found (the reason says where it looked)."""


def find_ardupilot(ardupilot_dir: str | os.PathLike[str] | None = None) -> Path:
    """The ArduPilot source tree holding a built ArduCopter SITL, or :class:`ArduPilotNotFound`."""
    root = Path(ardupilot_dir or os.environ.get("ARDUPILOT_DIR") or Path.home() / "ardupilot").expanduser()
    binary = root / "build" / "sitl" / "bin" / "arducopter"
    defaults = root / "Tools" / "autotest" / "default_params" / "copter.parm"
    if not binary.is_file():
        raise ArduPilotNotFound(
            f"no ArduCopter SITL build at {binary} (set ARDUPILOT_DIR to an ArduPilot tree with a SITL "
            "build, made as ArduPilot's own SITL documentation says)"
        )
    if not defaults.is_file():
        raise ArduPilotNotFound(f"ArduPilot tree {root} has no {defaults.relative_to(root)}")
    return root


def write_parm_file(path: Path, params: dict[str, float]) -> Path:
    """A parameter file in ArduPilot's ``NAME VALUE`` format."""
    lines = []
    for name, value in params.items():
        if not name or not name.replace("_", "").isalnum() or len(name) > 16:
            raise ValueError(f"parameter name {name!r}: expected at most 16 letters, digits and underscores")
        if not math.isfinite(float(value)):
            raise ValueError(f"parameter {name} = {value!r} is not finite")
        lines.append(f"{name.upper()} {float(value):g}\n")
    path.write_text("".join(lines))
    return path


@dataclass
class ArduCopterSitl:
    """A running ArduCopter SITL process. Use as a context manager.

    ``extra_params`` override copter.parm from boot; ``serials`` maps a SERIALn number (1..9) to
    an ArduPilot device string (``udpclient:127.0.0.1:14551``, ``tcp:5762``, ...); ``home`` is
    lat, lon, alt AMSL, heading.
    """

    root: Path
    instance: int = 0
    model: str = "+"
    home: tuple[float, float, float, float] = CMAC_HOME
    speedup: float = 1.0
    extra_params: dict[str, float] = field(default_factory=dict)
    serials: dict[int, str] = field(default_factory=dict)
    log_path: Path | None = None
    keep_workdir: bool = False
    workdir: Path | None = None
    proc: subprocess.Popen[bytes] | None = None

    @property
    def binary(self) -> Path:
        return self.root / "build" / "sitl" / "bin" / "arducopter"

    @property
    def defaults(self) -> Path:
        return self.root / "Tools" / "autotest" / "default_params" / "copter.parm"

    @property
    def port(self) -> int:
        """SERIAL0's tcp port (the companion connects here)."""
        return SERIAL0_PORT + 10 * self.instance

    @property
    def connection(self) -> str:
        return f"tcp:127.0.0.1:{self.port}"

    def command(self) -> list[str]:
        assert self.workdir is not None
        defaults = [str(self.defaults)]
        if self.extra_params:
            defaults.append(str(write_parm_file(self.workdir / "companion-extra.parm", self.extra_params)))
        cmd = [
            str(self.binary),
            "--model",
            self.model,
            "--speedup",
            f"{self.speedup:g}",
            "--defaults",
            ",".join(defaults),
            "-I",
            str(self.instance),
            "--home",
            ",".join(f"{v:.7f}".rstrip("0").rstrip(".") for v in self.home),
        ]
        for n, dev in sorted(self.serials.items()):
            if not 1 <= n <= 9:
                raise ValueError(f"serial {n}: expected SERIAL1..SERIAL9 (SERIAL0 is the tcp link)")
            cmd += [f"--serial{n}", dev]
        return cmd

    def start(self, heartbeat_timeout_s: float = 20.0) -> ArduCopterSitl:
        self.workdir = Path(tempfile.mkdtemp(prefix="arducopter-"))  # clean eeprom.bin every start
        cmd = self.command()
        out = open(self.log_path, "wb") if self.log_path else subprocess.DEVNULL  # noqa: SIM115
        try:
            self.proc = subprocess.Popen(
                cmd,
                cwd=self.workdir,
                stdin=subprocess.DEVNULL,
                stdout=out,
                stderr=subprocess.STDOUT,
                start_new_session=True,
            )
        finally:
            if not isinstance(out, int):
                out.close()  # the child holds its own descriptor
        log.info("ArduCopter SITL pid %d in %s: %s", self.proc.pid, self.workdir, " ".join(cmd))
        if not wait_for_tcp_heartbeat(self.port, heartbeat_timeout_s, self.proc):
            code = self.proc.poll()
            self.stop()
            raise TimeoutError(
                f"ArduCopter SITL sent no heartbeat on tcp {self.port} within {heartbeat_timeout_s} s"
                + (f" (exited with {code}; see {self.log_path})" if code is not None else "")
            )
        return self

    def stop(self, timeout_s: float = 10.0) -> None:
        p, self.proc = self.proc, None
        stop_process_group(p, timeout_s)
        wd, self.workdir = self.workdir, None
        if wd is not None and not self.keep_workdir:
            shutil.rmtree(wd, ignore_errors=True)

    def __enter__(self) -> ArduCopterSitl:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


def _has_heartbeat(buf: bytes) -> bool:
    """A MAVLink 1 or 2 frame with message id 0 starts somewhere in ``buf``."""
    for i, b in enumerate(buf):
        if b == 0xFD and len(buf) >= i + 10 and buf[i + 7 : i + 10] == b"\x00\x00\x00":
            return True
        if b == 0xFE and len(buf) >= i + 6 and buf[i + 5] == 0 and buf[i + 1] == 9:
            return True
    return False


def wait_for_tcp_heartbeat(port: int, timeout_s: float, proc: subprocess.Popen[bytes] | None = None) -> bool:
    """True once a heartbeat arrives on tcp ``port`` (loopback); retries the connection while
    the SITL is still starting, gives up early when ``proc`` exits."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        if proc is not None and proc.poll() is not None:
            return False
        try:
            with socket.create_connection(("127.0.0.1", port), timeout=1.0) as s:
                buf = b""
                while time.monotonic() < end:
                    s.settimeout(max(0.05, min(1.0, end - time.monotonic())))
                    try:
                        data = s.recv(4096)
                    except TimeoutError:
                        continue
                    if not data:
                        break
                    buf = (buf + data)[-8192:]
                    if _has_heartbeat(buf):
                        return True
        except OSError:
            time.sleep(0.2)
    return False

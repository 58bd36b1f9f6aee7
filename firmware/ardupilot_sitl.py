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
are requested, arms only once EKF3 uses GPS (~41 s of simulated time after start, STATUSTEXT "EKF3
IMU0 is using GPS"). That wait is spent, as MAVProxy's ``sitl_autospeedup`` module spends it, at
``boot_speedup`` times real time: :meth:`ArduCopterSitl.start` boots the SITL with ``--speedup
boot_speedup``, waits on SERIAL0 for the pre-arm checks to pass and EKF3 to use GPS, then sets
``SIM_SPEEDUP`` back to ``speedup`` (read back) before anyone else connects. Everything after
start runs at ``speedup`` (1 = real time).
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

from pymavlink import mavutil
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion_firmware.px4_sitl import stop_process_group

log = logging.getLogger(__name__)

SERIAL0_PORT = 5760
# simulated seconds from start until ArduCopter 4.7 SITL is ready to arm (EKF3 uses GPS; measured
# 41.6 s, SYSTEM_TIME.time_boot_ms at the STATUSTEXT)
BOOT_SIM_S = 41.6
# a clock offset left by the boot above this is logged (companion preflight tolerates 2 s)
CLOCK_WARN_S = 1.0
# the speed drops this much before the SITL's UTC reaches the wall clock (the PARAM_SET's way there)
CLOCK_LEAD_S = 0.1
# the system id of the short link that watches the boot (a ground-station range id, not the companion's)
BOOT_LINK_SYSID = 250
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
        lines.append(f"{name.upper()} {float(value):.10g}\n")  # :g would round a bitmask >= 1e6
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
    boot_speedup: float = 10.0
    extra_params: dict[str, float] = field(default_factory=dict)
    serials: dict[int, str] = field(default_factory=dict)
    log_path: Path | None = None
    keep_workdir: bool = False
    workdir: Path | None = None
    # the SITL's UTC minus the wall clock after a fast boot (s); NaN when not measured
    clock_offset_s: float = math.nan
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
            f"{max(self.speedup, self.boot_speedup):g}",
            "--defaults",
            ",".join(defaults),
            "-I",
            str(self.instance),
            "--home",
            ",".join(f"{v:.7f}".rstrip("0").rstrip(".") for v in self.home),
        ]
        if self.boot_speedup > self.speedup:
            # the SITL's UTC is its start time plus simulated time: the boot at boot_speedup gains
            # about this much on the wall clock, so start it that much earlier (_boot_fast drops the
            # speed when the clock has caught up)
            gained_s = BOOT_SIM_S * (1.0 - self.speedup / self.boot_speedup)
            cmd += ["--start-time", str(round(time.time() - gained_s))]
        for n, dev in sorted(self.serials.items()):
            if not 1 <= n <= 9:
                raise ValueError(f"serial {n}: expected SERIAL1..SERIAL9 (SERIAL0 is the tcp link)")
            cmd += [f"--serial{n}", dev]
        return cmd

    def start(self, heartbeat_timeout_s: float = 20.0, ready_timeout_s: float = 60.0) -> ArduCopterSitl:
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
        if self.boot_speedup > self.speedup:
            try:
                waited = self._boot_fast(ready_timeout_s)
            except BaseException:
                self.stop()
                raise
            log.info(
                "ArduCopter SITL ready (pre-arm checks pass, EKF3 uses GPS) after %.1f s at %gx",
                waited,
                self.boot_speedup,
            )
        return self

    def _boot_fast(self, timeout_s: float) -> float:
        """Run at ``boot_speedup`` until the pre-arm checks pass and EKF3 uses GPS, and (at a
        target speed of 1) until the SITL's UTC has caught up with the wall clock, then put
        ``SIM_SPEEDUP`` back to ``speedup``; seconds waited. Raises :class:`TimeoutError` with the
        vehicle's last messages when it is not ready within ``timeout_s``.

        The SITL's UTC is ``--start-time`` plus simulated time. Started ``gained_s`` early (see
        :meth:`command`), it reads behind the wall clock until the fast boot has gained that much
        simulated time, and on time from then on: the speed drops when SYSTEM_TIME says so, so the
        clock is right whatever speed the machine managed (a slower boot just finishes at 1x)."""
        t0 = time.monotonic()
        link = mavutil.mavlink_connection(self.connection, source_system=BOOT_LINK_SYSID, source_component=0)
        try:
            if link.wait_heartbeat(timeout=5.0) is None:
                raise TimeoutError(f"ArduCopter SITL on tcp {self.port}: no heartbeat on the boot link")
            sysid, compid = link.target_system, link.target_component

            def interval(msg_id: int, us: int) -> None:
                link.mav.command_long_send(
                    sysid, compid, mavlink.MAV_CMD_SET_MESSAGE_INTERVAL, 0, msg_id, us, 0, 0, 0, 0, 0
                )

            # in simulated time: 50 ms at 10x is a message every 5 ms of wall time
            watched = (
                mavlink.MAVLINK_MSG_ID_SYS_STATUS,
                mavlink.MAVLINK_MSG_ID_SYSTEM_TIME,
                mavlink.MAVLINK_MSG_ID_EKF_STATUS_REPORT,
            )
            for msg_id in watched:
                interval(msg_id, 50_000)
            prearm = mavlink.MAV_SYS_STATUS_PREARM_CHECK
            prearm_ok, using_gps, clock_caught_up = False, False, False
            # the speed drop: not yet asked for, asked (PARAM_SET sent, repeated until read back), done
            drop_sent_at, dropped = math.nan, False
            said: list[str] = []
            while not (dropped and prearm_ok and using_gps):
                if time.monotonic() - t0 > timeout_s:
                    raise TimeoutError(
                        f"ArduCopter SITL not ready to arm within {timeout_s} s "
                        f"(pre-arm checks {'pass' if prearm_ok else 'fail'}, "
                        f"EKF3 {'uses' if using_gps else 'does not use'} GPS, "
                        f"speed {'back to' if dropped else 'not yet back to'} {self.speedup:g}x); "
                        f"it said: {' | '.join(said[-5:]) or 'nothing'}"
                    )
                if self.proc is None or self.proc.poll() is not None:
                    raise RuntimeError(f"ArduCopter SITL exited during boot (see {self.log_path})")
                # in real time the clock decides (still booting, the rest is at 1x); a SITL not in
                # real time has no clock to keep right, so readiness does
                due = clock_caught_up if self.speedup == 1.0 else prearm_ok and using_gps
                if due and not dropped and not time.monotonic() - drop_sent_at < 0.5:
                    link.mav.param_set_send(
                        sysid, compid, b"SIM_SPEEDUP", float(self.speedup), mavlink.MAV_PARAM_TYPE_REAL32
                    )
                    drop_sent_at = time.monotonic()
                # one receive for everything, so no message is dropped while waiting for another
                m = link.recv_match(
                    type=["SYS_STATUS", "STATUSTEXT", "SYSTEM_TIME", "EKF_STATUS_REPORT", "PARAM_VALUE"],
                    blocking=True,
                    timeout=0.1,
                )
                if m is None:
                    continue
                kind = m.get_type()
                if kind == "STATUSTEXT":
                    said.append(m.text)
                    using_gps = using_gps or "is using GPS" in m.text
                elif kind == "EKF_STATUS_REPORT":
                    # the filter has an absolute horizontal position: GPS is in use (the same moment
                    # as the STATUSTEXT, which a link can miss)
                    using_gps = using_gps or bool(m.flags & mavlink.EKF_POS_HORIZ_ABS)
                elif kind == "SYS_STATUS":
                    if m.onboard_control_sensors_present & prearm:
                        prearm_ok = bool(m.onboard_control_sensors_health & prearm)
                elif kind == "PARAM_VALUE":
                    if m.param_id == "SIM_SPEEDUP" and abs(m.param_value - self.speedup) < 1e-6:
                        dropped = True
                elif m.time_unix_usec > 0:
                    self.clock_offset_s = m.time_unix_usec * 1e-6 - time.time()
                    clock_caught_up = clock_caught_up or self.clock_offset_s >= -CLOCK_LEAD_S
            # back to the default rates on SERIAL0, for whoever connects next
            for msg_id in watched:
                interval(msg_id, 0)
            if abs(self.clock_offset_s) > CLOCK_WARN_S:
                log.warning(
                    "ArduCopter SITL's UTC is %+.1f s off the wall clock after its fast boot", self.clock_offset_s
                )
            return time.monotonic() - t0
        finally:
            link.close()

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

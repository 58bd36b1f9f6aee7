"""The companion dies in the descent: `companion fly` runs as its own process against a real SITL,
and when ground truth puts the vehicle over the pad at ``kill_height_m`` on the way down the whole
process group gets SIGKILL (no clean-up, no last message: a companion computer losing power). From
then on only the autopilot flies; this module watches it on a second link (the truth link) and
reports when it changed mode, touched down and disarmed, where it landed on truth and which
commands the companion had sent (through a :class:`UdpRelay` that decodes them).

Used by tests/real_px4/test_px4_companion_killed.py and
tests/real_ardupilot/test_arducopter_companion_killed.py (docs/flying.md, "Who is in control").
"""

from __future__ import annotations

import contextlib
import math
import os
import signal
import subprocess
import sys
import time
import tomllib
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from companion_firmware.truth_feed import MavlinkTruth
from companion_firmware.udp_relay import UdpRelay

# the release commands a companion can send (docs/flying.md, "Releasing the parcel")
MAV_CMD_DO_SET_SERVO = 183
MAV_CMD_DO_SET_ACTUATOR = 187
MAV_CMD_DO_GRIPPER = 211
RELEASE_COMMANDS = {
    MAV_CMD_DO_SET_SERVO: "DO_SET_SERVO",
    MAV_CMD_DO_SET_ACTUATOR: "DO_SET_ACTUATOR",
    MAV_CMD_DO_GRIPPER: "DO_GRIPPER",
}
MAV_MODE_FLAG_SAFETY_ARMED = 128

# The short delivery the real-firmware tests fly (params/sitl_short.toml's geometry: the pad ~20 m
# from home, 8 m up), laid over a firmware's shipped parameter file so that everything else (its
# failsafe-related runtime keys, release, limits) is what ships.
SHORT_MISSION = {
    "height_m": 8.0,
    "arc_radius_m": 2.0,
    "sector_speed_m_s": [2.5, 3.0, 5.0, 3.0, 2.0],
    "takeoff_alt_m": 2.5,
    "final_descent_alt_m": 2.0,
    "pad": {"north_m": 14.0, "east_m": 14.0, "size_m": 1.0},
}


def _toml_value(v: Any) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int | float):
        return repr(v)
    if isinstance(v, str):
        return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(v, list | tuple):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    raise TypeError(f"no TOML form for {v!r}")


def _toml_lines(table: dict[str, Any], prefix: str = "") -> list[str]:
    lines = [f"{k} = {_toml_value(v)}" for k, v in table.items() if not isinstance(v, dict)]
    for k, v in table.items():
        if isinstance(v, dict):
            name = f"{prefix}{k}"
            lines += ["", f"[{name}]", *_toml_lines(v, name + ".")]
    return lines


def merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        out[k] = merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def write_fly_params(shipped: Path, out: Path, overrides: dict[str, Any]) -> Path:
    """``shipped`` (a params/*.toml) with ``overrides`` laid over it, written to ``out``."""
    with shipped.open("rb") as f:
        data = merge(tomllib.load(f), overrides)
    out.write_text("\n".join(_toml_lines(data)) + "\n")
    return out


def _watch_landing(
    truth: MavlinkTruth,
    t_kill: float,
    kill_n: float,
    kill_e: float,
    land_timeout_s: float,
    proc: subprocess.Popen[bytes],
    how: str,
    stop_s: float,
) -> tuple[float | None, float | None, float, float]:
    """Truth until the autopilot disarms: (touchdown, disarmed) in s after the stop, the farthest
    drift from the stop point and the fastest sink below 1 m; a frozen companion thawed on time."""
    touchdown: float | None = None
    disarmed: float | None = None
    drift = 0.0
    sink = 0.0
    frozen = how == "freeze"
    t_end = t_kill + land_timeout_s
    while time.monotonic() < t_end:
        now = time.monotonic()
        if frozen and now - t_kill >= stop_s:
            os.killpg(proc.pid, signal.SIGCONT)
            frozen = False
        drift = max(drift, math.hypot(truth.pn - kill_n, truth.pe - kill_e))
        if -truth.pd < 1.0:
            sink = max(sink, truth.vd)
        if touchdown is None and -truth.pd < 0.5 and abs(truth.vd) < 0.2:
            touchdown = now - t_kill
        hb = truth.watched_messages("HEARTBEAT", since=t_kill)
        if disarmed is None and hb and not hb[-1][1].base_mode & MAV_MODE_FLAG_SAFETY_ARMED:
            disarmed = hb[-1][0] - t_kill
        if disarmed is not None and not frozen:
            break
        time.sleep(0.05)
    if frozen:
        os.killpg(proc.pid, signal.SIGCONT)
    return touchdown, disarmed, drift, sink


@dataclass(frozen=True)
class KillOutcome:
    """What the autopilot did by itself after the companion was killed (times in s after the kill)."""

    kill_height_m: float  # truth height above home at the kill
    kill_from_pad_m: float  # truth horizontal distance from the pad at the kill
    modes: tuple[tuple[float, str], ...]  # (s after the kill, mode): the mode at the kill, then each change
    failsafe_after_s: float | None  # first mode change after the kill
    touchdown_after_s: float | None  # truth height within 0.5 m of the ground, settled
    touchdown_speed_m_s: float  # fastest truth descent below 1 m height (how hard it came down)
    disarmed_after_s: float | None
    landed_from_pad_m: float  # truth horizontal distance from the pad where it disarmed (or at the end)
    landed_north_east_m: tuple[float, float]  # truth position then, from home
    max_drift_m: float  # farthest truth horizontal distance from the kill point until disarmed
    release_commands: tuple[str, ...]  # release commands the relay forwarded to the autopilot, whole flight
    commands_after_kill: int  # any command forwarded after the kill (none: the companion is dead)
    fly_returncode: int | None
    how: str = "kill"  # kill, freeze or hang (fly_and_kill)
    stopped_at_unix_s: float = 0.0  # the wall clock at the stop (the companion's log lines are stamped on it)

    @property
    def changes_after_stop(self) -> list[str]:
        """The modes the autopilot changed to after the stop, in order (not the one it was in)."""
        return [m for t, m in self.modes[1:] if t > 0.0]

    def story(self) -> str:
        modes = ", ".join(f"{t:+.1f} s {m}" for t, m in self.modes)
        fmt = lambda x: "-" if x is None else f"{x:.1f} s"  # noqa: E731
        what = {"kill": "killed", "freeze": "frozen", "hang": "loop hung"}[self.how]
        return (
            f"{what} at {self.kill_height_m:.2f} m, {self.kill_from_pad_m:.2f} m from the pad; modes: {modes}; "
            f"failsafe {fmt(self.failsafe_after_s)}, touchdown {fmt(self.touchdown_after_s)} (at most "
            f"{self.touchdown_speed_m_s:.2f} m/s down below 1 m), disarmed "
            f"{fmt(self.disarmed_after_s)} after the stop; landed {self.landed_from_pad_m:.2f} m from the pad "
            f"(N {self.landed_north_east_m[0]:.2f} E {self.landed_north_east_m[1]:.2f} m from home), drift "
            f"{self.max_drift_m:.2f} m; release commands sent: {list(self.release_commands) or 'none'}"
        )


def mode_changes(
    beats: list[tuple[float, Any]], t_stop: float, mode_name: Callable[[int], str]
) -> tuple[list[tuple[float, str]], float | None]:
    """The autopilot's modes around a stop at ``t_stop`` (monotonic s) from its heartbeats
    (arrival time, HEARTBEAT): the mode of the last heartbeat at or before the stop, then each
    change, as (s after the stop, name); and the time of the first change after the stop. With no
    heartbeat before the stop the mode the companion flew in is unknown, so no change is claimed."""
    before = [i for i, (t, _) in enumerate(beats) if t <= t_stop]
    modes: list[tuple[float, str]] = []
    for t, m in beats[before[-1] if before else 0 :]:
        name = mode_name(int(m.custom_mode))
        if not modes or modes[-1][1] != name:
            modes.append((round(t - t_stop, 2), name))
    failsafe = next((t for t, _ in modes[1:] if t > 0.0), None) if before else None
    return modes, failsafe


def fly_and_kill(
    params: Path,
    connection: str,
    truth: MavlinkTruth,
    relay: UdpRelay,
    mode_name: Callable[[int], str],
    run_dir: Path,
    kill_height_m: float = 5.0,
    pad_radius_m: float = 3.0,
    reach_timeout_s: float = 240.0,
    land_timeout_s: float = 90.0,
    how: Literal["kill", "freeze", "hang"] = "kill",
    stop_s: float = 15.0,
) -> KillOutcome:
    """Start `companion fly`, stop it over the pad at ``kill_height_m`` on the way down, then
    watch the autopilot (HEARTBEAT on ``truth``, which must watch HEARTBEAT) until it disarms or
    ``land_timeout_s`` passes. ``mode_name`` turns a HEARTBEAT custom_mode into a name.

    ``how``: ``"kill"``, SIGKILL of its process group (the computer dies); ``"freeze"``, SIGSTOP of
    the group for ``stop_s``, then SIGCONT; ``"hang"``, its event loop blocked ``stop_s`` (SIGUSR1 to
    :mod:`companion_firmware.hang_on_signal`), every other thread running. After a freeze or a hang
    the companion goes on: it is watched until it exits (its mission over) or ``land_timeout_s``
    after it is back, then killed; the commands it sent meanwhile are in the outcome."""
    with open(params, "rb") as f:
        pad = tomllib.load(f)["mission"]["pad"]
    pad_n, pad_e = float(pad["north_m"]), float(pad["east_m"])
    launcher = ["companion"] if how != "hang" else ["companion_firmware.hang_on_signal", str(stop_s)]
    cmd = [sys.executable, "-m", *launcher, "fly", "--params", str(params), "--connection", connection]
    cmd += ["--json", "--out", str(run_dir), "--timeout", str(reach_timeout_s + 60.0)]
    out = open(run_dir.parent / f"{run_dir.name}.out", "wb")  # noqa: SIM115
    proc = subprocess.Popen(cmd, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
    try:
        t_end = time.monotonic() + reach_timeout_s
        while True:
            if proc.poll() is not None:
                raise AssertionError(f"`companion fly` ended (exit {proc.returncode}) before the kill: see {out.name}")
            if time.monotonic() > t_end:
                raise AssertionError(
                    f"the vehicle was not over the pad at {kill_height_m} m within {reach_timeout_s} s"
                )
            h, d = -truth.pd, math.hypot(truth.pn - pad_n, truth.pe - pad_e)
            if d < pad_radius_m and h < kill_height_m and truth.vd > 0.2:
                break
            time.sleep(0.02)
        if how == "kill":
            os.killpg(proc.pid, signal.SIGKILL)  # the companion computer dies: every process it ran
        elif how == "freeze":
            os.killpg(proc.pid, signal.SIGSTOP)  # every process it ran, every thread, stopped
        else:
            os.kill(proc.pid, signal.SIGUSR1)  # its event loop blocks; its other threads run on
        t_kill, t_kill_unix = time.monotonic(), time.time()
        kill_n, kill_e, kill_h, kill_d = truth.pn, truth.pe, -truth.pd, d
        if how == "kill":
            proc.wait(5.0)
        touchdown, disarmed, drift, sink = _watch_landing(
            truth, t_kill, kill_n, kill_e, land_timeout_s, proc, how, stop_s
        )
        land_n, land_e = truth.pn, truth.pe
        if how != "kill":
            with contextlib.suppress(subprocess.TimeoutExpired):  # its mission ends by itself, or is ended
                proc.wait(max(0.0, t_kill + stop_s + land_timeout_s - time.monotonic()))
    finally:
        if proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait(5.0)
        out.close()

    modes, failsafe = mode_changes(truth.watched_messages("HEARTBEAT", since=t_kill - 3.0), t_kill, mode_name)
    return KillOutcome(
        kill_height_m=kill_h,
        kill_from_pad_m=kill_d,
        modes=tuple(modes),
        failsafe_after_s=failsafe,
        touchdown_after_s=touchdown,
        touchdown_speed_m_s=sink,
        disarmed_after_s=disarmed,
        landed_from_pad_m=math.hypot(land_n - pad_n, land_e - pad_e),
        landed_north_east_m=(land_n, land_e),
        max_drift_m=drift,
        release_commands=tuple(RELEASE_COMMANDS[c] for _, c in relay.commands_to_autopilot if c in RELEASE_COMMANDS),
        commands_after_kill=sum(1 for t, _ in relay.commands_to_autopilot if t > t_kill),
        fly_returncode=proc.returncode,
        how=how,
        stopped_at_unix_s=t_kill_unix,
    )


def log_line_after_s(out: Path, text: str, since_unix_s: float) -> float | None:
    """Seconds after ``since_unix_s`` of the first line of `companion`'s output (``out``, its
    ``%(asctime)s`` log format, local time, ms) that contains ``text``; None when none does."""
    for line in out.read_text(errors="replace").splitlines():
        if text not in line:
            continue
        try:
            stamp = time.mktime(time.strptime(line[:19], "%Y-%m-%d %H:%M:%S")) + int(line[20:23]) / 1000.0
        except ValueError:
            continue
        return stamp - since_unix_s
    return None

"""`companion preflight` (and `companion fly`'s check before arming) as a real process against the
MAVLink sim vehicle over UDP, in both dialects: the firmware defaults pass (ArduCopter with its
gripper set up), a wrong parameter on the vehicle ends with exit 6 and the value to set."""

from __future__ import annotations

import json
import socket
import struct
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.cli import exits
from companion_sitl.mavlink.factory import mavlink_sim_vehicle
from companion_sitl.params import SimConfig

TIME_LIMIT_S = 60.0
URLS = {"px4": "udpin://127.0.0.1:{port}", "ardupilot": "udpin:127.0.0.1:{port}"}
# the vehicle the shipped parameters expect: a gripper on output 9, and a battery failsafe (RTL at
# BATT_LOW_VOLT; copter.parm has none, which the pre-flight check names as wrong)
GRIPPER_SERVO9 = {"GRIP_ENABLE": 1.0, "SERVO9_FUNCTION": 28.0, "BATT_FS_LOW_ACT": 2.0}


def _free_udp_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _Vehicle:
    def __init__(self, dialect: str, params: dict[str, float] | None = None, **kwargs: Any) -> None:
        self.port = _free_udp_port()
        self.dialect = dialect
        self.sim = mavlink_sim_vehicle(
            SimConfig(ready_delay_s=0.0), dialect, remote=("127.0.0.1", self.port), params=params, **kwargs
        )
        self.commands: list[int] = []
        self.sim.on_message = self._seen

    def _seen(self, m: Any) -> None:
        if m.get_type() == "COMMAND_LONG":
            self.commands.append(m.command)

    def params_file(self, tmp_path: Path, landing: str = "fusion = false") -> Path:
        f = tmp_path / "vehicle.toml"
        f.write_text(
            f'autopilot = "{self.dialect}"\nconnection = "{URLS[self.dialect].format(port=self.port)}"\n'
            f"[runtime]\nconnect_timeout_s = 5\n[landing]\n{landing}\n[telemetry]\nenabled = false\n"
        )
        return f


@pytest.fixture
def vehicle() -> Iterator[list[_Vehicle]]:
    started: list[_Vehicle] = []
    yield started
    for v in started:
        v.sim.stop()


def _start(started: list[_Vehicle], dialect: str, params: dict[str, float] | None = None, **kw: Any) -> _Vehicle:
    v = _Vehicle(dialect, params, **kw)
    v.sim.start()
    started.append(v)
    return v


def _run(tmp_path: Path, *args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "companion", *args],
        capture_output=True,
        text=True,
        timeout=TIME_LIMIT_S,  # a process that hangs fails the test here
        cwd=tmp_path,
    )


@pytest.mark.parametrize("dialect, params", [("px4", None), ("ardupilot", GRIPPER_SERVO9)])
def test_firmware_defaults_pass(tmp_path: Path, vehicle: list[_Vehicle], dialect: str, params: Any) -> None:
    v = _start(vehicle, dialect, params)
    proc = _run(tmp_path, "preflight", "--params", str(v.params_file(tmp_path)))
    assert proc.returncode == exits.OK, proc.stdout + proc.stderr
    assert "Traceback" not in proc.stderr
    assert "PASSED, 0 unknown" in proc.stdout
    first = "COM_OF_LOSS_T" if dialect == "px4" else "GUID_TIMEOUT"
    assert first in proc.stdout and "clock" in proc.stdout


@pytest.mark.parametrize(
    "dialect, params, name, what_to_set",
    [
        ("px4", {"COM_OF_LOSS_T": 0.1}, "COM_OF_LOSS_T", "set COM_OF_LOSS_T >= 0.15"),
        ("px4", {"COM_OBL_RC_ACT": 3.0}, "COM_OBL_RC_ACT", "add 'rtl' to link_loss_resume_modes"),
        ("ardupilot", {**GRIPPER_SERVO9, "GUID_TIMEOUT": 0.1}, "GUID_TIMEOUT", "set GUID_TIMEOUT >= 0.15"),
        ("ardupilot", {}, "GRIP_ENABLE", "set GRIP_ENABLE = 1"),
    ],
)
def test_a_wrong_parameter_fails_with_what_to_set(
    tmp_path: Path, vehicle: list[_Vehicle], dialect: str, params: dict[str, float], name: str, what_to_set: str
) -> None:
    v = _start(vehicle, dialect, params)
    proc = _run(tmp_path, "preflight", "--params", str(v.params_file(tmp_path)), "--json")
    assert proc.returncode == exits.PREFLIGHT_FAILED == 6, proc.stdout + proc.stderr
    report = json.loads(proc.stdout)
    assert report["passed"] is False
    wrong = {c["check"]: c for c in report["checks"] if c["status"] == "wrong"}
    assert name in wrong and what_to_set in wrong[name]["detail"], wrong


def test_ardupilot_precision_landing_needs_plnd(tmp_path: Path, vehicle: list[_Vehicle]) -> None:
    """landing.controller = 'autopilot' on copter.parm's PLND_ENABLED = 0: wrong; set, it passes."""
    landing = 'fusion = true\nuse_uwb = false\ncontroller = "autopilot"\nlanding_target_output = "body_angles"'
    for plnd, code in ((0.0, exits.PREFLIGHT_FAILED), (1.0, exits.OK)):
        v = _start(vehicle, "ardupilot", {**GRIPPER_SERVO9, "PLND_ENABLED": plnd, "PLND_TYPE": plnd})
        proc = _run(tmp_path, "preflight", "--params", str(v.params_file(tmp_path, landing)), "--json", "--no-sensors")
        assert proc.returncode == code, proc.stdout + proc.stderr
        rows = {c["check"]: c for c in json.loads(proc.stdout)["checks"]}
        want = "ok" if plnd else "wrong"
        assert rows["PLND_ENABLED"]["status"] == rows["PLND_TYPE"]["status"] == want
        if not plnd:
            assert "set PLND_ENABLED = 1" in rows["PLND_ENABLED"]["detail"]


def test_sensors_that_cannot_be_opened_are_unknown_naming_the_setting(tmp_path: Path, vehicle: list[_Vehicle]) -> None:
    v = _start(vehicle, "px4")
    landing = 'fusion = true\ncamera_source = "/nonexistent/cam.avi"\nuwb_port = "/dev/companion-no-such-uwb"'
    proc = _run(tmp_path, "preflight", "--params", str(v.params_file(tmp_path, landing)), "--json")
    assert proc.returncode == exits.OK, proc.stdout + proc.stderr  # unknown does not fail the check
    rows = {c["check"]: c for c in json.loads(proc.stdout)["checks"]}
    assert (
        rows["camera"]["status"] == "unknown"
        and "landing.camera_source = '/nonexistent/cam.avi'" in rows["camera"]["detail"]
    )
    assert rows["UWB anchors"]["status"] == "unknown"
    assert "landing.uwb_port = '/dev/companion-no-such-uwb'" in rows["UWB anchors"]["detail"]


def test_clock_off_by_seconds_is_a_warning_not_a_failure(tmp_path: Path, vehicle: list[_Vehicle]) -> None:
    # a SITL whose UTC lags the host (ArduCopter started at speed-up) must not stop a flight on that
    v = _start(vehicle, "px4", clock_offset_s=30.0)
    proc = _run(tmp_path, "preflight", "--params", str(v.params_file(tmp_path)), "--json")
    assert proc.returncode == exits.OK, proc.stdout + proc.stderr
    report = json.loads(proc.stdout)
    (clock,) = [c for c in report["checks"] if c["check"] == "clock"]
    assert clock["status"] == "warn" and "30.0 s behind" in clock["detail"]
    # the other warning: PX4's default offboard-loss action (Position mode, docs/companion-death.md)
    warned = {c["check"] for c in report["checks"] if c["status"] == "warn"}
    assert report["passed"] and warned == {"clock", "COM_OBL_RC_ACT"}, warned


def test_a_slow_position_stream_is_wrong(tmp_path: Path, vehicle: list[_Vehicle]) -> None:
    from companion_sitl.mavlink.messages import PX4_DEFAULT_STREAMS_HZ

    slow = {**PX4_DEFAULT_STREAMS_HZ, mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 4.0}
    v = _start(vehicle, "px4", stream_rates_hz=slow)
    proc = _run(tmp_path, "preflight", "--params", str(v.params_file(tmp_path)), "--json")
    assert proc.returncode == exits.PREFLIGHT_FAILED, proc.stdout + proc.stderr
    rows = {c["check"]: c for c in json.loads(proc.stdout)["checks"]}
    assert rows["local position rate"]["status"] == "wrong" and "MAV_x_RATE" in rows["local position rate"]["detail"]
    assert 3.0 <= float(rows["local position rate"]["value"].split()[0]) <= 5.0
    assert rows["attitude rate"]["status"] == "ok"


def test_no_vehicle_is_exit_3(tmp_path: Path) -> None:
    port = _free_udp_port()
    f = tmp_path / "v.toml"
    f.write_text(f'autopilot = "ardupilot"\nconnection = "udpin:127.0.0.1:{port}"\n[runtime]\nconnect_timeout_s = 1\n')
    proc = _run(tmp_path, "preflight", "--params", str(f), "--no-sensors")
    assert proc.returncode == exits.AUTOPILOT_UNREACHABLE, proc.stderr
    assert proc.stderr.startswith("companion preflight: no heartbeat") and "Traceback" not in proc.stderr


@pytest.mark.parametrize("dialect", ["px4", "ardupilot"])
def test_fly_refuses_to_start_on_a_wrong_parameter_before_arming(
    tmp_path: Path, vehicle: list[_Vehicle], dialect: str
) -> None:
    params = {"COM_OBL_RC_ACT": 3.0} if dialect == "px4" else {**GRIPPER_SERVO9, "FS_GCS_ENABLE": 1.0}
    v = _start(vehicle, dialect, params)
    proc = _run(tmp_path, "fly", "--params", str(v.params_file(tmp_path)), "--out", str(tmp_path / "run"))
    assert proc.returncode == exits.PREFLIGHT_FAILED, proc.stdout + proc.stderr
    lines = proc.stderr.splitlines()
    assert len(lines) == 1 and "Traceback" not in proc.stderr, proc.stderr
    name = "COM_OBL_RC_ACT" if dialect == "px4" else "FS_GCS_ENABLE"
    assert lines[0].startswith(f"companion fly: pre-flight check failed (1 wrong): {name} = ")
    assert "add 'rtl' to link_loss_resume_modes" in lines[0]
    assert mavlink.MAV_CMD_COMPONENT_ARM_DISARM not in v.commands  # stopped before arming


def test_px4_sim_sends_integer_parameters_bytewise() -> None:
    """PX4 sends int32 parameters byte-wise in PARAM_VALUE's float (MAVSDK decodes them by type);
    ArduPilot casts them to a float."""
    for dialect, expect in (("px4", 1), ("ardupilot", None)):
        v = _Vehicle(dialect, {"COM_RC_OVERRIDE": 1.0, "FLTMODE_CH": 5.0})
        name = "COM_RC_OVERRIDE" if dialect == "px4" else "FLTMODE_CH"
        m = v.sim.param_value_message(name, 0)
        if expect is not None:
            assert m.param_type == mavlink.MAV_PARAM_TYPE_INT32
            assert struct.unpack("<i", struct.pack("<f", m.param_value))[0] == expect
            assert v.sim.param_decode(name, m.param_value) == 1.0  # PARAM_SET reads it back the same way
        else:
            assert m.param_value == 5.0

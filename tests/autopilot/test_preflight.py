"""The pre-flight rules, each with hand-written parameter values: ok, wrong (naming what to set)
and unknown (naming why)."""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np
import pytest

from companion.autopilot.preflight.ardupilot import (
    ardupilot_param_names,
    check_ardupilot_failsafe_release,
    check_ardupilot_gcs_failsafe,
    check_ardupilot_guided_timeout,
    check_ardupilot_mode_switch,
    check_ardupilot_precland,
    check_ardupilot_rc_override,
    check_ardupilot_release,
)
from companion.autopilot.preflight.px4 import (
    check_px4_ekf_gps,
    check_px4_ekf_height,
    check_px4_offboard_loss,
    check_px4_offboard_loss_action,
    check_px4_precland,
    check_px4_rc_override,
    px4_param_types,
)
from companion.autopilot.preflight.readers import (
    clock_probe_from,
    probe_camera,
    probe_uwb,
    stream_rate_hz,
)
from companion.autopilot.preflight.report import (
    CameraProbe,
    CheckResult,
    ClockProbe,
    ParamUnavailable,
    RealtimeProbe,
    Requirements,
    Status,
    StreamProbe,
    UwbProbe,
    requirements_from_config,
)
from companion.autopilot.preflight.runner import (
    run_checks,
)
from companion.autopilot.preflight.sensors import (
    check_camera,
    check_clock,
    check_realtime,
    check_streams,
    check_uwb,
)
from companion.config import load_config, shipped_params_path
from companion.plugin_api import Frame

PX4 = Requirements("px4", setpoint_rate_hz=20.0, link_loss_resume_modes=("hold", "position"))
AP = Requirements("ardupilot", setpoint_rate_hz=20.0, link_loss_resume_modes=("hold", "position"))

PX4_DEFAULTS = {"COM_OF_LOSS_T": 1.0, "COM_OBL_RC_ACT": 0.0, "COM_RC_OVERRIDE": 1.0, "EKF2_GPS_CTRL": 7.0}
PX4_DEFAULTS |= {"EKF2_HGT_REF": 1.0, "PLD_BTOUT": 5.0, "PLD_HACC_RAD": 0.2}
# the SITL's: GF_ACTION Hold, COM_LOW_BAT_ACT 3 (rcS), BAT_CRIT_THR 7 %, Remote ID not checked
PX4_DEFAULTS |= {"GF_ACTION": 2.0, "COM_LOW_BAT_ACT": 3.0, "BAT_CRIT_THR": 0.07, "COM_ARM_ODID": 0.0}
AP_DEFAULTS = {"GUID_TIMEOUT": 3.0, "RC_OVERRIDE_TIME": 3.0, "FS_GCS_ENABLE": 0.0, "FLTMODE_CH": 5.0}
AP_DEFAULTS |= {"GRIP_ENABLE": 0.0, "PLND_ENABLED": 0.0, "PLND_TYPE": 0.0}
AP_DEFAULTS |= {f"SERVO{n}_FUNCTION": float(32 + n if n <= 4 else 0) for n in range(1, 17)}


def _row(rows: list[CheckResult], name: str) -> CheckResult:
    (row,) = [r for r in rows if r.name == name]
    return row


# ------------------------------------------------------------------------------------------ PX4
def test_px4_firmware_defaults_pass() -> None:
    report = run_checks(PX4, PX4_DEFAULTS, clock=ClockProbe(offset_s=0.01))
    assert report.passed, report.wrong
    assert [c.name for c in report.checks] == [
        "COM_OF_LOSS_T",
        "COM_OBL_RC_ACT",
        "COM_RC_OVERRIDE",
        "EKF2_GPS_CTRL",
        "EKF2_HGT_REF",
        "GF_ACTION",
        "COM_LOW_BAT_ACT",
        "BAT_CRIT_THR",
        "COM_ARM_ODID",
        "clock",
    ]
    # PX4's default offboard-loss action is Position mode: said, not a failure (docs/companion-death.md)
    assert {c.name for c in report.checks if c.status is not Status.OK} == {"COM_OBL_RC_ACT"}
    assert _row(report.checks, "COM_OBL_RC_ACT").status is Status.WARN


@pytest.mark.parametrize(
    "value, status, words",
    [
        (1.0, Status.OK, ["1 s"]),
        (0.1, Status.WRONG, ["set COM_OF_LOSS_T >= 0.15", "setpoint_rate_hz = 20"]),
        (10.0, Status.WRONG, ["between 0.15 and 5"]),
    ],
)
def test_px4_offboard_loss_timeout(value: float, status: Status, words: list[str]) -> None:
    row = check_px4_offboard_loss(PX4, {"COM_OF_LOSS_T": value})
    assert row.status is status
    for w in words:
        assert w in row.detail


def test_offboard_loss_timeout_follows_the_setpoint_rate() -> None:
    slow = dataclasses.replace(PX4, setpoint_rate_hz=5.0)  # 3 periods = 0.6 s
    assert check_px4_offboard_loss(PX4, {"COM_OF_LOSS_T": 0.5}).status is Status.OK
    row = check_px4_offboard_loss(slow, {"COM_OF_LOSS_T": 0.5})
    assert row.status is Status.WRONG and "set COM_OF_LOSS_T >= 0.60" in row.detail


def test_unread_and_missing_parameters_are_unknown_with_the_reason() -> None:
    row = check_px4_offboard_loss(PX4, {"COM_OF_LOSS_T": ParamUnavailable("MAVSDK TIMEOUT")})
    assert (row.status, row.name) == (Status.UNKNOWN, "COM_OF_LOSS_T") and "MAVSDK TIMEOUT" in row.detail
    assert check_px4_offboard_loss(PX4, {}).status is Status.UNKNOWN
    assert check_px4_offboard_loss(PX4, {"COM_OF_LOSS_T": float("nan")}).status is Status.UNKNOWN
    report = run_checks(PX4, {}, clock=ClockProbe(offset_s=0.0))
    assert report.passed  # unknown rows do not fail the check
    # 5 rules, and the fence action, battery failsafe (action, critical level) and Remote ID
    assert sum(c.status is Status.UNKNOWN for c in report.checks) == 9


@pytest.mark.parametrize(
    "action, resume, status, words",
    [
        (0, ("hold", "position"), Status.WARN, ["Position mode", "without RC", "COM_OBL_RC_ACT = 4 (Land)"]),
        (4, ("hold", "position"), Status.OK, ["lands where it is", "leaves it to LAND"]),
        (4, ("land",), Status.OK, ["the mission resumes"]),
        (5, ("hold", "position"), Status.OK, ["Hold"]),
        (3, ("hold", "position"), Status.WRONG, ["Return", "add 'rtl' to link_loss_resume_modes", "ACT = 4"]),
        (3, ("rtl",), Status.OK, ["Return"]),
        (0, ("hold",), Status.WRONG, ["add 'position'"]),
        (6, ("hold", "position"), Status.WRONG, ["Terminate"]),
        (7, ("hold", "position"), Status.WRONG, ["Disarm"]),
        (9, ("hold", "position"), Status.WRONG, ["0-7"]),
    ],
)
def test_px4_offboard_loss_action_against_the_resume_modes(
    action: int, resume: tuple[str, ...], status: Status, words: list[str]
) -> None:
    req = dataclasses.replace(PX4, link_loss_resume_modes=resume)
    row = check_px4_offboard_loss_action(req, {"COM_OBL_RC_ACT": float(action)})
    assert row.status is status, row
    for w in words:
        assert w in row.detail


def test_px4_rc_override() -> None:
    assert "takes over with the mode switch" in check_px4_rc_override(PX4, {"COM_RC_OVERRIDE": 1.0}).detail
    assert "sticks take" in check_px4_rc_override(PX4, {"COM_RC_OVERRIDE": 3.0}).detail
    row = check_px4_rc_override(PX4, {"COM_RC_OVERRIDE": 16.0})
    assert row.status is Status.WRONG and "COM_RC_OVERRIDE = 1 or 3" in row.detail


def test_px4_ekf_settings() -> None:
    assert check_px4_ekf_gps(PX4, {"EKF2_GPS_CTRL": 1.0}).status is Status.OK
    row = check_px4_ekf_gps(PX4, {"EKF2_GPS_CTRL": 6.0})  # position bit off
    assert row.status is Status.WRONG and "EKF2_GPS_CTRL = 7" in row.detail
    assert check_px4_ekf_height(PX4, {"EKF2_HGT_REF": 0.0}).status is Status.OK
    row = check_px4_ekf_height(PX4, {"EKF2_HGT_REF": 3.0})
    assert row.status is Status.WRONG and "EKF2_HGT_REF = 0 (baro) or 1 (GNSS)" in row.detail
    assert check_px4_ekf_height(PX4, {"EKF2_HGT_REF": 4.0}).status is Status.WRONG


def test_px4_precision_landing_only_when_px4_lands() -> None:
    assert check_px4_precland(PX4, {}) == []
    assert "PLD_BTOUT" not in px4_param_types(PX4)
    req = dataclasses.replace(PX4, landing_controller="autopilot", camera_rate_hz=2.0, pad_size_m=1.0)
    assert {"PLD_BTOUT", "PLD_HACC_RAD"} <= set(px4_param_types(req))
    rows = check_px4_precland(req, {"PLD_BTOUT": 5.0, "PLD_HACC_RAD": 0.2})
    assert [r.status for r in rows] == [Status.OK, Status.OK]
    rows = check_px4_precland(req, {"PLD_BTOUT": 1.0, "PLD_HACC_RAD": 0.8})
    assert [r.status for r in rows] == [Status.WRONG, Status.WRONG]
    assert "set PLD_BTOUT >= 1.50" in rows[0].detail  # 3 frames at 2 Hz
    assert "set PLD_HACC_RAD <= 0.5" in rows[1].detail
    rows = check_px4_precland(req, {"PLD_HACC_RAD": ParamUnavailable("MAVSDK DOES_NOT_EXIST")})
    assert [r.status for r in rows] == [Status.UNKNOWN, Status.UNKNOWN]


# ------------------------------------------------------------------------------------ ArduPilot
def test_ardupilot_copter_parm_defaults_fail_only_on_the_gripper() -> None:
    report = run_checks(AP, AP_DEFAULTS, clock=ClockProbe(offset_s=0.0))
    assert [c.name for c in report.wrong] == ["GRIP_ENABLE", "gripper output"]
    assert "set GRIP_ENABLE = 1" in report.wrong[0].detail
    assert "SERVOn_FUNCTION = 28" in report.wrong[1].detail
    fixed = AP_DEFAULTS | {"GRIP_ENABLE": 1.0, "SERVO9_FUNCTION": 28.0}
    report = run_checks(AP, fixed, clock=ClockProbe(offset_s=0.0))
    assert report.passed, report.wrong
    assert _row(list(report.checks), "gripper output").value == "SERVO9"


def test_ardupilot_param_names_follow_the_configuration() -> None:
    names = ardupilot_param_names(AP)
    assert "GRIP_ENABLE" in names and "SERVO16_FUNCTION" in names and "PLND_ENABLED" not in names
    servo = dataclasses.replace(AP, release="servo", servo_channel=10, landing_controller="autopilot")
    names = ardupilot_param_names(servo)
    assert "SERVO10_FUNCTION" in names and "GRIP_ENABLE" not in names and "PLND_TYPE" in names


@pytest.mark.parametrize(
    "value, status, words",
    [(3.0, Status.OK, ["3 s"]), (0.1, Status.WRONG, ["set GUID_TIMEOUT >= 0.15"]), (8.0, Status.WRONG, ["and 5"])],
)
def test_ardupilot_guided_timeout(value: float, status: Status, words: list[str]) -> None:
    row = check_ardupilot_guided_timeout(AP, {"GUID_TIMEOUT": value})
    assert row.status is status
    for w in words:
        assert w in row.detail


def test_ardupilot_rc_override_time() -> None:
    assert check_ardupilot_rc_override(AP, {"RC_OVERRIDE_TIME": 3.0}).status is Status.OK
    assert check_ardupilot_rc_override(AP, {"RC_OVERRIDE_TIME": 0.0}).status is Status.OK
    row = check_ardupilot_rc_override(AP, {"RC_OVERRIDE_TIME": -1.0})
    assert row.status is Status.WRONG and "set RC_OVERRIDE_TIME = 3" in row.detail
    assert check_ardupilot_rc_override(AP, {"RC_OVERRIDE_TIME": ParamUnavailable("x")}).status is Status.UNKNOWN


@pytest.mark.parametrize(
    "value, resume, status, words",
    [
        (0, ("hold", "position"), Status.WARN, ["no GCS failsafe", "companion dies", "FS_GCS_ENABLE = 5"]),
        (1, ("hold", "position"), Status.WRONG, ["ArduCopter RTL", "add 'rtl'", "FS_GCS_ENABLE = 5"]),
        (1, ("rtl",), Status.OK, ["resumes"]),
        (5, ("hold", "position"), Status.OK, ["5 s after", "lands where it is", "leaves it to LAND"]),
        (5, ("land",), Status.OK, ["the mission resumes"]),
        (7, ("hold", "position"), Status.OK, ["Brake"]),
        (9, ("hold", "position"), Status.WRONG, ["0-7"]),
    ],
)
def test_ardupilot_gcs_failsafe(value: int, resume: tuple[str, ...], status: Status, words: list[str]) -> None:
    req = dataclasses.replace(AP, link_loss_resume_modes=resume)
    row = check_ardupilot_gcs_failsafe(req, {"FS_GCS_ENABLE": float(value), "FS_GCS_TIMEOUT": 5.0})
    assert row.status is status, row
    for w in words:
        assert w in row.detail


@pytest.mark.parametrize(
    "value, release, status, words",
    [
        (16, "gripper", Status.OK, ["does not release"]),
        (48, "gripper", Status.WRONG, ["releases the gripper on any failsafe", "set FS_OPTIONS = 16"]),
        (-1, "gripper", Status.WRONG, ["not a bitmask"]),
        (48, "servo", None, []),  # DO_SET_SERVO's output is not the gripper FS_OPTIONS releases
    ],
)
def test_ardupilot_failsafe_must_not_release_the_gripper(
    value: int, release: str, status: Status | None, words: list[str]
) -> None:
    req = dataclasses.replace(AP, release=release)
    rows = check_ardupilot_failsafe_release(req, {"FS_OPTIONS": float(value)})
    if status is None:
        assert rows == []
        return
    (row,) = rows
    assert row.status is status, row
    for w in words:
        assert w in row.detail
    assert check_ardupilot_failsafe_release(req, {})[0].status is Status.UNKNOWN


@pytest.mark.parametrize(
    "value, status, words",
    [(5, Status.OK, ["channel 5"]), (0, Status.WRONG, ["FLTMODE_CH = 5"]), (3, Status.WRONG, ["stick channel 3"])],
)
def test_ardupilot_mode_switch(value: int, status: Status, words: list[str]) -> None:
    row = check_ardupilot_mode_switch(AP, {"FLTMODE_CH": float(value)})
    assert row.status is status
    for w in words:
        assert w in row.detail


def test_ardupilot_precision_landing() -> None:
    assert check_ardupilot_precland(AP, {}) == []
    req = dataclasses.replace(AP, landing_controller="autopilot", landing_target_output="body_angles")
    rows = check_ardupilot_precland(req, {"PLND_ENABLED": 1.0, "PLND_TYPE": 1.0})
    assert [r.status for r in rows] == [Status.OK, Status.OK]
    rows = check_ardupilot_precland(req, {"PLND_ENABLED": 0.0, "PLND_TYPE": 0.0})
    assert [r.status for r in rows] == [Status.WRONG, Status.WRONG]
    assert "set PLND_ENABLED = 1" in rows[0].detail and "set PLND_TYPE = 1" in rows[1].detail
    local = dataclasses.replace(req, landing_target_output="local_ned")
    (_, row) = check_ardupilot_precland(local, {"PLND_ENABLED": 1.0, "PLND_TYPE": 1.0})
    assert row.status is Status.WRONG and "landing_target_output = 'body_angles'" in row.detail


def test_ardupilot_release_by_servo() -> None:
    req = dataclasses.replace(AP, release="servo", servo_channel=10)
    (row,) = check_ardupilot_release(req, {"SERVO10_FUNCTION": 0.0})
    assert row.status is Status.OK
    (row,) = check_ardupilot_release(req, {"SERVO10_FUNCTION": 33.0})
    assert row.status is Status.WRONG and "set SERVO10_FUNCTION = 0" in row.detail
    (row,) = check_ardupilot_release(req, {})
    assert row.status is Status.UNKNOWN
    (row,) = check_ardupilot_release(dataclasses.replace(AP, release="actuator"), {})
    assert row.status is Status.WRONG and "'gripper' or 'servo'" in row.detail


def test_ardupilot_gripper_output_unknown_when_no_output_was_read() -> None:
    rows = check_ardupilot_release(AP, {"GRIP_ENABLE": 1.0})
    assert [r.status for r in rows] == [Status.OK, Status.UNKNOWN]
    some = {"GRIP_ENABLE": 1.0, "SERVO1_FUNCTION": 33.0}
    rows = check_ardupilot_release(AP, some)
    assert rows[1].status is Status.WRONG and "15 outputs not read" in rows[1].detail


# -------------------------------------------------------------------------- sensors and clock
CAM = dataclasses.replace(PX4, camera_size_px=(640, 480), camera_rate_hz=30.0)


def test_camera_rules() -> None:
    assert check_camera(PX4, None) == []  # no camera configured: no row
    rows = check_camera(CAM, CameraProbe(640, 480, 29.5, 60))
    assert [r.status for r in rows] == [Status.OK, Status.OK]
    rows = check_camera(CAM, CameraProbe(1280, 720, 15.0, 30))
    assert [r.status for r in rows] == [Status.WRONG, Status.WRONG]
    assert "calibration (landing.camera_calibration) is for 640x480" in rows[0].detail
    assert "landing.camera_rate_hz = 15" in rows[1].detail
    rows = check_camera(CAM, CameraProbe(640, 480, None, 2))
    assert [r.status for r in rows] == [Status.OK, Status.UNKNOWN]
    (row,) = check_camera(CAM, CameraProbe(error="camera OpenCvCamera: cannot open 0"))
    assert row.status is Status.UNKNOWN and "cannot open 0" in row.detail


def test_uwb_rules() -> None:
    req = dataclasses.replace(AP, uwb_anchor_ids=frozenset({"A1", "A2", "A3", "A4"}))
    assert check_uwb(AP, UwbProbe()) == []
    (row,) = check_uwb(req, UwbProbe(frozenset({"A1", "A2", "A3", "A4", "B9"}), 20))
    assert row.status is Status.OK and row.value == "4/4" and "B9" in row.detail
    (row,) = check_uwb(req, UwbProbe(frozenset({"A1", "A2"}), 20))
    assert row.status is Status.WRONG and row.value == "2/4" and "not heard: A3, A4" in row.detail
    (row,) = check_uwb(req, UwbProbe(error="no reading from the UWB tag within 2 s"))
    assert row.status is Status.UNKNOWN


def test_clock_rule() -> None:
    assert check_clock(PX4, ClockProbe(offset_s=0.2)).status is Status.OK
    row = check_clock(PX4, ClockProbe(offset_s=5.0))
    assert row.status is Status.WARN and "5.0 s behind" in row.detail and "NTP" in row.detail
    assert run_checks(PX4, PX4_DEFAULTS, clock=ClockProbe(offset_s=5.0)).passed  # logs, not flight safety
    assert "ahead of" in check_clock(PX4, ClockProbe(offset_s=-5.0)).detail
    assert check_clock(PX4, None).status is Status.UNKNOWN
    assert clock_probe_from(None).error == "no SYSTEM_TIME from the autopilot"
    assert "no UTC" in clock_probe_from((0, 1.0e9)).error
    assert clock_probe_from((1_700_000_002_500_000, 1_700_000_000.0)).offset_s == pytest.approx(2.5)


def test_realtime_rule() -> None:
    assert check_realtime(None) == []  # runtime.realtime_priority = 0: nothing to check
    (row,) = check_realtime(RealtimeProbe(20))
    assert row.status is Status.OK and row.value == "SCHED_RR 20"
    (row,) = check_realtime(RealtimeProbe(20, "not permitted: needs CAP_SYS_NICE"))
    assert row.status is Status.WARN and "CAP_SYS_NICE" in row.detail and "normal policy" in row.detail
    report = run_checks(PX4, PX4_DEFAULTS, realtime=RealtimeProbe(20, "not permitted"))
    assert report.passed and report.checks[-1].name == "real-time priority"  # a warning, not a refusal


def test_the_realtime_probe_leaves_the_callers_thread_alone(monkeypatch) -> None:
    import os

    from companion import scheduling

    before = scheduling.thread_policy()
    refused = scheduling.probe_realtime(15)
    assert scheduling.thread_policy() == before
    if refused is None:  # permitted here: the probe's thread ran it; refused must say why
        monkeypatch.setattr(scheduling.os, "sched_setscheduler", _refuse)
        assert "CAP_SYS_NICE" in (scheduling.probe_realtime(15) or "")
    else:
        assert "CAP_SYS_NICE" in refused and before.policy == os.SCHED_OTHER


def _refuse(*_args: object) -> None:
    import errno

    raise PermissionError(errno.EPERM, "Operation not permitted")


# --------------------------------------------------------------------------------- the probes
class _FakeCamera:
    def __init__(self, width: int, height: int, fail: bool = False) -> None:
        self.shape = (height, width, 3)
        self.fail = fail
        self.i = 0
        self.started = self.stopped = False

    def start(self) -> None:
        if self.fail:
            raise OSError("cannot open /dev/video7")
        self.started = True

    def read(self) -> Frame:
        self.i += 1
        n = self.i // 2  # each frame read twice
        return Frame(n / 25.0, np.zeros(self.shape, np.uint8), n)  # exposed at 25 Hz

    def stop(self) -> None:
        self.stopped = True


def test_probe_camera_reads_size_and_rate() -> None:
    cam = _FakeCamera(320, 240)
    probe = probe_camera(cam, seconds=0.1)
    assert (probe.width_px, probe.height_px, probe.error) == (320, 240, "")
    assert probe.frames >= 3 and probe.fps == pytest.approx(25.0)  # from the exposure times, not the reads
    assert cam.started and cam.stopped
    probe = probe_camera(_FakeCamera(320, 240, fail=True), seconds=0.1)
    assert "cannot open /dev/video7" in probe.error


class _FakeUwb:
    def __init__(self, ids: list[str]) -> None:
        self.ids = ids

    def start(self) -> None: ...

    def read(self) -> list[Any]:
        return [dataclasses.make_dataclass("M", ["anchor_ids"])(tuple(self.ids))]

    def stop(self) -> None: ...


def test_probe_uwb_collects_anchor_ids() -> None:
    probe = probe_uwb(_FakeUwb(["A1", "A2"]), seconds=0.05)
    assert probe.anchors_seen == {"A1", "A2"} and probe.readings > 0


def test_requirements_from_the_shipped_files() -> None:
    cfg = load_config(str(shipped_params_path("ardupilot_quad.toml")))
    req = requirements_from_config(cfg)
    assert (req.autopilot, req.release) == ("ardupilot", cfg.payload.release)
    assert req.setpoint_rate_hz == cfg.runtime.setpoint_rate_hz
    with pytest.raises(ValueError, match="needs 'px4' or 'ardupilot'"):
        requirements_from_config(load_config(str(shipped_params_path("delivery_paper.toml"))))


def test_stream_rates_against_the_guidance_rate() -> None:
    rows = check_streams(PX4, StreamProbe({"PositionNed": 30.0, "Attitude": 50.0}, 1.5))
    assert [(r.name, r.status) for r in rows] == [("local position rate", Status.OK), ("attitude rate", Status.OK)]
    rows = check_streams(PX4, StreamProbe({"PositionNed": 4.0, "Attitude": 50.0}, 1.5))
    assert rows[0].status is Status.WRONG and "runtime.guidance_rate_hz = 20 (10 Hz)" in rows[0].detail
    assert "MAV_x_RATE" in rows[0].detail
    # nothing at all (ArduPilot before its EKF has an origin): not known yet, not a wrong setting
    (_, row) = check_streams(AP, StreamProbe({"PositionNed": 30.0}, 1.5))  # no attitude at all
    assert row.status is Status.UNKNOWN and row.value == "0 Hz" and "SRn_EXTRA1" in row.detail
    assert "no estimate yet" in row.detail
    assert check_streams(PX4, None)[0].status is Status.UNKNOWN


def test_stream_rate_counts_from_the_first_sample() -> None:
    assert stream_rate_hz([]) == 0.0 and stream_rate_hz([1.0]) == 0.0
    assert stream_rate_hz([1.0 + 0.1 * i for i in range(11)]) == pytest.approx(10.0)


@pytest.mark.parametrize(
    "value, status", [(0.0, Status.WRONG), (16.0, Status.OK), (17.0, Status.OK), (8.0, Status.WRONG)]
)
def test_ardupilot_moving_pad_needs_guided_without_a_position_target(value: float, status: Status) -> None:
    moving = dataclasses.replace(AP, moving_pad=True)
    assert "GUID_OPTIONS" in ardupilot_param_names(moving) and "GUID_OPTIONS" not in ardupilot_param_names(AP)
    fixed = AP_DEFAULTS | {"GRIP_ENABLE": 1.0, "SERVO9_FUNCTION": 28.0}
    rows = list(run_checks(moving, fixed | {"GUID_OPTIONS": value}, clock=ClockProbe(offset_s=0.0)).checks)
    row = _row(rows, "GUID_OPTIONS")
    assert row.status is status, row
    if status is Status.WRONG:
        assert "set bit 4 (DoNotStabilizePositionXY, add 16)" in row.detail
    assert all(c.name != "GUID_OPTIONS" for c in run_checks(AP, fixed, clock=ClockProbe(offset_s=0.0)).checks)

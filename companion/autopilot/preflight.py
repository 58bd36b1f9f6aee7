"""Pre-flight check against the vehicle: is the autopilot configured the way the companion needs?

The rules are pure functions over what was read from the vehicle -- a dict of autopilot parameters
(name -> value, or :class:`ParamUnavailable` with the reason), a camera probe, a UWB probe and a
clock probe -- and the companion's own configuration (:class:`Requirements`), so each rule is
unit-testable with hand-written values. The thin async readers at the end fetch those values from
a connected backend (PX4: MAVSDK's Param plugin; ArduPilot: PARAM_REQUEST_READ).

Every check ends in one :class:`CheckResult` row: ``ok``, ``wrong`` (with what to set) or
``unknown`` (could not be read, with why). ``companion preflight`` prints the rows;
``companion fly`` refuses to start when any is ``wrong``.

Firmware assumptions (parameter names, meanings and defaults):

* PX4 v1.16: COM_OF_LOSS_T (float, s, default 1.0), COM_OBL_RC_ACT (int32, 0 Position, 1 Altitude,
  2 Manual, 3 Return, 4 Land, 5 Hold, 6 Terminate, 7 Disarm; default 0), COM_RC_OVERRIDE (int32
  bitmask, bit 0 auto modes, bit 1 offboard, bit 2 ignore throttle; default 1), EKF2_GPS_CTRL
  (int32 bitmask, bit 0 horizontal position; default 7), EKF2_HGT_REF (int32, 0 baro, 1 GNSS,
  2 range, 3 vision; default 1), PLD_BTOUT (float, s, default 5), PLD_HACC_RAD (float, m,
  default 0.2). PX4 sends int32 parameters byte-wise; MAVSDK's Param plugin decodes them.
* ArduCopter 4.x (copter.parm): GUID_TIMEOUT (s, default 3), RC_OVERRIDE_TIME (s, default 3,
  -1 = never lapses), FS_GCS_ENABLE (0 off, 1 RTL, 2 RTL/continue in AUTO, 3 SmartRTL or RTL,
  4 SmartRTL or Land, 5 Land, 6 DO_LAND_START or RTL, 7 Brake or Land; default 0), FLTMODE_CH
  (0 none, else the RC channel; default 5), GRIP_ENABLE (default 0), SERVOn_FUNCTION (28 =
  gripper, 0 = no function), PLND_ENABLED (default 0), PLND_TYPE (1 = MAVLink companion).
  ArduPilot sends every parameter as a float.
"""

from __future__ import annotations

import asyncio
import enum
import logging
import math
import time
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

log = logging.getLogger(__name__)


class Status(enum.Enum):
    OK = "ok"
    WRONG = "wrong"
    UNKNOWN = "unknown"


@dataclass(frozen=True)
class CheckResult:
    """One row: what was checked, the value found, the verdict and the explanation (for ``wrong``:
    what to set; for ``unknown``: why it could not be read)."""

    name: str
    status: Status
    value: str
    detail: str

    def to_json(self) -> dict[str, str]:
        return {"check": self.name, "status": self.status.value, "value": self.value, "detail": self.detail}


@dataclass(frozen=True)
class ParamUnavailable:
    """A parameter that could not be read, and why (no answer, not on this firmware, ...)."""

    reason: str


ParamValue = float | ParamUnavailable


@dataclass(frozen=True)
class CameraProbe:
    """What the configured camera plugin delivered in a short read: frame size and rate; ``error``
    when it could not be opened or gave no frame."""

    width_px: int | None = None
    height_px: int | None = None
    fps: float | None = None
    frames: int = 0
    error: str = ""


@dataclass(frozen=True)
class UwbProbe:
    """The anchor ids the UWB tag reported ranges to in a short read; ``error`` when the tag could
    not be opened or reported nothing."""

    anchors_seen: frozenset[str] = frozenset()
    readings: int = 0
    error: str = ""


@dataclass(frozen=True)
class ClockProbe:
    """The autopilot's UTC (SYSTEM_TIME.time_unix_usec) minus the companion's wall clock at
    arrival, seconds; ``error`` when no SYSTEM_TIME arrived or it carried no UTC."""

    offset_s: float | None = None
    error: str = ""


@dataclass(frozen=True)
class StreamProbe:
    """Telemetry samples the backend accepted per second over ``window_s``, by sample type
    (``PositionNed``: LOCAL_POSITION_NED / PX4's position-velocity, ``Attitude``)."""

    rates_hz: Mapping[str, float]
    window_s: float


@dataclass(frozen=True)
class Requirements:
    """What the companion's configuration needs from the vehicle (from :func:`requirements_from_config`)."""

    autopilot: Literal["px4", "ardupilot"]
    setpoint_rate_hz: float
    link_loss_resume_modes: tuple[str, ...]
    landing_controller: Literal["companion", "autopilot"] = "companion"
    landing_target_output: str = "off"
    release: str = "gripper"
    servo_channel: int = 9
    pad_size_m: float = 1.0
    camera_rate_hz: float = 30.0
    camera_size_px: tuple[int, int] | None = None  # (width, height) from the calibration, when the camera is used
    uwb_anchor_ids: frozenset[str] | None = None  # from the anchor layout, when UWB is used
    # 2 s: ArduCopter 4.7 SITL's SYSTEM_TIME read 1.13 s behind a synced companion (its simulated
    # GPS time lags); a real GPS's UTC is within milliseconds
    clock_tolerance_s: float = 2.0
    guidance_rate_hz: float = 20.0


@dataclass(frozen=True)
class PreflightReport:
    autopilot: str
    checks: tuple[CheckResult, ...] = field(default_factory=tuple)

    @property
    def wrong(self) -> tuple[CheckResult, ...]:
        return tuple(c for c in self.checks if c.status is Status.WRONG)

    @property
    def passed(self) -> bool:
        """No check is wrong (unknown ones do not fail the check)."""
        return not self.wrong

    def to_json(self) -> dict[str, Any]:
        return {
            "autopilot": self.autopilot,
            "passed": self.passed,
            "wrong": len(self.wrong),
            "unknown": sum(c.status is Status.UNKNOWN for c in self.checks),
            "checks": [c.to_json() for c in self.checks],
        }


#: minimum number of setpoint periods an autopilot's setpoint timeout must cover (a late or lost
#: setpoint or two must not trip the failsafe)
MIN_SETPOINT_PERIODS = 3.0
#: longest time the vehicle may fly on a stalled companion's last setpoint
MAX_SETPOINT_TIMEOUT_S = 5.0
#: share of ``landing.camera_rate_hz`` the measured camera rate must reach
CAMERA_RATE_TOLERANCE = 0.8


def requirements_from_config(config: Any) -> Requirements:
    """The :class:`Requirements` of a :class:`companion.config.CompanionConfig` (``autopilot`` must
    be px4 or ardupilot). The camera size and the anchor ids are added by the caller from the
    landing kit it builds (``companion.cli.preflight.sensor_requirements``)."""
    if config.autopilot not in ("px4", "ardupilot"):
        raise ValueError(f"autopilot = {config.autopilot!r}: the pre-flight check needs 'px4' or 'ardupilot'")
    lc = config.landing
    return Requirements(
        autopilot=config.autopilot,
        setpoint_rate_hz=config.runtime.setpoint_rate_hz,
        guidance_rate_hz=config.runtime.guidance_rate_hz,
        link_loss_resume_modes=tuple(config.mission.link_loss_resume_modes),
        landing_controller=lc.controller,
        landing_target_output=lc.landing_target_output,
        release=config.payload.release,
        servo_channel=config.payload.servo_channel,
        pad_size_m=config.mission.pad.size_m,
        camera_rate_hz=lc.camera_rate_hz,
    )


def _fmt(x: float) -> str:
    return f"{x:g}"


def _get(params: Mapping[str, ParamValue], name: str) -> float | CheckResult:
    """The value of ``name``, or the ``unknown`` row saying why it is missing."""
    v = params.get(name)
    if v is None:
        return CheckResult(name, Status.UNKNOWN, "-", "not read")
    if isinstance(v, ParamUnavailable):
        return CheckResult(name, Status.UNKNOWN, "-", f"could not read {name}: {v.reason}")
    if not math.isfinite(v):
        return CheckResult(name, Status.UNKNOWN, "-", f"{name} read as {v}")
    return float(v)


def _min_timeout_s(req: Requirements) -> float:
    return MIN_SETPOINT_PERIODS / req.setpoint_rate_hz


def _setpoint_timeout(name: str, v: float, req: Requirements, what: str) -> CheckResult:
    lo = _min_timeout_s(req)
    if v < lo:
        return CheckResult(
            name,
            Status.WRONG,
            _fmt(v),
            f"{what} after {_fmt(v)} s, less than {MIN_SETPOINT_PERIODS:g} setpoint periods at "
            f"runtime.setpoint_rate_hz = {_fmt(req.setpoint_rate_hz)}: set {name} >= {lo:.2f} "
            f"(or raise runtime.setpoint_rate_hz)",
        )
    if v > MAX_SETPOINT_TIMEOUT_S:
        return CheckResult(
            name,
            Status.WRONG,
            _fmt(v),
            f"a stalled companion leaves the vehicle on its last setpoint for {_fmt(v)} s: set {name} "
            f"between {lo:.2f} and {MAX_SETPOINT_TIMEOUT_S:g}",
        )
    return CheckResult(name, Status.OK, _fmt(v), f"{what} after {_fmt(v)} s ({lo:.2f}-{MAX_SETPOINT_TIMEOUT_S:g} s)")


# ---------------------------------------------------------------------------------------------- PX4
PX4_OBL_ACTIONS: dict[int, tuple[str, str | None]] = {  # COM_OBL_RC_ACT -> (PX4 name, FlightMode value)
    0: ("Position mode", "position"),
    1: ("Altitude mode", "manual"),
    2: ("Manual", "manual"),
    3: ("Return", "rtl"),
    4: ("Land", "land"),
    5: ("Hold", "hold"),
    6: ("Terminate", None),
    7: ("Disarm", None),
}
PX4_HGT_REF = {0: "baro", 1: "GNSS", 2: "range sensor", 3: "vision"}


def px4_param_types(req: Requirements) -> dict[str, Literal["int", "float"]]:
    """The PX4 parameters the checks read, with their PX4 types."""
    names: dict[str, Literal["int", "float"]] = {
        "COM_OF_LOSS_T": "float",
        "COM_OBL_RC_ACT": "int",
        "COM_RC_OVERRIDE": "int",
        "EKF2_GPS_CTRL": "int",
        "EKF2_HGT_REF": "int",
    }
    if req.landing_controller == "autopilot":
        names.update({"PLD_BTOUT": "float", "PLD_HACC_RAD": "float"})
    return names


def check_px4_offboard_loss(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = _get(params, "COM_OF_LOSS_T")
    if isinstance(v, CheckResult):
        return v
    return _setpoint_timeout("COM_OF_LOSS_T", v, req, "PX4 leaves OFFBOARD")


def _resume_check(name: str, v: float, mode: str | None, what: str, req: Requirements, fix: str) -> CheckResult:
    modes = ", ".join(req.link_loss_resume_modes) or "none"
    if mode is None:
        return CheckResult(name, Status.WRONG, _fmt(v), f"a lost link makes the vehicle {what}: {fix}")
    if mode in req.link_loss_resume_modes:
        return CheckResult(
            name,
            Status.OK,
            _fmt(v),
            f"a lost link -> {what}, listed in [mission] link_loss_resume_modes ({modes}): the mission resumes",
        )
    return CheckResult(
        name,
        Status.WRONG,
        _fmt(v),
        f"a lost link -> {what} ({mode}), not in [mission] link_loss_resume_modes ({modes}): the mission "
        f"would end at the reconnect; add {mode!r} to link_loss_resume_modes or {fix}",
    )


def check_px4_offboard_loss_action(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = _get(params, "COM_OBL_RC_ACT")
    if isinstance(v, CheckResult):
        return v
    action = PX4_OBL_ACTIONS.get(int(v)) if v == int(v) else None
    if action is None:
        return CheckResult(
            "COM_OBL_RC_ACT", Status.WRONG, _fmt(v), "not a PX4 v1.16 value (0-7): set COM_OBL_RC_ACT = 0"
        )
    name, mode = action
    return _resume_check("COM_OBL_RC_ACT", v, mode, f"PX4 {name}", req, "set COM_OBL_RC_ACT = 0 (Position) or 5 (Hold)")


def check_px4_rc_override(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = _get(params, "COM_RC_OVERRIDE")
    if isinstance(v, CheckResult):
        return v
    if v != int(v) or not 0 <= v <= 7:
        return CheckResult(
            "COM_RC_OVERRIDE", Status.WRONG, _fmt(v), "not a PX4 v1.16 bitmask (0-7): set COM_RC_OVERRIDE = 1 or 3"
        )
    if int(v) & 2:
        return CheckResult("COM_RC_OVERRIDE", Status.OK, _fmt(v), "moving the sticks takes the vehicle out of OFFBOARD")
    return CheckResult(
        "COM_RC_OVERRIDE",
        Status.OK,
        _fmt(v),
        "the sticks do not end OFFBOARD: the pilot takes over with the mode switch (3 lets the sticks do it too)",
    )


def check_px4_ekf_gps(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = _get(params, "EKF2_GPS_CTRL")
    if isinstance(v, CheckResult):
        return v
    if v != int(v) or v < 0:
        return CheckResult("EKF2_GPS_CTRL", Status.WRONG, _fmt(v), "not a bitmask: set EKF2_GPS_CTRL = 7")
    if not int(v) & 1:
        return CheckResult(
            "EKF2_GPS_CTRL",
            Status.WRONG,
            _fmt(v),
            "PX4's EKF does not use GNSS position (bit 0), but the delivery flies to a pad given by "
            "latitude/longitude: set EKF2_GPS_CTRL = 7",
        )
    return CheckResult("EKF2_GPS_CTRL", Status.OK, _fmt(v), "GNSS horizontal position fused (bit 0)")


def check_px4_ekf_height(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = _get(params, "EKF2_HGT_REF")
    if isinstance(v, CheckResult):
        return v
    ref = PX4_HGT_REF.get(int(v)) if v == int(v) else None
    if ref is None:
        return CheckResult("EKF2_HGT_REF", Status.WRONG, _fmt(v), "not a PX4 v1.16 value (0-3): set EKF2_HGT_REF = 1")
    if ref == "vision":
        return CheckResult(
            "EKF2_HGT_REF",
            Status.WRONG,
            _fmt(v),
            "height from external vision, which this companion does not send: set EKF2_HGT_REF = 0 (baro) or 1 (GNSS)",
        )
    return CheckResult("EKF2_HGT_REF", Status.OK, _fmt(v), f"height reference: {ref}")


def check_px4_precland(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    """PLD_* when PX4's AUTO.PRECLAND flies the final descent (``landing.controller = 'autopilot'``)."""
    if req.landing_controller != "autopilot":
        return []
    out: list[CheckResult] = []
    v = _get(params, "PLD_BTOUT")
    if isinstance(v, CheckResult):
        out.append(v)
    else:
        lo = max(0.5, MIN_SETPOINT_PERIODS / req.camera_rate_hz)
        if v < lo:
            out.append(
                CheckResult(
                    "PLD_BTOUT",
                    Status.WRONG,
                    _fmt(v),
                    f"PX4 gives the target up after {_fmt(v)} s, shorter than {lo:.2f} s (3 frames at "
                    f"landing.camera_rate_hz = {_fmt(req.camera_rate_hz)}, at least 0.5 s): set PLD_BTOUT >= {lo:.2f}",
                )
            )
        else:
            out.append(CheckResult("PLD_BTOUT", Status.OK, _fmt(v), f"target timeout {_fmt(v)} s (>= {lo:.2f} s)"))
    v = _get(params, "PLD_HACC_RAD")
    if isinstance(v, CheckResult):
        out.append(v)
    else:
        half = req.pad_size_m / 2.0
        if v > half:
            out.append(
                CheckResult(
                    "PLD_HACC_RAD",
                    Status.WRONG,
                    _fmt(v),
                    f"PX4 starts the final descent up to {_fmt(v)} m off the target, more than half the pad "
                    f"(mission.pad.size_m = {_fmt(req.pad_size_m)}): set PLD_HACC_RAD <= {half:g}",
                )
            )
        else:
            out.append(
                CheckResult("PLD_HACC_RAD", Status.OK, _fmt(v), f"final descent within {_fmt(v)} m of the target")
            )
    return out


def check_px4(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    return [
        check_px4_offboard_loss(req, params),
        check_px4_offboard_loss_action(req, params),
        check_px4_rc_override(req, params),
        check_px4_ekf_gps(req, params),
        check_px4_ekf_height(req, params),
        *check_px4_precland(req, params),
    ]


# ---------------------------------------------------------------------------------------- ArduPilot
AP_FS_GCS_ACTIONS: dict[int, tuple[str, str | None]] = {  # FS_GCS_ENABLE -> (ArduCopter name, FlightMode value)
    1: ("RTL", "rtl"),
    2: ("RTL (continue in AUTO)", "rtl"),
    3: ("SmartRTL or RTL", "rtl"),
    4: ("SmartRTL or Land", "rtl"),
    5: ("Land", "land"),
    6: ("DO_LAND_START or RTL", "rtl"),
    7: ("Brake or Land", "hold"),
}
AP_GRIPPER_FUNCTION = 28
AP_SERVO_OUTPUTS = 16


def ardupilot_param_names(req: Requirements) -> list[str]:
    """The ArduPilot parameters the checks read."""
    names = ["GUID_TIMEOUT", "RC_OVERRIDE_TIME", "FS_GCS_ENABLE", "FLTMODE_CH"]
    if req.landing_controller == "autopilot":
        names += ["PLND_ENABLED", "PLND_TYPE"]
    if req.release == "gripper":
        names += ["GRIP_ENABLE", *(f"SERVO{n}_FUNCTION" for n in range(1, AP_SERVO_OUTPUTS + 1))]
    elif req.release == "servo":
        names.append(f"SERVO{req.servo_channel}_FUNCTION")
    return names


def check_ardupilot_guided_timeout(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = _get(params, "GUID_TIMEOUT")
    if isinstance(v, CheckResult):
        return v
    return _setpoint_timeout("GUID_TIMEOUT", v, req, "GUIDED stops the vehicle")


def check_ardupilot_rc_override(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = _get(params, "RC_OVERRIDE_TIME")
    if isinstance(v, CheckResult):
        return v
    if v < 0:
        return CheckResult(
            "RC_OVERRIDE_TIME",
            Status.WRONG,
            _fmt(v),
            "RC overrides never lapse: a companion (the Dart) that stops leaves its last sticks in force; "
            "set RC_OVERRIDE_TIME = 3 (s)",
        )
    if v == 0:
        return CheckResult("RC_OVERRIDE_TIME", Status.OK, _fmt(v), "RC overrides are ignored (the Dart cannot fly)")
    return CheckResult("RC_OVERRIDE_TIME", Status.OK, _fmt(v), f"RC overrides lapse {_fmt(v)} s after the last one")


def check_ardupilot_gcs_failsafe(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = _get(params, "FS_GCS_ENABLE")
    if isinstance(v, CheckResult):
        return v
    if v == 0:
        return CheckResult(
            "FS_GCS_ENABLE",
            Status.OK,
            _fmt(v),
            "no GCS failsafe: a lost link leaves ArduCopter in GUIDED, stopped after GUID_TIMEOUT; the mission "
            "flies on when the link is back",
        )
    action = AP_FS_GCS_ACTIONS.get(int(v)) if v == int(v) else None
    if action is None:
        return CheckResult(
            "FS_GCS_ENABLE", Status.WRONG, _fmt(v), "not an ArduCopter value (0-7): set FS_GCS_ENABLE = 0"
        )
    name, mode = action
    return _resume_check("FS_GCS_ENABLE", v, mode, f"ArduCopter {name}", req, "set FS_GCS_ENABLE = 0")


def check_ardupilot_mode_switch(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = _get(params, "FLTMODE_CH")
    if isinstance(v, CheckResult):
        return v
    if v != int(v) or not 0 <= v <= 16:
        return CheckResult("FLTMODE_CH", Status.WRONG, _fmt(v), "not an RC channel (0-16): set FLTMODE_CH = 5")
    if v == 0:
        return CheckResult(
            "FLTMODE_CH",
            Status.WRONG,
            _fmt(v),
            "no flight-mode switch: the pilot cannot take the vehicle back with a switch; set FLTMODE_CH = 5",
        )
    if v <= 4:
        return CheckResult(
            "FLTMODE_CH",
            Status.WRONG,
            _fmt(v),
            f"the flight-mode switch is on stick channel {int(v)}: set FLTMODE_CH to a switch channel (5-16)",
        )
    return CheckResult("FLTMODE_CH", Status.OK, _fmt(v), f"pilot's mode switch on channel {int(v)}")


def check_ardupilot_precland(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    if req.landing_controller != "autopilot":
        return []
    out: list[CheckResult] = []
    v = _get(params, "PLND_ENABLED")
    if isinstance(v, CheckResult):
        out.append(v)
    elif v != 1:
        out.append(
            CheckResult(
                "PLND_ENABLED",
                Status.WRONG,
                _fmt(v),
                "landing.controller = 'autopilot' hands the descent to LAND with precision landing: "
                "set PLND_ENABLED = 1",
            )
        )
    else:
        out.append(CheckResult("PLND_ENABLED", Status.OK, _fmt(v), "LAND lands on the target"))
    v = _get(params, "PLND_TYPE")
    if isinstance(v, CheckResult):
        out.append(v)
    elif v != 1:
        out.append(
            CheckResult(
                "PLND_TYPE",
                Status.WRONG,
                _fmt(v),
                "the target comes from this companion's LANDING_TARGET: set PLND_TYPE = 1 (MAVLink) "
                "and landing.landing_target_output = 'body_angles'",
            )
        )
    elif req.landing_target_output != "body_angles":
        out.append(
            CheckResult(
                "PLND_TYPE",
                Status.WRONG,
                _fmt(v),
                f"ArduCopter reads the body-frame angles: set landing.landing_target_output = 'body_angles' "
                f"(now {req.landing_target_output!r})",
            )
        )
    else:
        out.append(CheckResult("PLND_TYPE", Status.OK, _fmt(v), "target from our LANDING_TARGET (body angles)"))
    return out


def check_ardupilot_release(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    """GRIP_ENABLE and a SERVOn_FUNCTION = 28 output for the gripper; a free output for the servo."""
    if req.release == "gripper":
        out: list[CheckResult] = []
        v = _get(params, "GRIP_ENABLE")
        if isinstance(v, CheckResult):
            out.append(v)
        elif v != 1:
            out.append(
                CheckResult(
                    "GRIP_ENABLE",
                    Status.WRONG,
                    _fmt(v),
                    "payload.release = 'gripper' but ArduCopter's gripper is off (DO_GRIPPER answers FAILED): "
                    "set GRIP_ENABLE = 1",
                )
            )
        else:
            out.append(CheckResult("GRIP_ENABLE", Status.OK, _fmt(v), "gripper enabled"))
        found, unread = [], []
        for n in range(1, AP_SERVO_OUTPUTS + 1):
            f = params.get(f"SERVO{n}_FUNCTION")
            if f is None or isinstance(f, ParamUnavailable) or not math.isfinite(f):
                unread.append(n)
            elif int(f) == AP_GRIPPER_FUNCTION:
                found.append(n)
        if found:
            outs = ", ".join(f"SERVO{n}" for n in found)
            out.append(CheckResult("gripper output", Status.OK, outs, f"{outs}_FUNCTION = 28 (gripper)"))
        elif len(unread) == AP_SERVO_OUTPUTS:
            out.append(CheckResult("gripper output", Status.UNKNOWN, "-", "no SERVOn_FUNCTION could be read"))
        else:
            miss = f" ({len(unread)} outputs not read)" if unread else ""
            out.append(
                CheckResult(
                    "gripper output",
                    Status.WRONG,
                    "none",
                    f"no output drives the gripper{miss}: set SERVOn_FUNCTION = 28 on the gripper's output",
                )
            )
        return out
    if req.release == "servo":
        name = f"SERVO{req.servo_channel}_FUNCTION"
        v = _get(params, name)
        if isinstance(v, CheckResult):
            return [v]
        if v != 0:
            return [
                CheckResult(
                    name,
                    Status.WRONG,
                    _fmt(v),
                    f"payload.servo_channel = {req.servo_channel} is an output with function {int(v)}, which "
                    f"drives it too: set {name} = 0 or pick a free output for payload.servo_channel",
                )
            ]
        return [CheckResult(name, Status.OK, _fmt(v), f"output {req.servo_channel} is free for DO_SET_SERVO")]
    return [
        CheckResult(
            "payload.release",
            Status.WRONG,
            req.release,
            "ArduPilot has no actuator-set command: set payload.release = 'gripper' or 'servo'",
        )
    ]


def check_ardupilot(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    return [
        check_ardupilot_guided_timeout(req, params),
        check_ardupilot_rc_override(req, params),
        check_ardupilot_gcs_failsafe(req, params),
        check_ardupilot_mode_switch(req, params),
        *check_ardupilot_precland(req, params),
        *check_ardupilot_release(req, params),
    ]


# ---------------------------------------------------------------------------- sensors and the clock
def check_camera(req: Requirements, probe: CameraProbe | None) -> list[CheckResult]:
    """Frame size against the calibration, frame rate against ``landing.camera_rate_hz``."""
    if req.camera_size_px is None:
        return []
    if probe is None:
        return [CheckResult("camera", Status.UNKNOWN, "-", "not probed")]
    if probe.error:
        return [CheckResult("camera", Status.UNKNOWN, "-", probe.error)]
    out: list[CheckResult] = []
    w, h = req.camera_size_px
    if probe.width_px is None or probe.height_px is None:
        out.append(CheckResult("camera resolution", Status.UNKNOWN, "-", "no frame arrived"))
    elif (probe.width_px, probe.height_px) != (w, h):
        out.append(
            CheckResult(
                "camera resolution",
                Status.WRONG,
                f"{probe.width_px}x{probe.height_px}",
                f"the calibration (landing.camera_calibration) is for {w}x{h}: set the camera to {w}x{h} "
                "or calibrate it at this size",
            )
        )
    else:
        out.append(CheckResult("camera resolution", Status.OK, f"{w}x{h}", "matches the calibration"))
    if probe.fps is None:
        out.append(CheckResult("camera rate", Status.UNKNOWN, "-", f"too few frames to measure ({probe.frames})"))
    elif probe.fps < CAMERA_RATE_TOLERANCE * req.camera_rate_hz:
        out.append(
            CheckResult(
                "camera rate",
                Status.WRONG,
                f"{probe.fps:.1f} Hz",
                f"below landing.camera_rate_hz = {_fmt(req.camera_rate_hz)}: set the camera to that rate "
                f"or set landing.camera_rate_hz = {math.floor(probe.fps)}",
            )
        )
    else:
        out.append(
            CheckResult(
                "camera rate", Status.OK, f"{probe.fps:.1f} Hz", f"landing.camera_rate_hz = {_fmt(req.camera_rate_hz)}"
            )
        )
    return out


def check_uwb(req: Requirements, probe: UwbProbe | None) -> list[CheckResult]:
    """Every anchor of the layout heard by the tag."""
    if req.uwb_anchor_ids is None:
        return []
    if probe is None:
        return [CheckResult("UWB anchors", Status.UNKNOWN, "-", "not probed")]
    if probe.error:
        return [CheckResult("UWB anchors", Status.UNKNOWN, "-", probe.error)]
    want = req.uwb_anchor_ids
    seen = probe.anchors_seen & want
    value = f"{len(seen)}/{len(want)}"
    missing = sorted(want - probe.anchors_seen)
    if missing:
        return [
            CheckResult(
                "UWB anchors",
                Status.WRONG,
                value,
                f"not heard: {', '.join(missing)} (landing.uwb_anchors); power them or fix their ids in the layout",
            )
        ]
    extra = sorted(probe.anchors_seen - want)
    note = f"; also heard, not in the layout: {', '.join(extra)}" if extra else ""
    return [CheckResult("UWB anchors", Status.OK, value, f"all anchors of the layout heard{note}")]


def check_clock(req: Requirements, probe: ClockProbe | None) -> CheckResult:
    """The autopilot's UTC against the companion's wall clock (logs, telemetry timestamps and the
    freshness of signed ground commands depend on it)."""
    if probe is None:
        return CheckResult("clock", Status.UNKNOWN, "-", "not probed")
    if probe.error or probe.offset_s is None:
        return CheckResult("clock", Status.UNKNOWN, "-", probe.error or "no offset")
    off = probe.offset_s
    if abs(off) > req.clock_tolerance_s:
        return CheckResult(
            "clock",
            Status.WRONG,
            f"{off:+.3f} s",
            f"the companion's clock is {abs(off):.1f} s {'behind' if off > 0 else 'ahead of'} the autopilot's UTC "
            f"(tolerance {req.clock_tolerance_s:g} s): sync the companion's clock (NTP/chrony, or from GPS)",
        )
    return CheckResult(
        "clock", Status.OK, f"{off:+.3f} s", f"autopilot UTC - companion clock (within {req.clock_tolerance_s:g} s)"
    )


#: the streams the delivery flies on, and what raises their rate on each firmware
STREAMS = {"PositionNed": "local position", "Attitude": "attitude"}
STREAM_FIX = {
    "px4": "raise MAV_x_RATE of the companion's MAVLink instance (0 = as fast as the link allows) "
    "or the link's baud rate",
    "ardupilot": "raise SRn_POSITION / SRn_EXTRA1 of the companion's serial port or its baud rate",
}


def check_streams(req: Requirements, probe: StreamProbe | None) -> list[CheckResult]:
    """Position and attitude arrive at least at half the guidance rate (each guidance tick then
    uses a sample at most two ticks old)."""
    if probe is None:
        return [CheckResult("telemetry rate", Status.UNKNOWN, "-", "not measured")]
    need = req.guidance_rate_hz / 2.0
    out: list[CheckResult] = []
    for kind, what in STREAMS.items():
        hz = probe.rates_hz.get(kind, 0.0)
        name = f"{what} rate"
        if hz <= 0.0:
            # nothing at all: the autopilot has no estimate yet (ArduPilot sends LOCAL_POSITION_NED
            # only once its EKF has an origin, ~20 s after a SITL boot) or the stream is off;
            # the mission waits for it (mission.ready_timeout_s), so not a wrong setting
            out.append(
                CheckResult(
                    name,
                    Status.UNKNOWN,
                    "0 Hz",
                    f"no {what} in {probe.window_s:.1f} s: the autopilot has no estimate yet (check again once "
                    f"it has a position), or the stream is off ({STREAM_FIX[req.autopilot]})",
                )
            )
        elif hz < need:
            out.append(
                CheckResult(
                    name,
                    Status.WRONG,
                    f"{hz:.1f} Hz",
                    f"{what} arrives at {hz:.1f} Hz over {probe.window_s:.1f} s, under half of "
                    f"runtime.guidance_rate_hz = {_fmt(req.guidance_rate_hz)} ({need:g} Hz): "
                    f"{STREAM_FIX[req.autopilot]}",
                )
            )
        else:
            out.append(CheckResult(name, Status.OK, f"{hz:.1f} Hz", f">= {need:g} Hz (half the guidance rate)"))
    return out


def run_checks(
    req: Requirements,
    params: Mapping[str, ParamValue],
    *,
    camera: CameraProbe | None = None,
    uwb: UwbProbe | None = None,
    clock: ClockProbe | None = None,
    streams: StreamProbe | None = None,
) -> PreflightReport:
    rows = check_px4(req, params) if req.autopilot == "px4" else check_ardupilot(req, params)
    if streams is not None:
        rows += check_streams(req, streams)
    rows += check_camera(req, camera)
    rows += check_uwb(req, uwb)
    rows.append(check_clock(req, clock))
    return PreflightReport(req.autopilot, tuple(rows))


# ------------------------------------------------------------------------------------------ readers
async def read_params(autopilot: Any, req: Requirements) -> dict[str, ParamValue]:
    """The parameters the checks need, from a connected PX4 or ArduPilot backend."""
    if req.autopilot == "px4":
        return dict(await autopilot.read_params(px4_param_types(req)))
    out: dict[str, ParamValue] = {}
    for name in ardupilot_param_names(req):
        v = await autopilot.read_param(name)
        out[name] = ParamUnavailable("no PARAM_VALUE answer") if v is None else float(v)
    return out


def clock_probe_from(system_time: tuple[int, float] | None, what: str = "SYSTEM_TIME") -> ClockProbe:
    """A :class:`ClockProbe` from ``(time_unix_usec, companion wall time at arrival)``."""
    if system_time is None:
        return ClockProbe(error=f"no {what} from the autopilot")
    usec, wall = system_time
    if usec <= 0:
        return ClockProbe(error="the autopilot has no UTC time (SYSTEM_TIME.time_unix_usec = 0: no GPS time yet?)")
    return ClockProbe(offset_s=usec / 1e6 - wall)


async def probe_clock(autopilot: Any, timeout_s: float = 2.0) -> ClockProbe:
    try:
        st = await autopilot.system_time(timeout_s)
    except Exception as err:  # a backend error is an unknown row, not a crash
        return ClockProbe(error=f"{type(err).__name__}: {err}")
    return clock_probe_from(st)


def probe_camera(camera: Any, seconds: float = 2.0, started: bool = False, what: str = "") -> CameraProbe:
    """Read a ``companion.cameras`` driver for ``seconds``: frame size and rate (distinct frames
    over the span of their exposure times, so a video file played faster than real time still
    gives its own rate)."""
    times: list[float] = []
    size: tuple[int, int] | None = None
    last_index = None
    t_end = time.monotonic() + seconds
    try:
        if not started:
            camera.start()
        while time.monotonic() < t_end:
            f = camera.read()
            if f is None or f.index == last_index:
                time.sleep(0.002)
                continue
            last_index = f.index
            times.append(float(f.time_s))
            h, w = f.image.shape[:2]
            size = (int(w), int(h))
    except Exception as err:
        return CameraProbe(error=f"{what or 'camera'} ({type(camera).__name__}): {err}")
    finally:
        if not started:
            try:
                camera.stop()
            except Exception as err:
                log.debug("camera stop: %s", err)
    if size is None:
        return CameraProbe(error=f"{what or 'camera'}: no frame within {seconds:g} s")
    fps = stream_rate_hz(times) if len(times) >= 3 else None
    return CameraProbe(size[0], size[1], fps or None, len(times))


def probe_uwb(uwb: Any, seconds: float = 2.0, started: bool = False, what: str = "") -> UwbProbe:
    """Read a ``companion.uwb`` driver for ``seconds``: the anchor ids it reported ranges to."""
    seen: set[str] = set()
    n = 0
    t_end = time.monotonic() + seconds
    try:
        if not started:
            uwb.start()
        while time.monotonic() < t_end:
            r = uwb.read()
            items = r if isinstance(r, list | tuple) else [] if r is None else [r]
            if not items:
                time.sleep(0.01)
                continue
            for item in items:
                n += 1
                seen.update(_anchor_ids(item))
    except Exception as err:
        return UwbProbe(error=f"{what or 'UWB'} ({type(uwb).__name__}): {err}")
    finally:
        if not started:
            try:
                uwb.stop()
            except Exception as err:
                log.debug("uwb stop: %s", err)
    if n == 0:
        return UwbProbe(error=f"{what or 'UWB'}: no reading within {seconds:g} s")
    return UwbProbe(frozenset(seen), n)


def _anchor_ids(reading: Any) -> Sequence[str]:
    ids = getattr(reading, "anchor_ids", None)
    if ids is not None:
        return [str(a) for a in ids]
    anchors = getattr(reading, "anchors", ())
    return [str(getattr(a, "anchor_id", a)) for a in anchors]


def stream_rate_hz(arrivals: Sequence[float]) -> float:
    """Samples per second between the first and the last arrival (a stream that starts late in
    the window is measured while it runs); 0 with fewer than two."""
    if len(arrivals) < 2 or arrivals[-1] <= arrivals[0]:
        return 0.0
    return (len(arrivals) - 1) / (arrivals[-1] - arrivals[0])


async def preflight(
    autopilot: Any,
    req: Requirements,
    *,
    camera: CameraProbe | None = None,
    uwb: UwbProbe | None = None,
    stream_window_s: float = 1.5,
) -> PreflightReport:
    """Read the parameters and the clock from the connected ``autopilot``, measure its position and
    attitude rates meanwhile (over ``stream_window_s`` at least), and run every check."""
    arrivals: dict[str, list[float]] = {k: [] for k in STREAMS}

    def on_sample(sample: Any) -> None:
        times = arrivals.get(type(sample).__name__)
        if times is not None:
            times.append(time.monotonic())

    tc = autopilot.telemetry
    tc.add_listener(on_sample)
    try:
        t0 = time.monotonic()
        params = await read_params(autopilot, req)
        clock = await probe_clock(autopilot)
        rest = stream_window_s - (time.monotonic() - t0)
        if rest > 0:
            await asyncio.sleep(rest)
    finally:
        tc.remove_listener(on_sample)
    streams = StreamProbe({k: stream_rate_hz(v) for k, v in arrivals.items()}, time.monotonic() - t0)
    return run_checks(req, params, camera=camera, uwb=uwb, clock=clock, streams=streams)

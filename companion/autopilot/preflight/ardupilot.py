"""The pre-flight rules for ArduCopter 4.x.

Parameters (copter.parm): GUID_TIMEOUT (s, default 3), RC_OVERRIDE_TIME (s, default 3, -1 = never
lapses), FS_GCS_ENABLE (0 off, 1 RTL, 2 RTL/continue in AUTO, 3 SmartRTL or RTL, 4 SmartRTL or
Land, 5 Land, 6 DO_LAND_START or RTL, 7 Brake or Land; default 0), FLTMODE_CH (0 none, else the
RC channel; default 5), GRIP_ENABLE (default 0), SERVOn_FUNCTION (28 = gripper, 0 = no
function), PLND_ENABLED (default 0), PLND_TYPE (1 = MAVLink companion), FS_GCS_TIMEOUT (s, default
5), FS_OPTIONS (bitmask, default 16; bit 5, 32, releases the gripper on any failsafe). ArduPilot
sends every parameter as a float.

The GCS failsafe is what acts when the companion dies: ArduCopter counts the heartbeats of
MAV_GCS_SYSID (255, the companion's system id) and, FS_GCS_TIMEOUT after the last, takes the
FS_GCS_ENABLE action; with 0 a dead companion leaves the vehicle hovering in GUIDED (it stops
GUID_TIMEOUT after the last setpoint) until the battery fails safe (docs/flying.md, "Who is in
control").
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from companion.autopilot.preflight.external_nav import check_ardupilot_external_nav, external_nav_param_names
from companion.autopilot.preflight.report import (
    CheckResult,
    ParamUnavailable,
    ParamValue,
    Requirements,
    Status,
)
from companion.autopilot.preflight.rules import (
    check_link_loss_resume,
    check_setpoint_timeout,
    fmt,
    param_or_unknown,
)
from companion.autopilot.preflight.safety import ardupilot_safety_param_names, check_ardupilot_safety

AP_FS_GCS_ACTIONS: dict[int, tuple[str, str | None]] = {  # FS_GCS_ENABLE -> (ArduCopter name, FlightMode value)
    1: ("RTL", "rtl"),
    2: ("RTL (continue in AUTO)", "rtl"),
    3: ("SmartRTL or RTL", "rtl"),
    4: ("SmartRTL or Land", "rtl"),
    5: ("Land", "land"),
    6: ("DO_LAND_START or RTL", "rtl"),
    7: ("Brake or Land", "hold"),
}
AP_FS_GCS_LAND = 5
AP_FS_OPTION_RELEASE_GRIPPER = 32  # FS_OPTIONS bit 5: release the gripper on any failsafe
AP_GRIPPER_FUNCTION = 28
AP_SERVO_OUTPUTS = 16
AP_GUID_OPTION_NO_POSITION_XY = 16  # GUID_OPTIONS bit 4, DoNotStabilizePositionXY


def ardupilot_param_names(req: Requirements) -> list[str]:
    """The ArduPilot parameters the checks read."""
    names = ["GUID_TIMEOUT", "RC_OVERRIDE_TIME", "FS_GCS_ENABLE", "FS_GCS_TIMEOUT", "FLTMODE_CH"]
    if req.landing_controller == "autopilot":
        names += ["PLND_ENABLED", "PLND_TYPE"]
    if req.release == "gripper":
        names += ["FS_OPTIONS", "GRIP_ENABLE", *(f"SERVO{n}_FUNCTION" for n in range(1, AP_SERVO_OUTPUTS + 1))]
    elif req.release == "servo":
        names.append(f"SERVO{req.servo_channel}_FUNCTION")
    if req.moving_pad:
        names.append("GUID_OPTIONS")
    return names + ardupilot_safety_param_names(req) + external_nav_param_names(req)


def check_ardupilot_moving_pad(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    """A moving pad (docs/moving-pad.md): GUIDED must fly the velocity setpoints without a
    position target of its own. With one, the target runs on ahead once the ground (or the deck)
    stops the vehicle, the lean request winds up and the land detector never fires."""
    if not req.moving_pad:
        return []
    v = param_or_unknown(params, "GUID_OPTIONS")
    if isinstance(v, CheckResult):
        return [v]
    if int(v) & AP_GUID_OPTION_NO_POSITION_XY:
        return [CheckResult("GUID_OPTIONS", Status.OK, fmt(v), "bit 4 set: GUIDED keeps no position target of its own")]
    return [
        CheckResult(
            "GUID_OPTIONS",
            Status.WRONG,
            fmt(v),
            "landing.moving_pad.enabled: set bit 4 (DoNotStabilizePositionXY, add 16): without it GUIDED's position "
            "target runs on ahead when the vehicle meets the pad, and ArduCopter does not detect the landing",
        )
    ]


def check_ardupilot_guided_timeout(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = param_or_unknown(params, "GUID_TIMEOUT")
    if isinstance(v, CheckResult):
        return v
    return check_setpoint_timeout("GUID_TIMEOUT", v, req, "GUIDED stops the vehicle")


def check_ardupilot_rc_override(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = param_or_unknown(params, "RC_OVERRIDE_TIME")
    if isinstance(v, CheckResult):
        return v
    if v < 0:
        return CheckResult(
            "RC_OVERRIDE_TIME",
            Status.WRONG,
            fmt(v),
            "RC overrides never lapse: a companion (the Dart) that stops leaves its last sticks in force; "
            "set RC_OVERRIDE_TIME = 3 (s)",
        )
    if v == 0:
        return CheckResult("RC_OVERRIDE_TIME", Status.OK, fmt(v), "RC overrides are ignored (the Dart cannot fly)")
    return CheckResult("RC_OVERRIDE_TIME", Status.OK, fmt(v), f"RC overrides lapse {fmt(v)} s after the last one")


def check_ardupilot_gcs_failsafe(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    """FS_GCS_ENABLE: what ArduCopter does when the companion's heartbeat stops (it dies, or the
    link is lost for longer than FS_GCS_TIMEOUT). The companion expects 5, Land: the vehicle lands
    where it is with the parcel aboard (measured: tests/real_ardupilot/test_arducopter_companion_killed.py)."""
    v = param_or_unknown(params, "FS_GCS_ENABLE")
    if isinstance(v, CheckResult):
        return v
    t = param_or_unknown(params, "FS_GCS_TIMEOUT")
    after = f"{fmt(t)} s" if not isinstance(t, CheckResult) else "FS_GCS_TIMEOUT"
    if v == 0:
        return CheckResult(
            "FS_GCS_ENABLE",
            Status.WARN,
            fmt(v),
            "no GCS failsafe: if the companion dies ArduCopter hovers in GUIDED (stopped after GUID_TIMEOUT) until "
            "its battery fails safe; set FS_GCS_ENABLE = 5 (Land) to land where it is, parcel aboard",
        )
    action = AP_FS_GCS_ACTIONS.get(int(v)) if v == int(v) else None
    if action is None:
        return CheckResult(
            "FS_GCS_ENABLE", Status.WRONG, fmt(v), "not an ArduCopter value (0-7): set FS_GCS_ENABLE = 5 (Land)"
        )
    name, mode = action
    if v == AP_FS_GCS_LAND:
        resume = "the mission resumes" if mode in req.link_loss_resume_modes else "the companion leaves it to LAND"
        return CheckResult(
            "FS_GCS_ENABLE",
            Status.OK,
            fmt(v),
            f"{after} after the companion's last heartbeat (it died, or a link loss) ArduCopter lands where it is; "
            f"on a reconnect {resume}",
        )
    return check_link_loss_resume("FS_GCS_ENABLE", v, mode, f"ArduCopter {name}", req, "set FS_GCS_ENABLE = 5 (Land)")


def check_ardupilot_failsafe_release(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    """FS_OPTIONS bit 5 releases the gripper on any failsafe (GCS, radio, battery): the parcel
    would drop wherever the failsafe fires, over people or in the cruise."""
    if req.release != "gripper":
        return []
    v = param_or_unknown(params, "FS_OPTIONS")
    if isinstance(v, CheckResult):
        return [v]
    if v != int(v) or v < 0:
        return [CheckResult("FS_OPTIONS", Status.WRONG, fmt(v), "not a bitmask: set FS_OPTIONS = 16 (the default)")]
    if int(v) & AP_FS_OPTION_RELEASE_GRIPPER:
        return [
            CheckResult(
                "FS_OPTIONS",
                Status.WRONG,
                fmt(v),
                "bit 5 (32) releases the gripper on any failsafe: a dead companion or a lost link would drop the "
                f"parcel wherever the vehicle is; set FS_OPTIONS = {int(v) & ~AP_FS_OPTION_RELEASE_GRIPPER}",
            )
        ]
    return [CheckResult("FS_OPTIONS", Status.OK, fmt(v), "a failsafe does not release the gripper (bit 5 clear)")]


def check_ardupilot_mode_switch(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = param_or_unknown(params, "FLTMODE_CH")
    if isinstance(v, CheckResult):
        return v
    if v != int(v) or not 0 <= v <= 16:
        return CheckResult("FLTMODE_CH", Status.WRONG, fmt(v), "not an RC channel (0-16): set FLTMODE_CH = 5")
    if v == 0:
        return CheckResult(
            "FLTMODE_CH",
            Status.WRONG,
            fmt(v),
            "no flight-mode switch: the pilot cannot take the vehicle back with a switch; set FLTMODE_CH = 5",
        )
    if v <= 4:
        return CheckResult(
            "FLTMODE_CH",
            Status.WRONG,
            fmt(v),
            f"the flight-mode switch is on stick channel {int(v)}: set FLTMODE_CH to a switch channel (5-16)",
        )
    return CheckResult("FLTMODE_CH", Status.OK, fmt(v), f"pilot's mode switch on channel {int(v)}")


def check_ardupilot_precland(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    if req.landing_controller != "autopilot":
        return []
    out: list[CheckResult] = []
    v = param_or_unknown(params, "PLND_ENABLED")
    if isinstance(v, CheckResult):
        out.append(v)
    elif v != 1:
        out.append(
            CheckResult(
                "PLND_ENABLED",
                Status.WRONG,
                fmt(v),
                "landing.controller = 'autopilot' hands the descent to LAND with precision landing: "
                "set PLND_ENABLED = 1",
            )
        )
    else:
        out.append(CheckResult("PLND_ENABLED", Status.OK, fmt(v), "LAND lands on the target"))
    v = param_or_unknown(params, "PLND_TYPE")
    if isinstance(v, CheckResult):
        out.append(v)
    elif v != 1:
        out.append(
            CheckResult(
                "PLND_TYPE",
                Status.WRONG,
                fmt(v),
                "the target comes from this companion's LANDING_TARGET: set PLND_TYPE = 1 (MAVLink) "
                "and landing.landing_target_output = 'body_angles'",
            )
        )
    elif req.landing_target_output != "body_angles":
        out.append(
            CheckResult(
                "PLND_TYPE",
                Status.WRONG,
                fmt(v),
                f"ArduCopter reads the body-frame angles: set landing.landing_target_output = 'body_angles' "
                f"(now {req.landing_target_output!r})",
            )
        )
    else:
        out.append(CheckResult("PLND_TYPE", Status.OK, fmt(v), "target from our LANDING_TARGET (body angles)"))
    return out


def check_ardupilot_release(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    """GRIP_ENABLE and a SERVOn_FUNCTION = 28 output for the gripper; a free output for the servo."""
    if req.release == "gripper":
        out: list[CheckResult] = []
        v = param_or_unknown(params, "GRIP_ENABLE")
        if isinstance(v, CheckResult):
            out.append(v)
        elif v != 1:
            out.append(
                CheckResult(
                    "GRIP_ENABLE",
                    Status.WRONG,
                    fmt(v),
                    "payload.release = 'gripper' but ArduCopter's gripper is off (DO_GRIPPER answers FAILED): "
                    "set GRIP_ENABLE = 1",
                )
            )
        else:
            out.append(CheckResult("GRIP_ENABLE", Status.OK, fmt(v), "gripper enabled"))
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
        v = param_or_unknown(params, name)
        if isinstance(v, CheckResult):
            return [v]
        if v != 0:
            return [
                CheckResult(
                    name,
                    Status.WRONG,
                    fmt(v),
                    f"payload.servo_channel = {req.servo_channel} is an output with function {int(v)}, which "
                    f"drives it too: set {name} = 0 or pick a free output for payload.servo_channel",
                )
            ]
        return [CheckResult(name, Status.OK, fmt(v), f"output {req.servo_channel} is free for DO_SET_SERVO")]
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
        *check_ardupilot_failsafe_release(req, params),
        *check_ardupilot_safety(req, params),
        *check_ardupilot_external_nav(req, params),
        *check_ardupilot_moving_pad(req, params),
    ]

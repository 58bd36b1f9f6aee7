"""The pre-flight rules for PX4 v1.16.

Parameters (names, meanings and defaults): COM_OF_LOSS_T (float, s, default 1.0), COM_OBL_RC_ACT
(int32, 0 Position, 1 Altitude, 2 Manual, 3 Return, 4 Land, 5 Hold, 6 Terminate, 7 Disarm;
default 0), COM_RC_OVERRIDE (int32 bitmask, bit 0 auto modes, bit 1 offboard, bit 2 ignore
throttle; default 1), EKF2_GPS_CTRL (int32 bitmask, bit 0 horizontal position; default 7),
EKF2_HGT_REF (int32, 0 baro, 1 GNSS, 2 range, 3 vision; default 1), PLD_BTOUT (float, s,
default 5), PLD_HACC_RAD (float, m, default 0.2), EKF2_EV_CTRL (int32 bitmask, bit 0 horizontal
position, 1 vertical, 2 velocity, 3 yaw; 0 on the SIH build), COM_POSCTL_NAVL (int32, 0 Altitude/Manual,
1 Land/Descend; default 0). PX4 sends int32 parameters byte-wise; MAVSDK's
Param plugin decodes them.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Literal

from companion.autopilot.preflight.external_nav import check_px4_external_nav, px4_external_nav_param_types
from companion.autopilot.preflight.report import (
    CheckResult,
    ParamValue,
    Requirements,
    Status,
)
from companion.autopilot.preflight.rules import (
    MIN_SETPOINT_PERIODS,
    check_link_loss_resume,
    check_setpoint_timeout,
    fmt,
    param_or_unknown,
)
from companion.autopilot.preflight.safety import check_px4_safety, px4_safety_param_types

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
PX4_OBL_POSITION = 0
PX4_OBL_LAND = 4
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
    names.update(px4_safety_param_types(req))
    names.update({k: "int" for k in px4_external_nav_param_types(req)})
    return names


def check_px4_offboard_loss(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = param_or_unknown(params, "COM_OF_LOSS_T")
    if isinstance(v, CheckResult):
        return v
    return check_setpoint_timeout("COM_OF_LOSS_T", v, req, "PX4 leaves OFFBOARD")


def check_px4_offboard_loss_action(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = param_or_unknown(params, "COM_OBL_RC_ACT")
    if isinstance(v, CheckResult):
        return v
    action = PX4_OBL_ACTIONS.get(int(v)) if v == int(v) else None
    if action is None:
        return CheckResult(
            "COM_OBL_RC_ACT", Status.WRONG, fmt(v), "not a PX4 v1.16 value (0-7): set COM_OBL_RC_ACT = 0"
        )
    name, mode = action
    if int(v) == PX4_OBL_LAND:
        resume = "the mission resumes" if mode in req.link_loss_resume_modes else "the companion leaves it to LAND"
        return CheckResult(
            "COM_OBL_RC_ACT",
            Status.OK,
            fmt(v),
            "COM_OF_LOSS_T after our last setpoint (the companion died, or a link loss) PX4 lands where it is; on a "
            f"reconnect {resume}",
        )
    row = check_link_loss_resume("COM_OBL_RC_ACT", v, mode, f"PX4 {name}", req, "set COM_OBL_RC_ACT = 4 (Land)")
    if int(v) == PX4_OBL_POSITION and row.status is Status.OK:
        # measured on v1.16 SIH (tests/real_px4/test_px4_companion_killed.py, docs/companion-death.md)
        return CheckResult(
            "COM_OBL_RC_ACT",
            Status.WARN,
            fmt(v),
            "if the companion dies PX4 goes to Position mode: with a pilot's RC it hovers for the pilot; without RC "
            "Position mode cannot run and PX4 only sinks on its failsafe setpoint; set COM_OBL_RC_ACT = 4 (Land) to "
            "land where it is (a link loss longer than COM_OF_LOSS_T then lands it too)",
        )
    return row


def check_px4_rc_override(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = param_or_unknown(params, "COM_RC_OVERRIDE")
    if isinstance(v, CheckResult):
        return v
    if v != int(v) or not 0 <= v <= 7:
        return CheckResult(
            "COM_RC_OVERRIDE", Status.WRONG, fmt(v), "not a PX4 v1.16 bitmask (0-7): set COM_RC_OVERRIDE = 1 or 3"
        )
    if int(v) & 2:
        return CheckResult("COM_RC_OVERRIDE", Status.OK, fmt(v), "moving the sticks takes the vehicle out of OFFBOARD")
    return CheckResult(
        "COM_RC_OVERRIDE",
        Status.OK,
        fmt(v),
        "the sticks do not end OFFBOARD: the pilot takes over with the mode switch (3 lets the sticks do it too)",
    )


def check_px4_ekf_gps(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = param_or_unknown(params, "EKF2_GPS_CTRL")
    if isinstance(v, CheckResult):
        return v
    if v != int(v) or v < 0:
        return CheckResult("EKF2_GPS_CTRL", Status.WRONG, fmt(v), "not a bitmask: set EKF2_GPS_CTRL = 7")
    if not int(v) & 1:
        return CheckResult(
            "EKF2_GPS_CTRL",
            Status.WRONG,
            fmt(v),
            "PX4's EKF does not use GNSS position (bit 0), but the delivery flies to a pad given by "
            "latitude/longitude: set EKF2_GPS_CTRL = 7",
        )
    return CheckResult("EKF2_GPS_CTRL", Status.OK, fmt(v), "GNSS horizontal position fused (bit 0)")


def check_px4_ekf_height(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = param_or_unknown(params, "EKF2_HGT_REF")
    if isinstance(v, CheckResult):
        return v
    ref = PX4_HGT_REF.get(int(v)) if v == int(v) else None
    if ref is None:
        return CheckResult("EKF2_HGT_REF", Status.WRONG, fmt(v), "not a PX4 v1.16 value (0-3): set EKF2_HGT_REF = 1")
    if ref == "vision":
        return CheckResult(
            "EKF2_HGT_REF",
            Status.WRONG,
            fmt(v),
            "height from external vision, which this companion does not send: set EKF2_HGT_REF = 0 (baro) or 1 (GNSS)",
        )
    return CheckResult("EKF2_HGT_REF", Status.OK, fmt(v), f"height reference: {ref}")


def check_px4_precland(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    """PLD_* when PX4's AUTO.PRECLAND flies the final descent (``landing.controller = 'autopilot'``)."""
    if req.landing_controller != "autopilot":
        return []
    out: list[CheckResult] = []
    v = param_or_unknown(params, "PLD_BTOUT")
    if isinstance(v, CheckResult):
        out.append(v)
    else:
        lo = max(0.5, MIN_SETPOINT_PERIODS / req.camera_rate_hz)
        if v < lo:
            out.append(
                CheckResult(
                    "PLD_BTOUT",
                    Status.WRONG,
                    fmt(v),
                    f"PX4 gives the target up after {fmt(v)} s, shorter than {lo:.2f} s (3 frames at "
                    f"landing.camera_rate_hz = {fmt(req.camera_rate_hz)}, at least 0.5 s): set PLD_BTOUT >= {lo:.2f}",
                )
            )
        else:
            out.append(CheckResult("PLD_BTOUT", Status.OK, fmt(v), f"target timeout {fmt(v)} s (>= {lo:.2f} s)"))
    v = param_or_unknown(params, "PLD_HACC_RAD")
    if isinstance(v, CheckResult):
        out.append(v)
    else:
        half = req.pad_size_m / 2.0
        if v > half:
            out.append(
                CheckResult(
                    "PLD_HACC_RAD",
                    Status.WRONG,
                    fmt(v),
                    f"PX4 starts the final descent up to {fmt(v)} m off the target, more than half the pad "
                    f"(mission.pad.size_m = {fmt(req.pad_size_m)}): set PLD_HACC_RAD <= {half:g}",
                )
            )
        else:
            out.append(CheckResult("PLD_HACC_RAD", Status.OK, fmt(v), f"final descent within {fmt(v)} m of the target"))
    return out


def check_px4(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    return [
        check_px4_offboard_loss(req, params),
        check_px4_offboard_loss_action(req, params),
        check_px4_rc_override(req, params),
        check_px4_ekf_gps(req, params),
        check_px4_ekf_height(req, params),
        *check_px4_precland(req, params),
        *check_px4_safety(req, params),
        *check_px4_external_nav(req, params),
    ]

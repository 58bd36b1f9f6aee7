"""The pre-flight rules of ``[external_nav]`` on ArduCopter 4.x and on PX4 v1.16 (at the end; docs/external-nav.md).

The companion streams VISION_POSITION_ESTIMATE (AP_VisualOdom, VISO_TYPE = 1: MAVLink) and, when
GNSS is lost near the pad, switches EKF3 to source set n = ``external_nav.source_set``, which must
take its horizontal position from it (EK3_SRCn_POSXY = 6, ExternalNav), no horizontal velocity
(EK3_SRCn_VELXY = 0: the pose carries none, and the fused velocity is the autopilot's own), height
from the barometer (EK3_SRCn_POSZ = 1: the fused height is the barometer's too) and yaw from the
compass (EK3_SRCn_YAW = 1: the pose's yaw is the autopilot's own). Where GNSS is lost out of camera
and UWB range the EKF failsafe acts: FS_EKF_ACTION 1 (Land) or 3 (Land, also in non-GPS modes)
lands where it is; 2 (AltHold) leaves the vehicle drifting with the wind until the pilot acts.
With VISO_TYPE = 1 ArduCopter refuses to arm ("PreArm: VisOdom: not healthy") until a pose arrives,
and the pose exists only near the pad: ARMING_CHECK must leave out the visual-odometry check (bit
18; bit 0, "all", would include it): 1835006 keeps every other check (ArduCopter 4.7-dev of 2025-07;
later ArduPilot replaces ARMING_CHECK with ARMING_SKIPCHK, where bit 18 set skips it).
"""

from __future__ import annotations

from collections.abc import Mapping

from companion.autopilot.preflight.report import CheckResult, ParamValue, Requirements, Status
from companion.autopilot.preflight.rules import fmt, param_or_unknown

VISO_TYPE_MAVLINK = 1
EK3_SRC_EXTNAV = 6
EK3_SRC_NONE = 0
EK3_SRC_BARO = 1
EK3_SRC_COMPASS = 1
ARMING_CHECK_ALL = 1
ARMING_CHECK_VISION = 1 << 18  # AP_Arming::Check::VISION
ARMING_CHECKS_BUT_VISION = (1 << 21) - 2 - ARMING_CHECK_VISION  # bits 1-20 but 18: 1835006
FS_EKF_ACTIONS = {1: "Land", 2: "AltHold", 3: "Land (also in non-GPS modes)"}

# (parameter suffix, wanted value, what it is, why)
_SOURCE_RULES = (
    ("POSXY", EK3_SRC_EXTNAV, "ExternalNav", "the horizontal position from the companion's pose"),
    ("VELXY", EK3_SRC_NONE, "None", "the pose carries no velocity (the fused velocity is the autopilot's own)"),
    ("POSZ", EK3_SRC_BARO, "Baro", "the height from the barometer, as the fused height is"),
    ("YAW", EK3_SRC_COMPASS, "Compass", "the pose's yaw is the autopilot's own"),
)


def external_nav_param_names(req: Requirements) -> list[str]:
    n = req.external_nav_source_set
    if n is None:
        return []
    return ["VISO_TYPE", "ARMING_CHECK", "FS_EKF_ACTION", *(f"EK3_SRC{n}_{suffix}" for suffix, *_ in _SOURCE_RULES)]


def check_ardupilot_external_nav(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    n = req.external_nav_source_set
    if n is None:
        return []
    out: list[CheckResult] = []
    v = param_or_unknown(params, "VISO_TYPE")
    if isinstance(v, CheckResult):
        out.append(v)
    elif v != VISO_TYPE_MAVLINK:
        out.append(
            CheckResult(
                "VISO_TYPE",
                Status.WRONG,
                fmt(v),
                "external_nav.enabled: ArduPilot must read the pose from MAVLink (VISION_POSITION_ESTIMATE): "
                "set VISO_TYPE = 1 and reboot",
            )
        )
    else:
        out.append(CheckResult("VISO_TYPE", Status.OK, fmt(v), "VISION_POSITION_ESTIMATE read from MAVLink"))
    out.append(_check_arming_checks(params))
    for suffix, want, name, why in _SOURCE_RULES:
        key = f"EK3_SRC{n}_{suffix}"
        v = param_or_unknown(params, key)
        if isinstance(v, CheckResult):
            out.append(v)
        elif v != want:
            out.append(
                CheckResult(
                    key,
                    Status.WRONG,
                    fmt(v),
                    f"source set {n} (external_nav.source_set) navigates on the companion's pose: set {key} = "
                    f"{want} ({name}): {why}",
                )
            )
        else:
            out.append(CheckResult(key, Status.OK, fmt(v), f"{name}: {why}"))
    v = param_or_unknown(params, "FS_EKF_ACTION")
    if isinstance(v, CheckResult):
        out.append(v)
    elif v in (1, 3):
        out.append(
            CheckResult(
                "FS_EKF_ACTION",
                Status.OK,
                fmt(v),
                f"GNSS lost out of camera and UWB range: the EKF failsafe lands ({FS_EKF_ACTIONS[int(v)]})",
            )
        )
    elif v == 2:
        out.append(
            CheckResult(
                "FS_EKF_ACTION",
                Status.WARN,
                fmt(v),
                "GNSS lost out of camera and UWB range: AltHold drifts with the wind until the pilot acts; "
                "FS_EKF_ACTION = 1 lands where it is",
            )
        )
    else:
        out.append(
            CheckResult(
                "FS_EKF_ACTION",
                Status.WRONG,
                fmt(v),
                "not an EKF failsafe action ArduCopter lands or holds with (1 Land, 2 AltHold, 3 Land): set "
                "FS_EKF_ACTION = 1",
            )
        )
    return out


def _check_arming_checks(params: Mapping[str, ParamValue]) -> CheckResult:
    v = param_or_unknown(params, "ARMING_CHECK")
    if isinstance(v, CheckResult):
        return v
    if v != int(v) or v < 0:
        return CheckResult(
            "ARMING_CHECK", Status.WRONG, fmt(v), f"not a bitmask: set ARMING_CHECK = {ARMING_CHECKS_BUT_VISION}"
        )
    mask = int(v)
    if mask & ARMING_CHECK_ALL or mask & ARMING_CHECK_VISION:
        want = ARMING_CHECKS_BUT_VISION if mask & ARMING_CHECK_ALL else mask & ~ARMING_CHECK_VISION
        return CheckResult(
            "ARMING_CHECK",
            Status.WRONG,
            fmt(v),
            "VISO_TYPE = 1 refuses arming until a pose arrives (PreArm: VisOdom: not healthy) and the companion "
            f"sends one only near the pad: set ARMING_CHECK = {want} (every other check kept, bit 18 off)",
        )
    if mask == 0:
        return CheckResult("ARMING_CHECK", Status.WARN, fmt(v), "every pre-arm check is off, not only the vision one")
    return CheckResult("ARMING_CHECK", Status.OK, fmt(v), "the visual-odometry pre-arm check is off (bit 18)")


# PX4 v1.16 EKF2_EV_CTRL (int32 bitmask): bit 0 horizontal position, 1 vertical position, 2 velocity, 3 yaw
EV_CTRL_HPOS, EV_CTRL_VPOS, EV_CTRL_VEL, EV_CTRL_YAW = 1, 2, 4, 8
_EV_CTRL_OFF = (
    (EV_CTRL_VPOS, "vertical position (bit 1): the height stays EKF2's own (EKF2_HGT_REF), as the fused one is"),
    (EV_CTRL_VEL, "velocity (bit 2): the ODOMETRY's velocity is a zero placeholder, the fused one is PX4's own"),
    (EV_CTRL_YAW, "yaw (bit 3): the pose's yaw is PX4's own"),
)


# PX4 v1.16 COM_POSCTL_NAVL (int32): what the failsafe does without a position estimate, from a
# mode that needs one: 0 Altitude/Manual (PX4's default), 1 Land/Descend
POSCTL_NAVL = {0: "Altitude/Manual", 1: "Land/Descend"}


def px4_external_nav_param_types(req: Requirements) -> dict[str, str]:
    return {"EKF2_EV_CTRL": "int", "COM_POSCTL_NAVL": "int"} if req.external_nav_source_set is not None else {}


def check_px4_external_nav(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    """EKF2_EV_CTRL = 1 (horizontal position only) with ``[external_nav] enabled`` (the companion's
    ODOMETRY, companion/autopilot/px4/external_nav.py), and what PX4 does with GNSS lost out of
    camera and UWB range (COM_POSCTL_NAVL)."""
    if req.external_nav_source_set is None:
        return []
    return [_check_ev_ctrl(params), _check_posctl_navl(params)]


def _check_posctl_navl(params: Mapping[str, ParamValue]) -> CheckResult:
    v = param_or_unknown(params, "COM_POSCTL_NAVL")
    if isinstance(v, CheckResult):
        return v
    if v == 1:
        return CheckResult("COM_POSCTL_NAVL", Status.OK, fmt(v), "GNSS lost out of range: PX4 lands where it is")
    if v == 0:
        why = (
            "GNSS lost out of camera and UWB range: PX4 leaves OFFBOARD for Altitude mode (measured on SIH) and "
            "drifts with the wind until a pilot acts; COM_POSCTL_NAVL = 1 lands where it is"
        )
        return CheckResult("COM_POSCTL_NAVL", Status.WARN, fmt(v), why)
    return CheckResult("COM_POSCTL_NAVL", Status.WRONG, fmt(v), "not a PX4 v1.16 value (0, 1): set COM_POSCTL_NAVL = 1")


def _check_ev_ctrl(params: Mapping[str, ParamValue]) -> CheckResult:
    v = param_or_unknown(params, "EKF2_EV_CTRL")
    if isinstance(v, CheckResult):
        return v
    if v != int(v) or v < 0:
        return CheckResult("EKF2_EV_CTRL", Status.WRONG, fmt(v), "not a bitmask: set EKF2_EV_CTRL = 1")
    mask = int(v)
    if not mask & EV_CTRL_HPOS:
        why = (
            "external_nav.enabled: EKF2 must fuse the companion's pose as horizontal position (bit 0), or GNSS lost "
            "near the pad ends the delivery: set EKF2_EV_CTRL = 1"
        )
        return CheckResult("EKF2_EV_CTRL", Status.WRONG, fmt(v), why)
    wrong = [why for bit, why in _EV_CTRL_OFF if mask & bit]
    if wrong:
        why = "external_nav.enabled: set EKF2_EV_CTRL = 1 (horizontal position only); off: " + "; ".join(wrong)
        return CheckResult("EKF2_EV_CTRL", Status.WRONG, fmt(v), why)
    return CheckResult("EKF2_EV_CTRL", Status.OK, fmt(v), "the companion's pose fused as horizontal position only")

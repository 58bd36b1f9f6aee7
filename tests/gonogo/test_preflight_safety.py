"""The pre-flight rows for the autopilot's own safety nets (fence action, battery failsafe, Remote
ID), each with hand-written parameter values: what the companion expects, and what to set."""

from __future__ import annotations

import dataclasses

from companion.autopilot.preflight.report import ParamUnavailable, Requirements, Status
from companion.autopilot.preflight.safety import (
    ardupilot_safety_param_names,
    check_ardupilot_battery,
    check_ardupilot_fence,
    check_ardupilot_remote_id,
    check_px4_battery,
    check_px4_fence,
    check_px4_remote_id,
    px4_safety_param_types,
)

PX4 = Requirements("px4", setpoint_rate_hz=20.0, link_loss_resume_modes=("hold",))
AP = Requirements("ardupilot", setpoint_rate_hz=20.0, link_loss_resume_modes=("hold",))
FENCED = dict(fence_enabled=True, fence_max_alt_rel_m=60.0)


def rows(rs):  # type: ignore[no-untyped-def]
    return {r.name: (r.status, r.detail) for r in rs}


def test_px4_fence_action_is_judged_only_with_a_fence() -> None:
    (r,) = check_px4_fence(PX4, {"GF_ACTION": 1.0})
    assert r.status is Status.OK and "[fence] is off" in r.detail
    px4f = dataclasses.replace(PX4, **FENCED)  # type: ignore[arg-type]
    assert "GF_MAX_VER_DIST" in px4_safety_param_types(px4f)
    out = rows(check_px4_fence(px4f, {"GF_ACTION": 1.0, "GF_MAX_VER_DIST": 0.0}))
    assert out["GF_ACTION"][0] is Status.WRONG and "set GF_ACTION = 2" in out["GF_ACTION"][1]
    assert (
        out["GF_MAX_VER_DIST"][0] is Status.WRONG
        and "is off, above fence.max_alt_rel_m = 60" in out["GF_MAX_VER_DIST"][1]
    )
    out = rows(check_px4_fence(px4f, {"GF_ACTION": 4.0, "GF_MAX_VER_DIST": 50.0}))
    assert out["GF_ACTION"][0] is Status.WRONG and "kills the motors" in out["GF_ACTION"][1]
    assert out["GF_MAX_VER_DIST"][0] is Status.OK
    out = rows(check_px4_fence(px4f, {"GF_ACTION": 3.0, "GF_MAX_VER_DIST": 80.0}))
    assert out["GF_ACTION"][0] is Status.OK and "PX4 Return" in out["GF_ACTION"][1]
    assert (
        out["GF_MAX_VER_DIST"][0] is Status.WRONG and "set GF_MAX_VER_DIST to 60 or less" in out["GF_MAX_VER_DIST"][1]
    )


def test_px4_battery_failsafe_and_our_reserve() -> None:
    out = rows(check_px4_battery(PX4, {"COM_LOW_BAT_ACT": 0.0, "BAT_CRIT_THR": 0.07}))
    assert out["COM_LOW_BAT_ACT"][0] is Status.WRONG and "set COM_LOW_BAT_ACT = 3" in out["COM_LOW_BAT_ACT"][1]
    assert out["BAT_CRIT_THR"][0] is Status.OK and "battery_check is off" in out["BAT_CRIT_THR"][1]
    checked = dataclasses.replace(PX4, battery_check=True, battery_reserve_pct=5.0)
    out = rows(check_px4_battery(checked, {"COM_LOW_BAT_ACT": 3.0, "BAT_CRIT_THR": 0.07}))
    assert out["COM_LOW_BAT_ACT"][0] is Status.OK
    # 7 % critical >= 5 % reserve: PX4's failsafe acts first
    assert out["BAT_CRIT_THR"][0] is Status.WRONG and "critical level (7 %)" in out["BAT_CRIT_THR"][1]
    checked = dataclasses.replace(PX4, battery_check=True, battery_reserve_pct=20.0)
    out = rows(check_px4_battery(checked, {"COM_LOW_BAT_ACT": 3.0, "BAT_CRIT_THR": 0.07}))
    assert out["BAT_CRIT_THR"][0] is Status.OK and "the companion returns first" in out["BAT_CRIT_THR"][1]


def test_remote_id_rows() -> None:
    assert check_px4_remote_id(PX4, {"COM_ARM_ODID": 0.0}).status is Status.OK
    req = dataclasses.replace(PX4, remote_id_required=True)
    r = check_px4_remote_id(req, {"COM_ARM_ODID": 1.0})
    assert r.status is Status.WRONG and "set COM_ARM_ODID = 2" in r.detail
    assert check_px4_remote_id(req, {"COM_ARM_ODID": 2.0}).status is Status.OK
    missing = {"DID_ENABLE": ParamUnavailable("no PARAM_VALUE answer")}
    assert check_ardupilot_remote_id(AP, missing).status is Status.OK
    r = check_ardupilot_remote_id(dataclasses.replace(AP, remote_id_required=True), missing)
    assert r.status is Status.WRONG and "OpenDroneID" in r.detail


def test_ardupilot_fence_rows() -> None:
    defaults = {"FENCE_ENABLE": 0.0, "FENCE_TYPE": 7.0, "FENCE_ACTION": 1.0, "FENCE_ALT_MAX": 100.0}
    (r,) = check_ardupilot_fence(AP, defaults)
    assert r.status is Status.OK and "fence is off" in r.detail
    apf = dataclasses.replace(AP, **FENCED)  # type: ignore[arg-type]
    assert "FENCE_ALT_MAX" in ardupilot_safety_param_names(apf)
    out = rows(check_ardupilot_fence(apf, defaults))
    assert out["FENCE_ENABLE"][0] is Status.WRONG and "set FENCE_ENABLE = 1" in out["FENCE_ENABLE"][1]
    assert out["FENCE_TYPE"][0] is Status.OK and "circle" in out["FENCE_TYPE"][1]
    assert out["FENCE_ACTION"][0] is Status.OK
    assert (
        out["FENCE_ALT_MAX"][0] is Status.WRONG and "100 m, above fence.max_alt_rel_m = 60" in out["FENCE_ALT_MAX"][1]
    )
    out = rows(check_ardupilot_fence(apf, {**defaults, "FENCE_ENABLE": 1.0, "FENCE_TYPE": 3.0, "FENCE_ACTION": 0.0}))
    assert out["FENCE_TYPE"][0] is Status.WRONG and "add 4 to FENCE_TYPE" in out["FENCE_TYPE"][1]
    assert out["FENCE_ACTION"][0] is Status.WRONG and "only reported" in out["FENCE_ACTION"][1]


def test_ardupilot_battery_failsafe_needs_an_action_with_a_threshold() -> None:
    copter_parm = {"BATT_FS_LOW_ACT": 0.0, "BATT_FS_CRT_ACT": 0.0, "BATT_LOW_VOLT": 10.5, "BATT_CRT_VOLT": 0.0}
    copter_parm |= {"BATT_LOW_MAH": 0.0, "BATT_CRT_MAH": 0.0}
    out = rows(check_ardupilot_battery(AP, copter_parm))
    assert out["battery failsafe"][0] is Status.WRONG and "BATT_FS_LOW_ACT = 2" in out["battery failsafe"][1]
    out = rows(check_ardupilot_battery(AP, {**copter_parm, "BATT_FS_LOW_ACT": 2.0}))
    assert out["battery failsafe"][0] is Status.OK
    assert out["battery failsafe"][1] == "ArduCopter acts on its battery without us"
    # an action without a threshold never fires
    out = rows(check_ardupilot_battery(AP, {**copter_parm, "BATT_FS_CRT_ACT": 1.0}))
    assert out["battery failsafe"][0] is Status.WRONG
    out = rows(check_ardupilot_battery(AP, {**copter_parm, "BATT_FS_CRT_ACT": 5.0}))
    assert out["BATT_FS_CRT_ACT"][0] is Status.WRONG and "Terminate" in out["BATT_FS_CRT_ACT"][1]

"""The pre-flight rows for the autopilot's own safety nets (docs/go-no-go.md): its fence action,
its battery failsafe and its Remote ID arming rule. They are what still holds when the companion
dies, so the companion expects:

- fence: with ``[fence] enabled`` the autopilot acts on a breach of the uploaded polygons (PX4
  GF_ACTION hold / return / land; ArduPilot FENCE_ENABLE = 1, FENCE_TYPE with the polygon bit,
  FENCE_ACTION not report-only), and its ceiling is no higher than ``fence.max_alt_rel_m``.
- battery: the autopilot lands or returns by itself on a critical battery (PX4 COM_LOW_BAT_ACT != 0;
  ArduPilot BATT_FS_CRT_ACT land/RTL with a threshold set), and with ``[go_no_go] battery_check``
  our reserve sits above its critical level, so the companion's return comes first.
- Remote ID: with ``[go_no_go] remote_id_required`` arming needs it (PX4 COM_ARM_ODID = 2,
  ArduPilot DID_ENABLE = 1); otherwise the setting is reported.

PX4 v1.16: GF_ACTION (0 none, 1 warning, 2 hold, 3 return, 4 terminate, 5 land; default 2),
GF_MAX_VER_DIST (m, 0 = none), COM_LOW_BAT_ACT (0 warning, 1 return, 2 land, 3 return at critical
and land at emergency; the SITL's rcS sets 3), BAT_CRIT_THR (fraction, default 0.07),
COM_ARM_ODID (0 off, 1 warn, 2 require). ArduCopter 4.7: FENCE_ENABLE (default 0), FENCE_TYPE
(bits: 1 max altitude, 2 circle, 4 polygon, 8 min altitude), FENCE_ACTION (0 report only, 1 RTL or
land, 2 land, 3 SmartRTL/RTL/land, 4 brake/land, 5 SmartRTL/land), FENCE_ALT_MAX (m),
BATT_FS_LOW_ACT / BATT_FS_CRT_ACT (0 none, 1 land, 2 RTL, 3 SmartRTL or RTL, 4 SmartRTL or land,
5 terminate, 6 DO_LAND_START or RTL, 7 brake or land), BATT_LOW_VOLT / BATT_CRT_VOLT (V),
BATT_LOW_MAH / BATT_CRT_MAH (mAh), DID_ENABLE (only in builds with OpenDroneID).
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Literal

from companion.autopilot.preflight.report import CheckResult, ParamValue, Requirements, Status
from companion.autopilot.preflight.rules import fmt, param_or_unknown

PX4_GF_ACTIONS = {0: "none", 1: "warning only", 2: "Hold", 3: "Return", 4: "Terminate", 5: "Land"}
PX4_LOW_BAT_ACTIONS = {
    0: "warning only",
    1: "Return",
    2: "Land",
    3: "Return at the critical level, Land at the emergency level",
}
AP_FENCE_ACTIONS = {
    0: "report only",
    1: "RTL or Land",
    2: "Land",
    3: "SmartRTL or RTL or Land",
    4: "Brake or Land",
    5: "SmartRTL or Land",
}
AP_BATT_ACTIONS = {
    0: "none",
    1: "Land",
    2: "RTL",
    3: "SmartRTL or RTL",
    4: "SmartRTL or Land",
    5: "Terminate",
    6: "DO_LAND_START or RTL",
    7: "Brake or Land",
}


def px4_safety_param_types(req: Requirements) -> dict[str, Literal["int", "float"]]:
    names: dict[str, Literal["int", "float"]] = {
        "GF_ACTION": "int",
        "COM_LOW_BAT_ACT": "int",
        "BAT_CRIT_THR": "float",
        "COM_ARM_ODID": "int",
    }
    if req.fence_enabled and req.fence_max_alt_rel_m is not None:
        names["GF_MAX_VER_DIST"] = "float"
    return names


def ardupilot_safety_param_names(req: Requirements) -> list[str]:
    names = ["FENCE_ENABLE", "FENCE_TYPE", "FENCE_ACTION", "BATT_FS_LOW_ACT", "BATT_FS_CRT_ACT"]
    names += ["BATT_LOW_VOLT", "BATT_CRT_VOLT", "BATT_LOW_MAH", "BATT_CRT_MAH", "DID_ENABLE"]
    if req.fence_enabled and req.fence_max_alt_rel_m is not None:
        names.append("FENCE_ALT_MAX")
    return names


def _enum(v: float, table: Mapping[int, str]) -> str | None:
    return table.get(int(v)) if v == int(v) else None


# ---------------------------------------------------------------- PX4
def check_px4_fence(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    v = param_or_unknown(params, "GF_ACTION")
    if isinstance(v, CheckResult):
        return [v]
    name = _enum(v, PX4_GF_ACTIONS)
    if name is None:
        return [CheckResult("GF_ACTION", Status.WRONG, fmt(v), "not a PX4 v1.16 value (0-5): set GF_ACTION = 2 (Hold)")]
    out: list[CheckResult] = []
    if not req.fence_enabled:
        out.append(
            CheckResult("GF_ACTION", Status.OK, fmt(v), f"a fence breach -> {name}; [fence] is off: no fence uploaded")
        )
    elif int(v) in (2, 3, 5):
        out.append(
            CheckResult("GF_ACTION", Status.OK, fmt(v), f"a breach of the uploaded fence -> PX4 {name}, without us")
        )
    else:
        why = "kills the motors in the air" if int(v) == 4 else "does nothing about it"
        out.append(
            CheckResult(
                "GF_ACTION",
                Status.WRONG,
                fmt(v),
                f"a breach of the uploaded fence -> {name}: PX4 {why} if the companion is gone; set GF_ACTION = 2 "
                "(Hold), 3 (Return) or 5 (Land)",
            )
        )
    if req.fence_enabled and req.fence_max_alt_rel_m is not None:
        out.append(_ceiling("GF_MAX_VER_DIST", params, req.fence_max_alt_rel_m, "PX4's ceiling above home"))
    return out


def _ceiling(name: str, params: Mapping[str, ParamValue], ours: float, what: str) -> CheckResult:
    c = param_or_unknown(params, name)
    if isinstance(c, CheckResult):
        return c
    if c <= 0 or c > ours:
        return CheckResult(
            name,
            Status.WRONG,
            fmt(c),
            f"{what} is {'off' if c <= 0 else f'{fmt(c)} m'}, above fence.max_alt_rel_m = {fmt(ours)} m: set {name} "
            f"to {fmt(ours)} or less",
        )
    return CheckResult(name, Status.OK, fmt(c), f"{what} {fmt(c)} m, within fence.max_alt_rel_m = {fmt(ours)} m")


def check_px4_battery(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    out: list[CheckResult] = []
    v = param_or_unknown(params, "COM_LOW_BAT_ACT")
    if isinstance(v, CheckResult):
        out.append(v)
    else:
        name = _enum(v, PX4_LOW_BAT_ACTIONS)
        if name is None or int(v) == 0:
            out.append(
                CheckResult(
                    "COM_LOW_BAT_ACT",
                    Status.WRONG,
                    fmt(v),
                    f"{'not a PX4 v1.16 value (0-3)' if name is None else 'PX4 only warns on a low battery'}: with the "
                    "companion gone nothing brings the vehicle down; set COM_LOW_BAT_ACT = 3",
                )
            )
        else:
            out.append(CheckResult("COM_LOW_BAT_ACT", Status.OK, fmt(v), f"a low battery -> PX4 {name}"))
    t = param_or_unknown(params, "BAT_CRIT_THR")
    if isinstance(t, CheckResult):
        out.append(t)
    else:
        out.append(_reserve_row("BAT_CRIT_THR", 100.0 * t, fmt(t), req))
    return out


def _reserve_row(name: str, crit_pct: float, shown: str, req: Requirements) -> CheckResult:
    if not req.battery_check:
        return CheckResult(name, Status.OK, shown, f"critical at {crit_pct:.0f} %; [go_no_go] battery_check is off")
    if req.battery_reserve_pct <= crit_pct:
        return CheckResult(
            name,
            Status.WRONG,
            shown,
            f"the autopilot's critical level ({crit_pct:.0f} %) is at or above our reserve "
            f"(go_no_go.battery_reserve_pct = {fmt(req.battery_reserve_pct)} %): its failsafe would act before the "
            "companion's return; raise the reserve above it",
        )
    return CheckResult(
        name,
        Status.OK,
        shown,
        f"critical at {crit_pct:.0f} %, below our reserve of {fmt(req.battery_reserve_pct)} %: "
        "the companion returns first",
    )


def check_px4_remote_id(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = param_or_unknown(params, "COM_ARM_ODID")
    if isinstance(v, CheckResult):
        return v
    what = {0: "not checked", 1: "a warning without it", 2: "arming refused without it"}.get(int(v), "unknown value")
    if req.remote_id_required and v != 2:
        return CheckResult(
            "COM_ARM_ODID",
            Status.WRONG,
            fmt(v),
            f"Remote ID: {what}; go_no_go.remote_id_required: set COM_ARM_ODID = 2",
        )
    return CheckResult("COM_ARM_ODID", Status.OK, fmt(v), f"Remote ID: {what}")


def check_px4_safety(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    return [*check_px4_fence(req, params), *check_px4_battery(req, params), check_px4_remote_id(req, params)]


# ---------------------------------------------------------------- ArduPilot
def check_ardupilot_fence(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    out: list[CheckResult] = []
    en = param_or_unknown(params, "FENCE_ENABLE")
    typ = param_or_unknown(params, "FENCE_TYPE")
    act = param_or_unknown(params, "FENCE_ACTION")
    for row in (en, typ, act):
        if isinstance(row, CheckResult):
            out.append(row)
    if out:
        return out
    assert not isinstance(en, CheckResult) and not isinstance(typ, CheckResult) and not isinstance(act, CheckResult)
    action = _enum(act, AP_FENCE_ACTIONS)
    if not req.fence_enabled:
        state = "on" if en == 1 else "off"
        return [
            CheckResult(
                "FENCE_ENABLE", Status.OK, fmt(en), f"ArduPilot's fence is {state}; [fence] is off: none uploaded"
            )
        ]
    if en != 1:
        out.append(
            CheckResult(
                "FENCE_ENABLE",
                Status.WRONG,
                fmt(en),
                "the uploaded fence is not enforced by ArduPilot: set FENCE_ENABLE = 1",
            )
        )
    else:
        out.append(CheckResult("FENCE_ENABLE", Status.OK, fmt(en), "ArduPilot enforces its fence"))
    bits = int(typ) if typ == int(typ) else 0
    if not bits & 4:
        out.append(
            CheckResult(
                "FENCE_TYPE",
                Status.WRONG,
                fmt(typ),
                "the polygon bit (4) is clear: ArduPilot ignores the uploaded polygons; add 4 to FENCE_TYPE",
            )
        )
    else:
        extra = " (and its circle, FENCE_RADIUS, around home)" if bits & 2 else ""
        out.append(CheckResult("FENCE_TYPE", Status.OK, fmt(typ), f"ArduPilot acts on the polygons{extra}"))
    if action is None or int(act) == 0:
        out.append(
            CheckResult(
                "FENCE_ACTION",
                Status.WRONG,
                fmt(act),
                "a breach is only reported: with the companion gone nothing keeps the vehicle inside; set "
                "FENCE_ACTION = 1 (RTL or Land) or 4 (Brake or Land)",
            )
        )
    else:
        out.append(CheckResult("FENCE_ACTION", Status.OK, fmt(act), f"a breach -> ArduCopter {action}, without us"))
    if req.fence_max_alt_rel_m is not None:
        if not bits & 1:
            out.append(
                CheckResult(
                    "FENCE_ALT_MAX",
                    Status.WRONG,
                    fmt(typ),
                    "fence.max_alt_rel_m is set but FENCE_TYPE's altitude bit (1) is clear: add 1 to FENCE_TYPE",
                )
            )
        else:
            out.append(_ceiling("FENCE_ALT_MAX", params, req.fence_max_alt_rel_m, "ArduPilot's ceiling"))
    return out


def check_ardupilot_battery(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    """A row for each level's action, then whether some level both acts and has a threshold to
    fire at (low: BATT_LOW_VOLT / BATT_LOW_MAH; critical: BATT_CRT_VOLT / BATT_CRT_MAH)."""
    out: list[CheckResult] = []
    acting: list[str] = []
    unknown = False
    for name, level, volt, mah in (
        ("BATT_FS_LOW_ACT", "low", "BATT_LOW_VOLT", "BATT_LOW_MAH"),
        ("BATT_FS_CRT_ACT", "critical", "BATT_CRT_VOLT", "BATT_CRT_MAH"),
    ):
        v = param_or_unknown(params, name)
        if isinstance(v, CheckResult):
            out.append(v)
            unknown = True
            continue
        action = _enum(v, AP_BATT_ACTIONS)
        if action is None or int(v) == 5:
            out.append(
                CheckResult(
                    name,
                    Status.WRONG,
                    fmt(v),
                    f"a {level} battery -> {'Terminate: the motors stop in the air' if action else 'not a value (0-7)'}"
                    f"; set {name} = {2 if level == 'low' else 1} ({'RTL' if level == 'low' else 'Land'})",
                )
            )
            continue
        out.append(CheckResult(name, Status.OK, fmt(v), f"a {level} battery -> ArduCopter {action}"))
        if int(v) == 0:
            continue
        levels = [(n, param_or_unknown(params, n)) for n in (volt, mah)]
        set_ = [f"{n} = {fmt(x)}" for n, x in levels if not isinstance(x, CheckResult) and x > 0]
        unknown |= any(isinstance(x, CheckResult) for _, x in levels)
        if set_:
            acting.append(f"{level} ({', '.join(set_)}) -> {action}")
    if acting:
        out.append(
            CheckResult("battery failsafe", Status.OK, "; ".join(acting), "ArduCopter acts on its battery without us")
        )
    elif unknown:
        out.append(CheckResult("battery failsafe", Status.UNKNOWN, "-", "a level's action or threshold was not read"))
    else:
        out.append(
            CheckResult(
                "battery failsafe",
                Status.WRONG,
                "none",
                "no battery level both has an action and a threshold: with the companion gone the vehicle flies the "
                "battery flat; set BATT_FS_LOW_ACT = 2 (RTL) with BATT_LOW_VOLT, and BATT_FS_CRT_ACT = 1 (Land) with "
                "BATT_CRT_VOLT",
            )
        )
    return out


def check_ardupilot_remote_id(req: Requirements, params: Mapping[str, ParamValue]) -> CheckResult:
    v = param_or_unknown(params, "DID_ENABLE")
    if isinstance(v, CheckResult):
        if req.remote_id_required:
            return CheckResult(
                "DID_ENABLE",
                Status.WRONG,
                "-",
                f"go_no_go.remote_id_required but DID_ENABLE cannot be read ({v.detail}): a build without OpenDroneID?",
            )
        return CheckResult("DID_ENABLE", Status.OK, "-", f"Remote ID not in this build or not read ({v.detail})")
    if req.remote_id_required and v != 1:
        return CheckResult(
            "DID_ENABLE", Status.WRONG, fmt(v), "go_no_go.remote_id_required: set DID_ENABLE = 1 (and DID_OPTIONS)"
        )
    return CheckResult("DID_ENABLE", Status.OK, fmt(v), f"Remote ID {'on' if v == 1 else 'off'}")


def check_ardupilot_safety(req: Requirements, params: Mapping[str, ParamValue]) -> list[CheckResult]:
    return [
        *check_ardupilot_fence(req, params),
        *check_ardupilot_battery(req, params),
        check_ardupilot_remote_id(req, params),
    ]

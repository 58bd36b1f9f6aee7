"""What the rules of both firmwares share: reading a parameter (or the ``unknown`` row saying why
it is missing), the setpoint-timeout window and the link-loss resume rule."""

from __future__ import annotations

import math
from collections.abc import Mapping

from companion.autopilot.preflight.report import (
    CheckResult,
    ParamUnavailable,
    ParamValue,
    Requirements,
    Status,
)

#: minimum number of setpoint periods an autopilot's setpoint timeout must cover (a late or lost
#: setpoint or two must not trip the failsafe)
MIN_SETPOINT_PERIODS = 3.0
#: longest time the vehicle may fly on a stalled companion's last setpoint
MAX_SETPOINT_TIMEOUT_S = 5.0


def fmt(x: float) -> str:
    return f"{x:g}"


def param_or_unknown(params: Mapping[str, ParamValue], name: str) -> float | CheckResult:
    """The value of ``name``, or the ``unknown`` row saying why it is missing."""
    v = params.get(name)
    if v is None:
        return CheckResult(name, Status.UNKNOWN, "-", "not read")
    if isinstance(v, ParamUnavailable):
        return CheckResult(name, Status.UNKNOWN, "-", f"could not read {name}: {v.reason}")
    if not math.isfinite(v):
        return CheckResult(name, Status.UNKNOWN, "-", f"{name} read as {v}")
    return float(v)


def min_setpoint_timeout_s(req: Requirements) -> float:
    return MIN_SETPOINT_PERIODS / req.setpoint_rate_hz


def check_setpoint_timeout(name: str, v: float, req: Requirements, what: str) -> CheckResult:
    lo = min_setpoint_timeout_s(req)
    if v < lo:
        return CheckResult(
            name,
            Status.WRONG,
            fmt(v),
            f"{what} after {fmt(v)} s, less than {MIN_SETPOINT_PERIODS:g} setpoint periods at "
            f"runtime.setpoint_rate_hz = {fmt(req.setpoint_rate_hz)}: set {name} >= {lo:.2f} "
            f"(or raise runtime.setpoint_rate_hz)",
        )
    if v > MAX_SETPOINT_TIMEOUT_S:
        return CheckResult(
            name,
            Status.WRONG,
            fmt(v),
            f"a stalled companion leaves the vehicle on its last setpoint for {fmt(v)} s: set {name} "
            f"between {lo:.2f} and {MAX_SETPOINT_TIMEOUT_S:g}",
        )
    return CheckResult(name, Status.OK, fmt(v), f"{what} after {fmt(v)} s ({lo:.2f}-{MAX_SETPOINT_TIMEOUT_S:g} s)")


def check_link_loss_resume(
    name: str, v: float, mode: str | None, what: str, req: Requirements, fix: str
) -> CheckResult:
    modes = ", ".join(req.link_loss_resume_modes) or "none"
    if mode is None:
        return CheckResult(name, Status.WRONG, fmt(v), f"a lost link makes the vehicle {what}: {fix}")
    if mode in req.link_loss_resume_modes:
        return CheckResult(
            name,
            Status.OK,
            fmt(v),
            f"a lost link -> {what}, listed in [mission] link_loss_resume_modes ({modes}): the mission resumes",
        )
    return CheckResult(
        name,
        Status.WRONG,
        fmt(v),
        f"a lost link -> {what} ({mode}), not in [mission] link_loss_resume_modes ({modes}): the mission "
        f"would end at the reconnect; add {mode!r} to link_loss_resume_modes or {fix}",
    )

"""The pre-flight rules for the landing sensors, the clock and the telemetry rates: camera size
and rate against the calibration, UWB anchors against the layout, the autopilot's UTC against
the companion's clock, position and attitude rates against the guidance rate, the companion's
right to run real time."""

from __future__ import annotations

import math

from companion.autopilot.preflight.report import (
    CameraProbe,
    CheckResult,
    ClockProbe,
    RealtimeProbe,
    Requirements,
    Status,
    StreamProbe,
    UwbProbe,
)
from companion.autopilot.preflight.rules import fmt
from companion.timebase import ClockVerdict

#: share of ``landing.camera_rate_hz`` the measured camera rate must reach
CAMERA_RATE_TOLERANCE = 0.8


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
                f"below landing.camera_rate_hz = {fmt(req.camera_rate_hz)}: set the camera to that rate "
                f"or set landing.camera_rate_hz = {math.floor(probe.fps)}",
            )
        )
    else:
        out.append(
            CheckResult(
                "camera rate", Status.OK, f"{probe.fps:.1f} Hz", f"landing.camera_rate_hz = {fmt(req.camera_rate_hz)}"
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


def check_realtime(probe: RealtimeProbe | None) -> list[CheckResult]:
    """``runtime.realtime_priority`` permitted on this computer (no row when it is 0). A refusal is
    a warning: the flight runs at the normal policy, as it would without the setting."""
    if probe is None:
        return []
    name, value = "real-time priority", f"SCHED_RR {probe.priority}"
    if probe.refused:
        return [
            CheckResult(
                name,
                Status.WARN,
                f"{value}: refused",
                f"{probe.refused}; the flight runs at the normal policy, and on a core loaded by other "
                "processes exposure -> setpoint grows",
            )
        ]
    return [CheckResult(name, Status.OK, value, "permitted: the companion's threads run real time in flight")]


def clock_verdict(req: Requirements, probe: ClockProbe | None) -> ClockVerdict:
    """The clock check as a verdict: AGREES within the tolerance, OFF beyond it, UNKNOWN when the
    autopilot gave no UTC, NOT_CHECKED when it was not probed."""
    if probe is None:
        return ClockVerdict.NOT_CHECKED
    if probe.error or probe.offset_s is None:
        return ClockVerdict.UNKNOWN
    return ClockVerdict.OFF if abs(probe.offset_s) > req.clock_tolerance_s else ClockVerdict.AGREES


def check_clock(req: Requirements, probe: ClockProbe | None) -> CheckResult:
    """The autopilot's UTC against the companion's wall clock. The .tlog's and the companion's logs
    line up by it, and signed ground commands and orders are judged fresh on it: beyond the
    tolerance (:func:`clock_verdict` OFF) they are refused until a check agrees. Flying itself does
    not depend on it, so the row is a warning, not a failed check."""
    if probe is None:
        return CheckResult("clock", Status.UNKNOWN, "-", "not probed")
    if probe.error or probe.offset_s is None:
        return CheckResult("clock", Status.UNKNOWN, "-", probe.error or "no offset")
    off = probe.offset_s
    if abs(off) > req.clock_tolerance_s:
        return CheckResult(
            "clock",
            Status.WARN,
            f"{off:+.3f} s",
            f"the companion's clock is {abs(off):.1f} s {'behind' if off > 0 else 'ahead of'} the autopilot's UTC "
            f"(tolerance {req.clock_tolerance_s:g} s): signed ground commands and orders are refused and the flight "
            "logs will not line up with the .tlog; sync the companion's clock (NTP/chrony, or from GPS)",
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
            # only once its EKF has an origin) or the stream is off;
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
                    f"runtime.guidance_rate_hz = {fmt(req.guidance_rate_hz)} ({need:g} Hz): "
                    f"{STREAM_FIX[req.autopilot]}",
                )
            )
        else:
            out.append(CheckResult(name, Status.OK, f"{hz:.1f} Hz", f">= {need:g} Hz (half the guidance rate)"))
    return out

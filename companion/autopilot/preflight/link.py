"""The pre-flight rule for a serial link's budget (docs/serial-link.md): the bytes each way
against what the line carries (8N1: 10 bits a byte). The downlink measured over the check where
the backend counts bytes (ArduPilot; MAVSDK counts none), the uplink predicted from the setpoint
rate (the stream starts after the check) or measured if more; over half the line is a warning,
over LINK_WRONG_SHARE wrong."""

from __future__ import annotations

from dataclasses import dataclass

from companion.autopilot.preflight.report import CheckResult, Requirements, Status

BITS_PER_BYTE = 10  # 8N1: a start bit, 8 data bits, a stop bit
LINK_WARN_SHARE = 0.5  # ArduPilot sends its streams in bursts: leave the line room for them
LINK_WRONG_SHARE = 0.8
# MAVLink 2 frames (10-byte header + 2-byte CRC around the payload): the companion's uplink is
# its setpoints and its heartbeat (the GCS one; the camera component's beside it)
SETPOINT_FRAME_BYTES = 12 + 53  # SET_POSITION_TARGET_LOCAL_NED
HEARTBEAT_FRAME_BYTES = 12 + 9
HEARTBEATS_PER_S = 2.0
FIX = (
    "lower runtime.autopilot_attitude_rate_hz / autopilot_position_rate_hz (params/serial_115200.toml) "
    "or runtime.setpoint_rate_hz, or raise the line's baud rate"
)


@dataclass(frozen=True, slots=True)
class LinkProbe:
    """The line and what crossed it during the check: ``baud`` None on UDP/TCP; bytes per second
    each way None where the backend cannot count them."""

    baud: int | None
    down_bytes_s: float | None = None
    up_bytes_s: float | None = None
    seconds: float = 0.0


def predicted_uplink_bytes_s(req: Requirements) -> float:
    return req.setpoint_rate_hz * SETPOINT_FRAME_BYTES + HEARTBEATS_PER_S * HEARTBEAT_FRAME_BYTES


def check_link_budget(req: Requirements, probe: LinkProbe | None) -> list[CheckResult]:
    """One row for a serial link (none on UDP/TCP): the worse direction's share of the line decides."""
    if probe is None or probe.baud is None:
        return []
    if probe.baud <= 0:
        return [CheckResult("link budget", Status.WRONG, f"{probe.baud} baud", "a serial line needs a baud rate > 0")]
    line = probe.baud / BITS_PER_BYTE
    # the check runs before the setpoint stream starts: the uplink in flight is the larger of what
    # was measured and what the stream adds
    predicted = predicted_uplink_bytes_s(req)
    up = predicted if probe.up_bytes_s is None else max(probe.up_bytes_s, predicted)
    up_how = f"with the {req.setpoint_rate_hz:g} Hz setpoint stream, predicted from runtime.setpoint_rate_hz"
    if probe.up_bytes_s is not None:
        up_how += f"; {probe.up_bytes_s:.0f} B/s measured before it"
    parts = [f"up {up:.0f} B/s ({100 * up / line:.1f} %, {up_how})"]
    shares = [up / line]
    if probe.down_bytes_s is not None:
        parts.insert(0, f"down {probe.down_bytes_s:.0f} B/s ({100 * probe.down_bytes_s / line:.1f} %, measured)")
        shares.append(probe.down_bytes_s / line)
    else:
        parts.insert(0, "down not counted by this backend (PX4: MAV_x_RATE caps its streams, half the line by default)")
    value = f"{probe.baud} baud = {line:.0f} B/s each way"
    over = f"over {probe.seconds:.1f} s of the check (parameter reads included)" if probe.seconds else ""
    detail = "; ".join(parts) + (f"; {over}" if over else "")
    worst = max(shares)
    if worst > LINK_WRONG_SHARE:
        return [CheckResult("link budget", Status.WRONG, value, f"{detail}: over {LINK_WRONG_SHARE:.0%}; {FIX}")]
    if worst > LINK_WARN_SHARE:
        return [CheckResult("link budget", Status.WARN, value, f"{detail}: over {LINK_WARN_SHARE:.0%}; {FIX}")]
    return [CheckResult("link budget", Status.OK, value, detail)]

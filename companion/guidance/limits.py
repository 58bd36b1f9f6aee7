"""Setpoint clamping (the safety contract in docs/architecture.md: every setpoint is clamped before it
leaves)."""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from companion.config import LimitsConfig
from companion.geometry.rotations import wrap_angle
from companion.guidance.setpoint import VelocitySetpoint

log = logging.getLogger(__name__)


@dataclass(frozen=True, slots=True)
class ClampResult:
    setpoint: VelocitySetpoint
    clamped: bool
    reason: str = ""


def clamp_velocity(
    sp: VelocitySetpoint,
    limits: LimitsConfig,
    position_ned: tuple[float, float, float] | None = None,
    home_ned: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> ClampResult:
    """Clamp a velocity setpoint to speed, climb, descent and geofence limits.

    A non-finite component yields a zero-velocity setpoint (hover) and ``reason`` says why: a
    NaN must never reach the autopilot. At or beyond the geofence, velocity components that
    lead further out (horizontally or upwards) are removed; moving back in is allowed.
    """
    vals = (sp.north_m_s, sp.east_m_s, sp.down_m_s, sp.yaw_rad)
    if not all(math.isfinite(v) for v in vals):
        yaw = sp.yaw_rad if math.isfinite(sp.yaw_rad) else 0.0
        return ClampResult(VelocitySetpoint(0.0, 0.0, 0.0, yaw), True, f"non-finite setpoint {vals}")
    vn, ve, vd = sp.north_m_s, sp.east_m_s, sp.down_m_s
    reasons = []
    fenced = False  # a geofence rule took something out: no acceleration pushes on
    if position_ned is not None:
        dn, de = position_ned[0] - home_ned[0], position_ned[1] - home_ned[1]
        dist = math.hypot(dn, de)
        if dist >= limits.geofence_radius_m:
            outward = (vn * dn + ve * de) / dist
            if outward > 0.0:
                vn -= outward * dn / dist
                ve -= outward * de / dist
                reasons.append("geofence radius")
                fenced = True
        height = home_ned[2] - position_ned[2]
        if height >= limits.geofence_max_alt_m and vd < 0.0:
            vd = 0.0
            reasons.append("geofence altitude")
            fenced = True
    (vn, ve), held = _held_to((vn, ve), limits.max_horizontal_speed_m_s)
    if held:
        reasons.append("horizontal speed")
    if -vd > limits.max_climb_m_s:
        vd = -limits.max_climb_m_s
        reasons.append("climb rate")
    if vd > limits.max_descent_m_s:
        vd = limits.max_descent_m_s
        reasons.append("descent rate")
    acc = sp.accel_ne_m_s2
    if acc is not None and fenced:
        acc = None
    elif acc is not None and not all(math.isfinite(a) for a in acc):
        acc = None  # the velocity alone
        reasons.append(f"non-finite acceleration {sp.accel_ne_m_s2}")
    elif acc is not None:
        acc, held = _held_to(acc, limits.max_horizontal_accel_m_s2)
        if held:
            reasons.append("horizontal acceleration")
    out = VelocitySetpoint(vn, ve, vd, wrap_angle(sp.yaw_rad), acc)
    return ClampResult(out, bool(reasons), ", ".join(reasons))


def _held_to(xy: tuple[float, float], limit: float) -> tuple[tuple[float, float], bool]:
    """A horizontal vector scaled down to ``limit`` if longer (its direction kept); whether it was."""
    n = math.hypot(*xy)
    if n <= limit:
        return xy, False
    k = limit / n
    return (xy[0] * k, xy[1] * k), True

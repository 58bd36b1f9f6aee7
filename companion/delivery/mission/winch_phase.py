"""Winch delivery (docs/winch.md): hold over the pad (on the fused estimate) at the hover height
and step the winch sequence (delivery.winch): lower, release, reel in; then home."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING

from companion.config import WinchConfig
from companion.delivery.mission.offboard import offboard_reentry
from companion.delivery.mission.padpolicy import PAD_HEIGHT_TOLERANCE_M, PAD_POSITION_GAIN_1_S
from companion.delivery.mission.states import AbortLandState
from companion.delivery.mission.types import NOTHING, FailureKind, MissionInputs, RequestKind, Step
from companion.events import EventKind, Phase
from companion.guidance.setpoint import VelocitySetpoint

if TYPE_CHECKING:
    from companion.delivery.mission.base import MissionBase
    from companion.estimation.types import StateEstimate

PAD_HOVER_SPEED_M_S = 0.3  # the payout starts only below this horizontal speed


def winch(m: MissionBase, inp: MissionInputs) -> Step:
    """Until the payout starts, the pad-required policy holds as in a descent: a lost lock is a
    failed try (hold, search, tries). Once the line may be out the hover holds on the estimate
    whatever the lock. The sequence's end: fly home."""
    est, wc, seq = inp.estimate, m.winch_cfg, m.winch
    if est is None or m.frame is None or wc is None or seq is None:
        return NOTHING
    dn, de = m.winch_wind.offset_ne_m(inp.time_s, inp.wind)
    hover_n, hover_e = float(m.frame.pad_ned[0]) + dn, float(m.frame.pad_ned[1]) + de
    sp = _hover_setpoint(m, est, wc, hover_n, hover_e)
    req = offboard_reentry(m, inp)
    if req is not None or m.state.offboard.reenter:
        return Step(sp, req)
    locked, why = (True, "") if m.pad_policy is None else m.pads.judge(inp.pad_lock)
    if not locked and not seq.paid_out:
        h = m.height_above_ground(est)
        return Step(m.pads.try_failed(inp, f"pad lock lost in the winch hover at {h:.1f} m: {why}"))
    off = math.hypot(est.north_m - hover_n, est.east_m - hover_e)
    down = float(m.frame.pad_ned[2]) - wc.hover_height_m
    ready = (
        locked
        and off < wc.xy_tolerance_m
        and abs(est.down_m - down) < PAD_HEIGHT_TOLERANCE_M
        and math.hypot(est.north_m_s, est.east_m_s) < PAD_HOVER_SPEED_M_S
    )
    tick = seq.step(inp.time_s, ready, inp.winch, m.idle(), inp.parcel)
    for detail in tick.critical:  # first: the GCS hears the jam before anything the vehicle does about it
        m.emit(EventKind.WINCH_JAM, detail)
    for detail in tick.say:
        m.emit(EventKind.WINCH, detail)
    if tick.command is not None:
        req = m.make_request(RequestKind.WINCH, winch=tick.command)
    elif tick.release:
        req = m.make_request(RequestKind.RELEASE)
    if seq.delivered and not m.summary.delivered:
        m.summary.delivered = True
        m.emit(
            EventKind.DELIVERED,
            "parcel lowered and released on the alternate pad"
            if m.pad_index
            else "parcel lowered and released on the pad",
        )
    if tick.done and seq.jammed:
        # the line out and not coming in: flying it home at cruise height would drag it across
        # whatever lies on the way; the autopilot lands where the vehicle hovers, the line first
        m.set_abort_reason(f"the line will not reel in after {seq.tries}")
        m.goto(Phase.ABORT_LAND)
        m.state_as(AbortLandState).requested = False
        return Step(sp, None)
    if tick.done:
        m.left_pad = True
        if seq.failure and not seq.delivered:
            m.summary.fail(FailureKind.NOT_DELIVERED, f"parcel not delivered: {seq.failure}")
        m.goto(Phase.INBOUND)
    return Step(sp, req)


def _hover_setpoint(
    m: MissionBase, est: StateEstimate, wc: WinchConfig, north_m: float, east_m: float
) -> VelocitySetpoint:
    """Towards the hover point (NED north, east; hover_height_m over the pad): horizontally as the
    final descent closes its error (descent.xy_gain_1_s, at most descent.max_xy_speed_m_s),
    vertically at 1/s up to the S5 speed."""
    assert m.frame is not None
    c = m.cfg
    pad = m.frame.pad_ned
    vn = c.descent.xy_gain_1_s * (north_m - est.north_m)
    ve = c.descent.xy_gain_1_s * (east_m - est.east_m)
    vh = math.hypot(vn, ve)
    if vh > c.descent.max_xy_speed_m_s:
        vn, ve = vn * c.descent.max_xy_speed_m_s / vh, ve * c.descent.max_xy_speed_m_s / vh
    vz_max = c.sector_speed_m_s[4]
    vd = min(vz_max, max(-vz_max, PAD_POSITION_GAIN_1_S * (float(pad[2]) - wc.hover_height_m - est.down_m)))
    return VelocitySetpoint(vn, ve, vd, m.frame.yaw_to_ned(0.0))

"""Into OFFBOARD: stream field setpoints for a while before asking (PX4 refuses otherwise), and
the re-entry after a link loss during which the autopilot's failsafe changed the mode."""

from __future__ import annotations

from typing import TYPE_CHECKING

from companion.autopilot.types import FlightMode
from companion.delivery.mission.types import MissionInputs, Request, RequestKind

if TYPE_CHECKING:
    from companion.delivery.mission.base import MissionBase

OFFBOARD_STREAM_BEFORE_SWITCH_S = 0.5  # PX4 wants setpoints at > 2 Hz before OFFBOARD


def enter_offboard(m: MissionBase, inp: MissionInputs) -> Request | None:
    """Stream field setpoints for a while, then ask for OFFBOARD (PX4 refuses otherwise). The
    caller returns the setpoint alongside; this only times the switch request."""
    ob = m.state.offboard
    if ob.stream_t0 is None:
        ob.stream_t0 = inp.time_s
    if not ob.requested and m.idle() and inp.time_s - ob.stream_t0 >= OFFBOARD_STREAM_BEFORE_SWITCH_S:
        ob.requested = True
        m.expect_mode_change = True
        return m.make_request(RequestKind.START_OFFBOARD)
    return None


def in_offboard(inp: MissionInputs) -> bool:
    return inp.status is not None and inp.status.mode is FlightMode.OFFBOARD


def offboard_reentry(m: MissionBase, inp: MissionInputs) -> Request | None:
    """Back from a link loss during which the autopilot's failsafe switched to HOLD: OFFBOARD again."""
    ob = m.state.offboard
    if not ob.reenter:
        return None
    req = enter_offboard(m, inp)
    if ob.requested and req is None and m.requests.pending is None and in_offboard(inp):
        ob.reenter = False
        m.expect_mode_change = False
        ob.requested = False
        ob.stream_t0 = None
    return req

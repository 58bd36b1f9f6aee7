"""Ground commands to the mission (hold, return, land, abort), from Zenoh or the operator's GCS.
The mission decides; the safety contract (clamps, pilot priority) is untouched because every
setpoint still goes through the shell."""

from __future__ import annotations

from typing import TYPE_CHECKING

from companion.delivery.mission.states import AbortHoldState, AbortLandState
from companion.delivery.mission.types import FailureKind
from companion.events import EventKind, Phase

if TYPE_CHECKING:
    from companion.delivery.mission.base import MissionBase

RETURNABLE_PHASES = (Phase.OUTBOUND, Phase.LANDING_PAD, Phase.PAD_HOLD, Phase.PAD_SEARCH, Phase.DIVERT)


def ground_command(m: MissionBase, time_s: float, kind: str, sender: str) -> str:
    """Returns what was done, for the reply and the log."""
    m.now = time_s
    if m.phase.terminal:
        return f"ignored: mission already {m.phase.value}"
    if kind == "abort":
        m.abort(time_s, f"ground command from {sender}: abort")
        return "aborting: hold, then land"
    if kind == "land":
        m.emit(EventKind.ABORT, f"ground command from {sender}: land here")
        if m.on_ground():
            m.summary.fail(FailureKind.ABORTED, f"ground command from {sender}: land (on the ground)")
            m.goto(Phase.FAILED)
            return "on the ground: mission ended"
        m.set_abort_reason(f"ground command from {sender}: land")
        m.goto(Phase.ABORT_LAND)
        m.state_as(AbortLandState).requested = False  # (again, when already landing)
        return "landing where the vehicle is"
    if kind == "hold":
        if m.on_ground():
            return "ignored: on the ground"
        m.set_abort_reason(f"ground command from {sender}: hold")
        m.emit(EventKind.ABORT, m.abort_reason)
        m.goto(Phase.ABORT_HOLD)
        m.state_as(AbortHoldState).forever = True
        return "holding position until the pilot takes over or a land/abort command"
    if kind == "return":
        return _return(m, time_s, sender)
    return f"ignored: unknown command {kind!r}"


def _return(m: MissionBase, time_s: float, sender: str) -> str:
    if m.phase is Phase.WINCH and m.winch is not None:
        # the line comes in first (a parcel on the line would be dragged home); then inbound
        if m.winch.stop(time_s, f"ground command from {sender}: return"):
            m.emit(EventKind.WARNING, f"ground command from {sender}: reel in, then return home")
            return "reeling in, then returning home along the path"
        return "ignored: the winch sequence is already ending (reel in, then home)"
    if m.phase in RETURNABLE_PHASES:
        m.emit(EventKind.WARNING, f"ground command from {sender}: return home without delivering")
        m.summary.fail(FailureKind.RETURNED_ON_COMMAND, "returned on ground command")
        m.goto(Phase.INBOUND)
        return "returning home along the path"
    return f"ignored: cannot return from {m.phase.value}"

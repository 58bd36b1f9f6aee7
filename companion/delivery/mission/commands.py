"""Ground commands to the mission (hold, return, land, abort), from Zenoh or the operator's GCS.
The mission decides; the safety contract (clamps, pilot priority) is untouched because every
setpoint still goes through the shell."""

from __future__ import annotations

import enum
from typing import TYPE_CHECKING, assert_never

from companion.delivery.mission.states import AbortHoldState, AbortLandState
from companion.delivery.mission.types import FailureKind
from companion.events import CommandKind, EventKind, Phase

if TYPE_CHECKING:
    from companion.delivery.mission.base import MissionBase

RETURNABLE_PHASES = (
    Phase.OUTBOUND,
    Phase.LANDING_PAD,
    Phase.PAD_HOLD,
    Phase.PAD_SEARCH,
    Phase.DIVERT,
    Phase.DROP_ZONE_HOLD,
)


class CommandOutcome(enum.Enum):
    ACCEPTED = "accepted"  # done, or under way
    NOT_NOW = "not_now"  # not in this phase (on the ground, the winch ending, nothing to return from)
    ENDED = "ended"  # the mission has already ended


class CommandReply(str):
    """The mission's reply to a command: its text (for the operator and the log, a str as before)
    and its ``outcome``, which the callers decide on (the GCS's MAV_RESULT)."""

    outcome: CommandOutcome

    def __new__(cls, outcome: CommandOutcome, text: str) -> CommandReply:
        reply = super().__new__(cls, text)
        reply.outcome = outcome
        return reply

    def __getnewargs__(self) -> tuple[CommandOutcome, str]:  # type: ignore[override]
        # pickled whole (to the logging process, a campaign's worker): str's would call
        # __new__ with the text alone
        return self.outcome, str(self)


def ground_command(m: MissionBase, time_s: float, kind: CommandKind, sender: str) -> CommandReply:
    """Returns what was done, for the reply and the log. ``kind`` arrives parsed (the wire's text is
    read at the edges: :mod:`companion.telemetry.auth`, :mod:`companion.delivery.gcs`, the replay)."""
    m.now = time_s
    if m.phase.terminal:
        return CommandReply(CommandOutcome.ENDED, f"ignored: mission already {m.phase.value}")
    if kind is CommandKind.ABORT:
        m.abort(time_s, f"ground command from {sender}: abort")
        return CommandReply(CommandOutcome.ACCEPTED, "aborting: hold, then land")
    if kind is CommandKind.LAND:
        m.emit(EventKind.ABORT, f"ground command from {sender}: land here")
        if m.on_ground():
            m.summary.fail(FailureKind.ABORTED, f"ground command from {sender}: land (on the ground)")
            m.goto(Phase.FAILED)
            return CommandReply(CommandOutcome.ACCEPTED, "on the ground: mission ended")
        m.set_abort_reason(f"ground command from {sender}: land")
        m.goto(Phase.ABORT_LAND)
        m.state_as(AbortLandState).requested = False  # (again, when already landing)
        return CommandReply(CommandOutcome.ACCEPTED, "landing where the vehicle is")
    if kind is CommandKind.HOLD:
        if m.on_ground():
            return CommandReply(CommandOutcome.NOT_NOW, "ignored: on the ground")
        m.set_abort_reason(f"ground command from {sender}: hold")
        m.emit(EventKind.ABORT, m.abort_reason)
        m.goto(Phase.ABORT_HOLD)
        m.state_as(AbortHoldState).forever = True
        return CommandReply(
            CommandOutcome.ACCEPTED, "holding position until the pilot takes over or a land/abort command"
        )
    if kind is CommandKind.RETURN:
        return _return(m, time_s, sender)
    assert_never(kind)


def _return(m: MissionBase, time_s: float, sender: str) -> CommandReply:
    if m.phase is Phase.WINCH and m.winch is not None:
        # the line comes in first (a parcel on the line would be dragged home); then inbound
        if m.winch.stop(time_s, f"ground command from {sender}: return"):
            m.emit(EventKind.WARNING, f"ground command from {sender}: reel in, then return home")
            return CommandReply(CommandOutcome.ACCEPTED, "reeling in, then returning home along the path")
        return CommandReply(
            CommandOutcome.NOT_NOW, "ignored: the winch sequence is already ending (reel in, then home)"
        )
    if m.phase in RETURNABLE_PHASES:
        m.emit(EventKind.WARNING, f"ground command from {sender}: return home without delivering")
        m.summary.fail(FailureKind.RETURNED_ON_COMMAND, "returned on ground command")
        m.goto(Phase.INBOUND)
        return CommandReply(CommandOutcome.ACCEPTED, "returning home along the path")
    return CommandReply(CommandOutcome.NOT_NOW, f"ignored: cannot return from {m.phase.value}")

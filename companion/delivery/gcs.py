"""The companion in the operator's GCS (docs/gcs.md): mission events as STATUSTEXT, the computer's
state as ONBOARD_COMPUTER_STATUS, and hold / return / land from the GCS as COMMAND_LONG addressed to
our component, routed to the mission like the ground's commands (sender "gcs") and answered with
COMMAND_ACK plus a STATUSTEXT with the mission's reply.

Commands understood (what QGroundControl's custom actions, MAVProxy's ``long`` and Mission
Planner send to a component):

====================================  =========  =========================================
MAV_CMD                               mission    note
====================================  =========  =========================================
NAV_LOITER_UNLIM (17)                 hold       params ignored: holds where it is
DO_PAUSE_CONTINUE (193), param1 = 0   hold       param1 = 1 (continue) is DENIED
NAV_RETURN_TO_LAUNCH (20)             return     home along the path, parcel kept
NAV_LAND (21)                         land       params ignored: lands where it is
====================================  =========  =========================================

Anything else gets UNSUPPORTED. The answer is ACCEPTED when the mission acted, DENIED when it
has ended (or commands are off), TEMPORARILY_REJECTED when the phase does not allow it now
(a return before the outbound leg, a hold on the ground).
"""

from __future__ import annotations

import asyncio
import contextlib
import enum
import logging
import time
from collections.abc import Callable, Iterable

from companion.autopilot.component import (
    SEVERITY_CRITICAL,
    SEVERITY_INFO,
    SEVERITY_NOTICE,
    SEVERITY_WARNING,
    ComponentCommand,
    statustext_chunks,
)
from companion.autopilot.interface import Autopilot, AutopilotError
from companion.config import GcsConfig
from companion.delivery.host_status import HostStatusReader, onboard_computer_status
from companion.delivery.mission import CommandOutcome, CommandReply
from companion.events import CommandKind, EventKind, MissionEvent, Phase

log = logging.getLogger(__name__)

MAV_CMD_NAV_LOITER_UNLIM = 17
MAV_CMD_NAV_RETURN_TO_LAUNCH = 20
MAV_CMD_NAV_LAND = 21
MAV_CMD_DO_PAUSE_CONTINUE = 193

MAV_RESULT_ACCEPTED = 0
MAV_RESULT_TEMPORARILY_REJECTED = 1
MAV_RESULT_DENIED = 2
MAV_RESULT_UNSUPPORTED = 3

_WARNING_EVENTS = frozenset(
    {
        EventKind.ABORT,
        EventKind.PILOT_TAKEOVER,
        EventKind.LINK_LOST,
        EventKind.REQUEST_FAILED,
        EventKind.WARNING,
        EventKind.DROP_ZONE,
    }
)
_NOTICE_EVENTS = frozenset(
    {
        EventKind.ARMED,
        EventKind.TOUCHDOWN,
        EventKind.RELEASED,
        EventKind.DELIVERED,
        EventKind.RETURNED,
        EventKind.LINK_RESTORED,
    }
)
_WARNING_PHASES = frozenset({Phase.ABORT_HOLD, Phase.ABORT_LAND, Phase.PILOT})


def event_severity(ev: MissionEvent) -> int:
    """MAV_SEVERITY of a mission event: failures and aborts WARNING or higher (the mission failing:
    CRITICAL), deliveries and touchdowns NOTICE, phase and sector changes INFO."""
    if ev.kind is EventKind.PHASE:
        if ev.phase is Phase.FAILED:
            return SEVERITY_CRITICAL
        return SEVERITY_WARNING if ev.phase in _WARNING_PHASES else SEVERITY_INFO
    if ev.kind is EventKind.WINCH_JAM:
        return SEVERITY_CRITICAL
    if ev.kind in _WARNING_EVENTS:
        return SEVERITY_WARNING
    return SEVERITY_NOTICE if ev.kind in _NOTICE_EVENTS else SEVERITY_INFO


def event_text(ev: MissionEvent) -> str:
    """One line for the GCS's message list: ``phase outbound``, ``abort: <reason>``, ..."""
    if ev.kind is EventKind.PHASE:
        return f"phase {ev.phase.value}" + (f": {ev.detail}" if ev.detail and ev.detail != ev.phase.value else "")
    return ev.kind.value + (f": {ev.detail}" if ev.detail else "")


class GcsOnly(enum.Enum):
    """A COMMAND_LONG we understand that is no mission command: answered here, never the mission's."""

    CONTINUE = "continue"  # DO_PAUSE_CONTINUE, param1 = 1: resume after a pause (DENIED)


def mission_kind(cmd: ComponentCommand) -> CommandKind | GcsOnly | None:
    """The mission command (hold, return, land) a COMMAND_LONG asks for; None: not one of ours."""
    if cmd.command == MAV_CMD_NAV_LOITER_UNLIM:
        return CommandKind.HOLD
    if cmd.command == MAV_CMD_DO_PAUSE_CONTINUE:
        return CommandKind.HOLD if cmd.params[0] == 0 else GcsOnly.CONTINUE
    if cmd.command == MAV_CMD_NAV_RETURN_TO_LAUNCH:
        return CommandKind.RETURN
    if cmd.command == MAV_CMD_NAV_LAND:
        return CommandKind.LAND
    return None


ACK_RESULTS = {
    CommandOutcome.ACCEPTED: MAV_RESULT_ACCEPTED,
    CommandOutcome.ENDED: MAV_RESULT_DENIED,
    CommandOutcome.NOT_NOW: MAV_RESULT_TEMPORARILY_REJECTED,
}


def ack_result(reply: CommandReply) -> int:
    """MAV_RESULT of the mission's reply to a command, by its outcome."""
    return ACK_RESULTS[reply.outcome]


class GcsComponent:
    """The companion's MAVLink component, driven by the delivery shell: :meth:`open` once the
    autopilot is connected, :meth:`on_events` with every tick's mission events, :meth:`close` at
    the end. ``command(kind, sender)`` runs a mission command and returns the mission's reply."""

    def __init__(
        self, cfg: GcsConfig, autopilot: Autopilot, command: Callable[[CommandKind, str], CommandReply]
    ) -> None:
        self.cfg = cfg
        self.autopilot = autopilot
        self.command = command
        self.ids: tuple[int, int] | None = None  # (system, component) once open
        self.texts_sent = 0
        self.commands: list[tuple[int, int, str]] = []  # (MAV_CMD, MAV_RESULT, reply)
        self.refused = 0  # commands dropped: from a system not allowed, or unsigned on a signed link
        self.refused_by_system: dict[int, int] = {}
        self._text_id = 0
        self._status_task: asyncio.Task[None] | None = None
        self._host = HostStatusReader()

    def open(self) -> bool:
        """Start speaking as our component; False (said once in the log) where the backend cannot."""
        if not self.cfg.enabled:
            return False
        try:
            self.ids = self.autopilot.open_component(self.cfg.component_id, self.cfg.system_id, self._on_command)
        except AutopilotError as err:
            log.info("no GCS component: %s", err)
            return False
        self._status_task = asyncio.get_running_loop().create_task(self._status_loop(), name="gcs-status")
        self.send_text(f"companion component {self.ids[1]} up", SEVERITY_INFO)
        return True

    async def close(self) -> None:
        task, self._status_task = self._status_task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task
        if self.ids is not None:
            self.autopilot.close_component()
            self.ids = None

    def on_events(self, events: Iterable[MissionEvent]) -> None:
        if self.ids is None:
            return
        for ev in events:
            self.send_text(event_text(ev), event_severity(ev))

    def send_text(self, text: str, severity: int) -> None:
        """One STATUSTEXT; a text longer than 50 characters in chunks with a common id."""
        chunks = statustext_chunks(text)
        text_id = 0
        if len(chunks) > 1:
            self._text_id = self._text_id % 65535 + 1
            text_id = self._text_id
        for seq, chunk in enumerate(chunks):
            fields = {"severity": severity, "text": chunk, "id": text_id, "chunk_seq": seq}
            if self.autopilot.send_from_component("STATUSTEXT", fields):
                self.texts_sent += 1

    def _refuse(self, cmd: ComponentCommand) -> bool:
        """A command from a system not in ``command_system_ids``, or unsigned on a signed link: dropped
        unanswered (an answer would only help whoever forged it), counted, logged sampled."""
        why = ""
        if cmd.source_system not in self.cfg.command_system_ids:
            why = f"system {cmd.source_system} is not in gcs.command_system_ids {list(self.cfg.command_system_ids)}"
        elif cmd.signed is False:
            why = f"system {cmd.source_system} sent it unsigned on a signed link"
        if not why:
            return False
        self.refused += 1
        n = self.refused_by_system[cmd.source_system] = self.refused_by_system.get(cmd.source_system, 0) + 1
        if n in (1, 10, 100) or n % 1000 == 0:
            log.warning(
                "COMMAND_LONG %d from %d/%d refused (%d from it so far): %s",
                cmd.command,
                cmd.source_system,
                cmd.source_component,
                n,
                why,
            )
        return True

    def _on_command(self, cmd: ComponentCommand) -> None:
        """A COMMAND_LONG addressed to us (on the loop): to the mission, then the COMMAND_ACK."""
        if self._refuse(cmd):
            return
        kind = mission_kind(cmd)
        if kind is None:
            result, reply = MAV_RESULT_UNSUPPORTED, f"command {cmd.command} not supported (hold, return, land)"
        elif kind is GcsOnly.CONTINUE:
            result, reply = MAV_RESULT_DENIED, "continue not supported: a hold lasts until land or the pilot"
        elif not self.cfg.accept_commands:
            result, reply = MAV_RESULT_DENIED, "commands from the GCS are off (gcs.accept_commands = false)"
        else:
            reply = self.command(kind, "gcs")
            result = ack_result(reply)
        self.commands.append((cmd.command, result, reply))
        log.warning("GCS command %d from %d/%d: %s", cmd.command, cmd.source_system, cmd.source_component, reply)
        self.autopilot.send_from_component(
            "COMMAND_ACK",
            {
                "command": cmd.command,
                "result": result,
                "progress": 0,
                "result_param2": 0,
                "target_system": cmd.source_system,
                "target_component": cmd.source_component,
            },
        )
        self.send_text(reply, SEVERITY_NOTICE if result == MAV_RESULT_ACCEPTED else SEVERITY_WARNING)

    async def _status_loop(self) -> None:
        period = 1.0 / self.cfg.status_rate_hz
        while True:
            fields = onboard_computer_status(self._host.read(), int(time.time() * 1e6))
            self.autopilot.send_from_component("ONBOARD_COMPUTER_STATUS", fields)
            await asyncio.sleep(period)

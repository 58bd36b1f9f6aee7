"""The companion in MAVProxy (docs/gcs.md): ``module load companion_plugins.mavproxy_companion``.

MAVProxy prints a STATUSTEXT only from the vehicle it targets: ``LinkModule.master_msg_handling``
(``MAVProxy/modules/mavproxy_link.py``) returns early for any message that
``MPModule.message_is_from_primary_vehicle`` (``modules/lib/mp_module.py``) says is not from
(``target_system``, ``target_component``), before its STATUSTEXT branch prints ``AP: ...``. The
companion speaks as its own component (1/191), so its texts reach MAVProxy and are not printed;
retargeting MAVProxy to 191 prints them as ``AP:`` and hides the autopilot's. Modules marked
``multi_vehicle`` get every packet (``LinkModule.master_callback``), so this one prints the
companion's texts beside the autopilot's, without retargeting:

    companion: phase outbound
    companion: return ACCEPTED
    companion: ground command from gcs: return: ...

and sends its commands to (the vehicle, 191), MAVProxy's own target left on the autopilot:

    companion              its ids, last heartbeat, commands sent
    companion hold         MAV_CMD_NAV_LOITER_UNLIM
    companion return       MAV_CMD_NAV_RETURN_TO_LAUNCH
    companion land         MAV_CMD_NAV_LAND
    companion component N  the companion's component id (default 191)

MAVProxy loads a module from ``MAVProxy.modules.mavproxy_NAME`` or, failing that, imports NAME
itself (``MPState.load_module`` in ``MAVProxy/mavproxy.py``), so the dotted name of this installed
module loads it. It imports MAVProxy and pymavlink only: nothing of the companion.
"""

from __future__ import annotations

import time
from typing import Any

from MAVProxy.modules.lib import mp_module
from pymavlink import mavutil

COMPANION_COMPONENT = 191  # MAV_COMP_ID_ONBOARD_COMPUTER, [gcs] component_id
LOST_AFTER_S = 5.0  # the component heartbeats at 1 Hz

COMMANDS = {
    "hold": mavutil.mavlink.MAV_CMD_NAV_LOITER_UNLIM,
    "return": mavutil.mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH,
    "land": mavutil.mavlink.MAV_CMD_NAV_LAND,
}
COMMAND_NAMES = {v: k for k, v in COMMANDS.items()}

RESULTS = {
    0: "ACCEPTED",
    1: "TEMPORARILY_REJECTED",
    2: "DENIED",
    3: "UNSUPPORTED",
    4: "FAILED",
    5: "IN_PROGRESS",
    6: "CANCELLED",
}

SEVERITY_COLOURS = {0: "red", 1: "red", 2: "red", 3: "red", 4: "orange", 5: "blue", 6: "black", 7: "black"}


def _text(raw: Any) -> str:
    if isinstance(raw, (bytes, bytearray)):
        raw = bytes(raw).split(b"\0", 1)[0].decode(errors="replace")
    return str(raw).split("\0", 1)[0]


class CompanionModule(mp_module.MPModule):  # type: ignore[misc]
    def __init__(self, mpstate: Any) -> None:
        super().__init__(mpstate, "companion", "the delivery companion's component", multi_vehicle=True)
        self.component = COMPANION_COMPONENT
        self.system: int | None = None  # the companion's system, from its first heartbeat
        self.last_heartbeat = 0.0
        self.online = False
        self.sent: list[tuple[str, float]] = []
        self._chunks: dict[int, dict[int, str]] = {}  # STATUSTEXT id -> chunk_seq -> text
        self.add_command(
            "companion", self.cmd_companion, "the delivery companion: hold, return, land", ["<hold|return|land>"]
        )

    def _ours(self, m: Any) -> bool:
        if m.get_srcComponent() != self.component:
            return False
        target = self.target_system
        return target == 0 or m.get_srcSystem() == target

    def _say(self, text: str, severity: int = 6) -> None:
        self.console.writeln(f"companion: {text}", fg=SEVERITY_COLOURS.get(severity, "black"))

    def mavlink_packet(self, m: Any) -> None:
        if not self._ours(m):
            return
        mtype = m.get_type()
        if mtype == "HEARTBEAT":
            self.system = m.get_srcSystem()
            self.last_heartbeat = time.monotonic()
            if not self.online:
                self.online = True
                self._say(f"component {self.system}/{self.component} online")
        elif mtype == "STATUSTEXT":
            if self.target_component == self.component:
                return  # MAVProxy targets the companion itself: its link module prints it as "AP: ..."
            self._statustext(m)
        elif mtype == "COMMAND_ACK":
            if m.target_system != self.settings.source_system:
                return
            name = COMMAND_NAMES.get(m.command, f"command {m.command}")
            self._say(f"{name} {RESULTS.get(m.result, m.result)}", 5 if m.result == 0 else 4)

    def _statustext(self, m: Any) -> None:
        """One STATUSTEXT; a text longer than 50 characters comes in chunks sharing a nonzero id."""
        text = _text(m.text)
        text_id = getattr(m, "id", 0) if hasattr(m, "chunk_seq") else 0
        if text_id == 0:
            self._say(text, m.severity)
            return
        chunks = self._chunks.setdefault(text_id, {})
        chunks[m.chunk_seq] = text
        if len(text) < 50:  # the last chunk
            self._say("".join(chunks[k] for k in sorted(chunks)), m.severity)
            del self._chunks[text_id]

    def idle_task(self) -> None:
        if self.online and time.monotonic() - self.last_heartbeat > LOST_AFTER_S:
            self.online = False
            self._say(f"component {self.system}/{self.component} lost (no heartbeat for {LOST_AFTER_S:.0f} s)", 4)

    def cmd_companion(self, args: list[str]) -> None:
        if not args:
            age = f"{time.monotonic() - self.last_heartbeat:.1f} s ago" if self.last_heartbeat else "never"
            print(
                f"companion: component {self.system or '?'}/{self.component}, "
                f"{'online' if self.online else 'offline'}, last heartbeat {age}; sent {[n for n, _ in self.sent]}"
            )
            return
        if args[0] == "component" and len(args) == 2 and args[1].isdigit():
            self.component = int(args[1])
            self.online, self.system = False, None
            print(f"companion: component id {self.component}")
            return
        command = COMMANDS.get(args[0])
        if command is None:
            print("usage: companion [hold|return|land|component N]")
            return
        system = self.system or self.target_system
        if not system:
            print("companion: no vehicle yet (no heartbeat from the companion or the autopilot)")
            return
        self.master.mav.command_long_send(system, self.component, command, 0, 0, 0, 0, 0, 0, 0, 0)
        self.sent.append((args[0], time.monotonic()))
        self._say(f"{args[0]} sent to {system}/{self.component}")


def init(mpstate: Any) -> CompanionModule:
    """MAVProxy's entry point (``module load companion_plugins.mavproxy_companion``)."""
    return CompanionModule(mpstate)

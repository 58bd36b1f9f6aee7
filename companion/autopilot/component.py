"""The companion as a MAVLink component of its own, next to the autopilot (``docs/gcs.md``).

The operator's GCS sees every component that heartbeats on the vehicle's system id. A backend
that can speak for the companion (``Autopilot.open_component``) sends the companion's HEARTBEAT
(MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID) with the vehicle's system id and the
component id asked for, sends messages from that component (STATUSTEXT, ONBOARD_COMPUTER_STATUS,
COMMAND_ACK) and hands over every COMMAND_LONG addressed to it as a :class:`ComponentCommand`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

MAV_COMP_ID_ONBOARD_COMPUTER = 191
MAV_TYPE_ONBOARD_CONTROLLER = 18
MAV_AUTOPILOT_INVALID = 8
MAV_STATE_ACTIVE = 4

# MAV_SEVERITY
SEVERITY_CRITICAL = 2
SEVERITY_ERROR = 3
SEVERITY_WARNING = 4
SEVERITY_NOTICE = 5
SEVERITY_INFO = 6

STATUSTEXT_LEN = 50  # characters of one STATUSTEXT; longer texts go in chunks (id, chunk_seq)


@dataclass(frozen=True, slots=True)
class ComponentCommand:
    """A COMMAND_LONG addressed to the companion's component; ``time_s`` its receipt on the
    shell's monotonic clock, ``params`` param1..param7. ``signed``: on a link that signs, whether
    this packet carried a signature our key verified; None where the link does not sign."""

    time_s: float
    source_system: int
    source_component: int
    command: int
    confirmation: int
    params: tuple[float, float, float, float, float, float, float]
    signed: bool | None = None

    def validate(self) -> ComponentCommand:
        if len(self.params) != 7:
            raise ValueError(f"ComponentCommand.params: expected 7 values, got {len(self.params)}")
        if not 0 <= self.command <= 65535:
            raise ValueError(f"ComponentCommand.command {self.command} is not a MAV_CMD (0..65535)")
        if not math.isfinite(self.time_s):
            raise ValueError(f"ComponentCommand.time_s is not finite ({self.time_s})")
        return self


def statustext_chunks(text: str) -> list[str]:
    """``text`` cut into STATUSTEXT-sized pieces (at most 50 characters each, ASCII)."""
    t = text.encode("ascii", "replace").decode("ascii") or " "
    return [t[i : i + STATUSTEXT_LEN] for i in range(0, len(t), STATUSTEXT_LEN)]

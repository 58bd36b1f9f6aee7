"""The autopilot's winch: MAV_CMD_DO_WINCH (42600) and what WINCH_STATUS (9005) reports.

ArduCopter (AP_Winch, WINCH_TYPE 1 = PWM on the output with SERVOn_FUNCTION = 88): DO_WINCH answers
FAILED without a winch; action 1 (relative length) pays out param 3 metres more than the current
line (negative: reels in) under its length control (WINCH_POS_P, at most WINCH_RATE_MAX; param 4 is
not used), action 2 runs at param 4 m/s, action 0 lets the drum spin freely. The PWM backend has
no encoder: the line length in WINCH_STATUS is its own integral of the commanded rate.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass

MAV_CMD_DO_WINCH = 42600
MAV_WINCH_STATUS_HEALTHY = 1
MAV_WINCH_STATUS_FULLY_RETRACTED = 2
MAV_WINCH_STATUS_MOVING = 4


class WinchAction(enum.IntEnum):
    """DO_WINCH param 2 (MAVLink WINCH_ACTIONS, the three ArduCopter implements)."""

    RELAXED = 0
    RELATIVE_LENGTH_CONTROL = 1
    RATE_CONTROL = 2


@dataclass(frozen=True, slots=True)
class WinchCommand:
    """One DO_WINCH: ``instance`` (param 1), ``action`` (param 2), ``length_m`` (param 3: line to
    pay out, negative to reel in), ``rate_m_s`` (param 4)."""

    instance: int
    action: WinchAction
    length_m: float = 0.0
    rate_m_s: float = 0.0

    def validate(self) -> WinchCommand:
        if not (math.isfinite(self.length_m) and math.isfinite(self.rate_m_s)):
            raise ValueError(f"winch command with a non-finite length or rate: {self}")
        if not 1 <= self.instance <= 8:
            raise ValueError(f"winch instance {self.instance}: expected 1-8")
        return self


@dataclass(frozen=True, slots=True)
class WinchStatus:
    """The winch's report (MAVLink WINCH_STATUS): line paid out (m), its speed (m/s, + paying out),
    the MAV_WINCH_STATUS_FLAG bits and the line's tension (kg; NaN: not reported, as AP_Winch_PWM
    sends it: a winch without a load cell); ``time_s`` on the shell's clock at receipt."""

    time_s: float
    line_length_m: float
    speed_m_s: float
    flags: int = MAV_WINCH_STATUS_HEALTHY
    tension_kg: float = math.nan

    @property
    def healthy(self) -> bool:
        return bool(self.flags & MAV_WINCH_STATUS_HEALTHY)

    def validate(self) -> WinchStatus:
        if not (math.isfinite(self.time_s) and math.isfinite(self.line_length_m)):
            raise ValueError(f"WinchStatus with a non-finite time or line length: {self}")
        return self

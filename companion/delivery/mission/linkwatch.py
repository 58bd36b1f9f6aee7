"""The autopilot link as the mission sees it: lost (stop commanding, the autopilot's failsafe
acts), restored, and whether the mode found after the loss is the autopilot's failsafe (re-enter
offboard and resume from where the vehicle is: the field is path-, not time-based) or not."""

from __future__ import annotations

import enum
import math
from collections.abc import Callable

from companion.autopilot.types import FlightMode
from companion.delivery.mission.types import MissionInputs
from companion.events import EventKind


class LinkCheck(enum.Enum):
    LOST = "lost"  # no commanding this tick
    OK = "ok"
    REENTER = "reenter"  # back after a loss, in the autopilot's failsafe mode: OFFBOARD again


class LinkWatch:
    def __init__(self, resume_modes: list[str] | tuple[str, ...]):
        self.resume_modes = resume_modes
        self.lost = False
        self.lost_mode: FlightMode | None = None
        self.restored_at_s = -math.inf
        self.undecided = False  # the link is back, no status from after the loss yet
        self._status_t_at_loss = -math.inf  # the time of the last status before the link was lost

    def check(self, inp: MissionInputs, following: bool, emit: Callable[[EventKind, str], None]) -> LinkCheck:
        st = inp.status
        if not inp.link_ok:
            if not self.lost:
                self.lost = True
                self.lost_mode = st.mode if st is not None else None
                self._status_t_at_loss = st.time_s if st is not None else -math.inf
                emit(EventKind.LINK_LOST, "no heartbeat: stopped commanding, autopilot failsafe acts")
            return LinkCheck.LOST
        if self.lost:
            self.lost = False
            self.restored_at_s = inp.time_s
            self.undecided = True
            emit(EventKind.LINK_RESTORED, "resuming from where the vehicle is")
        if self.undecided:
            # The autopilot's offboard-loss failsafe will have switched to its failsafe mode (HOLD;
            # POSCTL on PX4 v1.16 with COM_OBL_RC_ACT = 0): that is not the pilot, so
            # re-enter offboard and let the (path-based) field resume. Decided on a status the
            # autopilot sent after the link came back: the link can return (a heartbeat) before
            # the mode does, and the last status from before the loss still says OFFBOARD.
            if st is None or st.time_s <= self._status_t_at_loss:
                return LinkCheck.OK
            self.undecided = False
            if following and st.mode is not FlightMode.OFFBOARD and st.mode.value in self.resume_modes:
                return LinkCheck.REENTER
        return LinkCheck.OK

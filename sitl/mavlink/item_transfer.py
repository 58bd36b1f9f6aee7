"""One mission type's side of the MAVLink mission protocol on the sim vehicle, as the firmware
answers a GCS (PX4 mavlink_mission.cpp, ArduPilot MissionItemProtocol): MISSION_COUNT ->
MISSION_REQUEST_INT for each item -> MISSION_ACK once the last has come (the stored items are
replaced only then); MISSION_REQUEST_LIST -> MISSION_COUNT, MISSION_REQUEST(_INT) ->
MISSION_ITEM_INT; MISSION_CLEAR_ALL. What a type stores and refuses is its owner's
(sitl/mavlink/fence.py, sitl/mavlink/mission.py)."""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, Generic, TypeVar

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

T = TypeVar("T")

# the frames of a position on the globe (the fence's vertices, a mission's positions)
GLOBAL_FRAMES = (
    mavlink.MAV_FRAME_GLOBAL,
    mavlink.MAV_FRAME_GLOBAL_INT,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
)

# an item as MISSION_ITEM_INT carries it: frame, command, autocontinue, param1-4, x, y, z
WireItem = tuple[int, int, int, float, float, float, float, int, int, float]


@dataclass
class ItemTransfer(Generic[T]):
    mission_type: int
    send: Callable[[Any], None]  # the vehicle's encoded-message sender
    enc: Any  # the vehicle's MAVLink encoder
    item_of: Callable[[Any], T]  # a received MISSION_ITEM_INT as the owner stores it
    problem: Callable[[Any], int | None]  # the MAV_MISSION_RESULT refusing an item, None to take it
    commit: Callable[[list[T]], int]  # store a complete upload; its MAV_MISSION_RESULT
    served: Callable[[], Sequence[T]]  # what a download gets
    wire: Callable[[T], WireItem]
    clear: Callable[[], None]
    incoming: list[T | None] | None = None  # an upload in progress
    downloads: int = 0

    def handle(self, m: Any) -> bool:
        """Answer ``m`` when it is a mission-protocol message of this mission type; False if not."""
        if getattr(m, "mission_type", 0) != self.mission_type:
            return False
        t = m.get_type()
        src = m.get_srcSystem(), m.get_srcComponent()
        if t == "MISSION_COUNT":
            self.incoming = [None] * m.count
            if m.count == 0:
                self._commit(src)
            else:
                self.send(self.enc.mission_request_int_encode(*src, 0, self.mission_type))
        elif t == "MISSION_ITEM_INT":
            items = self.incoming
            if items is None or not 0 <= m.seq < len(items):
                self.ack(src, mavlink.MAV_MISSION_OPERATION_CANCELLED)
                return True
            result = self.problem(m)
            if result is not None:
                self.incoming = None
                self.ack(src, result)
                return True
            items[m.seq] = self.item_of(m)
            missing = [i for i, it in enumerate(items) if it is None]
            if missing:
                self.send(self.enc.mission_request_int_encode(*src, missing[0], self.mission_type))
            else:
                self._commit(src)
        elif t == "MISSION_REQUEST_LIST":
            self.downloads += 1
            self.send(self.enc.mission_count_encode(*src, len(self.served()), self.mission_type))
        elif t in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            served = self.served()
            if not 0 <= m.seq < len(served):
                self.ack(src, mavlink.MAV_MISSION_INVALID_SEQUENCE)
                return True
            frame, command, autocontinue, p1, p2, p3, p4, x, y, z = self.wire(served[m.seq])
            self.send(
                self.enc.mission_item_int_encode(
                    *src, m.seq, frame, command, 0, autocontinue, p1, p2, p3, p4, x, y, z, self.mission_type
                )
            )
        elif t == "MISSION_CLEAR_ALL":
            self.clear()
            self.ack(src, mavlink.MAV_MISSION_ACCEPTED)
        elif t != "MISSION_ACK":  # MISSION_ACK ends a download; nothing to answer
            return False
        return True

    def _commit(self, src: tuple[int, int]) -> None:
        items = [it for it in self.incoming or [] if it is not None]
        self.incoming = None
        self.ack(src, self.commit(items))

    def ack(self, src: tuple[int, int], result: int) -> None:
        self.send(self.enc.mission_ack_encode(*src, result, self.mission_type))

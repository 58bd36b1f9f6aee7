"""The sim vehicle's fence storage and its side of the MAVLink mission protocol for
mission_type = MAV_MISSION_TYPE_FENCE, answered as PX4 (mavlink_mission.cpp) and ArduPilot
(MissionItemProtocol_Fence) answer it: MISSION_COUNT -> MISSION_REQUEST_INT for each item ->
MISSION_ACK once the last has come (the stored fence is replaced only then); MISSION_REQUEST_LIST
-> MISSION_COUNT, MISSION_REQUEST(_INT) -> MISSION_ITEM_INT. Polygon vertices only (5001/5002);
another command is answered MAV_MISSION_UNSUPPORTED, a frame that is not global
MAV_MISSION_UNSUPPORTED_FRAME. A polygon of fewer than 3 vertices: PX4 refuses the item
(MAV_MISSION_INVALID_PARAM1, mavlink_mission.cpp), ArduPilot takes every item and fails the upload
at the end (MAV_MISSION_ERROR: AC_PolyFence_loader::write_fence validates the polygons)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

FENCE = mavlink.MAV_MISSION_TYPE_FENCE
GLOBAL_FRAMES = (
    mavlink.MAV_FRAME_GLOBAL,
    mavlink.MAV_FRAME_GLOBAL_INT,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT,
    mavlink.MAV_FRAME_GLOBAL_RELATIVE_ALT_INT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT,
    mavlink.MAV_FRAME_GLOBAL_TERRAIN_ALT_INT,
)
VERTEX_COMMANDS = (
    mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_INCLUSION,
    mavlink.MAV_CMD_NAV_FENCE_POLYGON_VERTEX_EXCLUSION,
)


@dataclass(frozen=True, slots=True)
class StoredFenceItem:
    command: int
    frame: int
    param1: float
    param2: float
    lat_e7: int
    lon_e7: int


class FenceServer:
    """Mixin of :class:`~companion_sitl.mavlink.vehicle.MavlinkSimVehicle`."""

    _enc: Any
    system_id: int
    component_id: int

    _send: Any  # the vehicle's (link.py)

    fence: tuple[StoredFenceItem, ...] = ()  # what the vehicle holds
    _fence_in: list[StoredFenceItem | None] | None = None  # an upload in progress
    fence_uploads = 0
    FENCE_VERTEX_COUNT_PER_ITEM = True  # PX4; ArduPilot checks the polygons once all items are in

    def _fence_message(self, m: Any) -> bool:
        """Handle a fence-protocol message; False when it is not one (another mission type)."""
        t = m.get_type()
        if getattr(m, "mission_type", 0) != FENCE:
            return False
        src_s, src_c = m.get_srcSystem(), m.get_srcComponent()
        if t == "MISSION_COUNT":
            self._fence_in = [None] * m.count
            if m.count == 0:
                self._fence_commit(src_s, src_c)
            else:
                self._send(self._enc.mission_request_int_encode(src_s, src_c, 0, FENCE))
            return True
        if t == "MISSION_ITEM_INT":
            items = self._fence_in
            if items is None or not 0 <= m.seq < len(items):
                self._fence_ack(src_s, src_c, mavlink.MAV_MISSION_OPERATION_CANCELLED)
                return True
            if m.frame not in GLOBAL_FRAMES:
                self._fence_in = None
                self._fence_ack(src_s, src_c, mavlink.MAV_MISSION_UNSUPPORTED_FRAME)
                return True
            if m.command not in VERTEX_COMMANDS:
                self._fence_in = None
                self._fence_ack(src_s, src_c, mavlink.MAV_MISSION_UNSUPPORTED)
                return True
            if self.FENCE_VERTEX_COUNT_PER_ITEM and m.param1 < 3:
                self._fence_in = None
                self._fence_ack(src_s, src_c, mavlink.MAV_MISSION_INVALID_PARAM1)
                return True
            if not -900_000_000 <= m.x <= 900_000_000:
                self._fence_in = None
                self._fence_ack(src_s, src_c, mavlink.MAV_MISSION_INVALID_PARAM5_X)
                return True
            if not -1_800_000_000 <= m.y <= 1_800_000_000:
                self._fence_in = None
                self._fence_ack(src_s, src_c, mavlink.MAV_MISSION_INVALID_PARAM6_Y)
                return True
            items[m.seq] = StoredFenceItem(m.command, m.frame, m.param1, m.param2, m.x, m.y)
            missing = [i for i, it in enumerate(items) if it is None]
            if missing:
                self._send(self._enc.mission_request_int_encode(src_s, src_c, missing[0], FENCE))
            else:
                self._fence_commit(src_s, src_c)
            return True
        if t == "MISSION_REQUEST_LIST":
            self._send(self._enc.mission_count_encode(src_s, src_c, len(self.fence), FENCE))
            return True
        if t in ("MISSION_REQUEST_INT", "MISSION_REQUEST"):
            if not 0 <= m.seq < len(self.fence):
                self._fence_ack(src_s, src_c, mavlink.MAV_MISSION_INVALID_SEQUENCE)
                return True
            it = self.fence[m.seq]
            self._send(
                self._enc.mission_item_int_encode(
                    src_s, src_c, m.seq, it.frame, it.command, 0, 1,
                    it.param1, it.param2, 0.0, 0.0, it.lat_e7, it.lon_e7, 0.0, FENCE,
                )
            )  # fmt: skip
            return True
        if t == "MISSION_ACK":
            return True  # the end of a download
        if t == "MISSION_CLEAR_ALL":
            self.fence = ()
            self._fence_ack(src_s, src_c, mavlink.MAV_MISSION_ACCEPTED)
            return True
        return False

    def _fence_commit(self, src_s: int, src_c: int) -> None:
        items = [it for it in self._fence_in or [] if it is not None]
        self._fence_in = None
        if not _polygons_valid(items):
            self._fence_ack(src_s, src_c, mavlink.MAV_MISSION_ERROR)  # the stored fence stays as it was
            return
        self.fence = tuple(items)
        self.fence_uploads += 1
        self._fence_ack(src_s, src_c, mavlink.MAV_MISSION_ACCEPTED)

    def _fence_ack(self, src_s: int, src_c: int, result: int) -> None:
        self._send(self._enc.mission_ack_encode(src_s, src_c, result, FENCE))


def _polygons_valid(items: list[StoredFenceItem]) -> bool:
    """Each polygon is at least 3 vertices, each carrying the polygon's vertex count (ArduPilot's
    write_fence validation)."""
    i = 0
    while i < len(items):
        n = int(items[i].param1)
        group = items[i : i + n]
        if n < 3 or len(group) < n or any(g.command != items[i].command or int(g.param1) != n for g in group):
            return False
        i += n
    return True

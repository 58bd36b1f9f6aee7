"""The sim vehicle's fence storage for mission_type = MAV_MISSION_TYPE_FENCE, answered as PX4
(mavlink_mission.cpp) and ArduPilot (MissionItemProtocol_Fence) answer it over the mission protocol
(sitl/mavlink/item_transfer.py). Polygon vertices only (5001/5002); another command is answered
MAV_MISSION_UNSUPPORTED, a frame that is not global MAV_MISSION_UNSUPPORTED_FRAME. A polygon of
fewer than 3 vertices: PX4 refuses the item (MAV_MISSION_INVALID_PARAM1, mavlink_mission.cpp),
ArduPilot takes every item and fails the upload at the end (MAV_MISSION_ERROR:
AC_PolyFence_loader::write_fence validates the polygons)."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion_sitl.mavlink.item_transfer import GLOBAL_FRAMES, ItemTransfer

FENCE = mavlink.MAV_MISSION_TYPE_FENCE
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
    fence_uploads = 0
    FENCE_VERTEX_COUNT_PER_ITEM = True  # PX4; ArduPilot checks the polygons once all items are in
    _fence_t: ItemTransfer[StoredFenceItem] | None = None

    def _fence_message(self, m: Any) -> bool:
        """Handle a fence-protocol message; False when it is not one (another mission type)."""
        if self._fence_t is None:
            self._fence_t = ItemTransfer(
                FENCE,
                self._send,
                self._enc,
                item_of=lambda m: StoredFenceItem(m.command, m.frame, m.param1, m.param2, m.x, m.y),
                problem=self._fence_item_problem,
                commit=self._fence_commit,
                served=lambda: self.fence,
                wire=lambda it: (it.frame, it.command, 1, it.param1, it.param2, 0.0, 0.0, it.lat_e7, it.lon_e7, 0.0),
                clear=self._fence_clear,
            )
        return self._fence_t.handle(m)

    def _fence_item_problem(self, m: Any) -> int | None:
        if m.frame not in GLOBAL_FRAMES:
            return int(mavlink.MAV_MISSION_UNSUPPORTED_FRAME)
        if m.command not in VERTEX_COMMANDS:
            return int(mavlink.MAV_MISSION_UNSUPPORTED)
        if self.FENCE_VERTEX_COUNT_PER_ITEM and m.param1 < 3:
            return int(mavlink.MAV_MISSION_INVALID_PARAM1)
        if not -900_000_000 <= m.x <= 900_000_000:
            return int(mavlink.MAV_MISSION_INVALID_PARAM5_X)
        if not -1_800_000_000 <= m.y <= 1_800_000_000:
            return int(mavlink.MAV_MISSION_INVALID_PARAM6_Y)
        return None

    def _fence_commit(self, items: list[StoredFenceItem]) -> int:
        if not _polygons_valid(items):
            return int(mavlink.MAV_MISSION_ERROR)  # the stored fence stays as it was
        self.fence = tuple(items)
        self.fence_uploads += 1
        return int(mavlink.MAV_MISSION_ACCEPTED)

    def _fence_clear(self) -> None:
        self.fence = ()


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

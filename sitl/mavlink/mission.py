"""The sim vehicle's mission storage (mission_type MAV_MISSION_TYPE_MISSION), answered over the
mission protocol as the firmware answers a GCS (sitl/mavlink/item_transfer.py).

An item in a frame neither global nor MAV_FRAME_MISSION is answered MAV_MISSION_UNSUPPORTED_FRAME
(PX4 mavlink_mission.cpp; ArduPilot's mission_cmd conversion), a global position out of range
MAV_MISSION_INVALID_PARAM5_X / _PARAM6_Y. PX4 also refuses the terrain frames and a command it does
not list for the item's frame (MAV_MISSION_UNSUPPORTED): no NAV_PAYLOAD_PLACE, and NAV_RETURN_TO_LAUNCH
or DO_GRIPPER only in MAV_FRAME_MISSION, as QGroundControl sends them.

ArduPilot (``_mission_home_item``): item 0 is its home. What a GCS uploads as item 0 is not kept;
a download answers item 0 with the current home (AP_Mission::read_cmd_from_storage), so the count
is the operator's items + 1, and 1 for an empty mission. PX4 keeps the items as sent, from seq 0."""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion_sitl.mavlink.item_transfer import GLOBAL_FRAMES, ItemTransfer

MISSION = mavlink.MAV_MISSION_TYPE_MISSION
ACCEPTED_FRAMES = (*GLOBAL_FRAMES, mavlink.MAV_FRAME_MISSION)


@dataclass(frozen=True, slots=True)
class StoredMissionItem:
    frame: int
    command: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float
    autocontinue: int = 1


class MissionServer:
    """Mixin of :class:`~companion_sitl.mavlink.vehicle.MavlinkSimVehicle`."""

    _enc: Any
    _send: Any

    mission_items: tuple[StoredMissionItem, ...] = ()  # what the vehicle holds (ArduPilot: without home)
    mission_uploads = 0
    _mission_t: ItemTransfer[StoredMissionItem] | None = None

    def _mission_home_item(self) -> StoredMissionItem | None:
        """The item 0 a download starts with, the vehicle's home (ArduPilot), or None: the mission
        holds only the operator's items (PX4)."""
        return None

    @property
    def mission_downloads(self) -> int:
        return 0 if self._mission_t is None else self._mission_t.downloads

    def _mission_message(self, m: Any) -> bool:
        """Handle a message of the mission protocol for mission_type 0; False when it is not one."""
        if self._mission_t is None:
            self._mission_t = ItemTransfer(
                MISSION,
                self._send,
                self._enc,
                item_of=lambda m: StoredMissionItem(
                    m.frame, m.command, m.param1, m.param2, m.param3, m.param4, m.x, m.y, m.z, m.autocontinue
                ),
                problem=self._item_problem,
                commit=self._mission_commit,
                served=self._served,
                wire=lambda it: (
                    it.frame, it.command, it.autocontinue, it.param1, it.param2, it.param3, it.param4, it.x, it.y, it.z
                ),
                clear=self._mission_clear,
            )  # fmt: skip
        return self._mission_t.handle(m)

    def _served(self) -> tuple[StoredMissionItem, ...]:
        home = self._mission_home_item()
        return self.mission_items if home is None else (home, *self.mission_items)

    # PX4 (mavlink_mission.cpp parse_mavlink_mission_item): the commands it takes in each frame;
    # None: any (ArduPilot takes what its mission storage can hold)
    MISSION_GLOBAL_FRAMES: tuple[int, ...] | None = None
    MISSION_GLOBAL_COMMANDS: frozenset[int] | None = None
    MISSION_FRAME_COMMANDS: frozenset[int] | None = None

    def _item_problem(self, m: Any) -> int | None:
        frames = ACCEPTED_FRAMES if self.MISSION_GLOBAL_FRAMES is None else (*self.MISSION_GLOBAL_FRAMES, 2)
        if m.frame not in frames:
            return int(mavlink.MAV_MISSION_UNSUPPORTED_FRAME)
        allowed = self.MISSION_FRAME_COMMANDS if m.frame == mavlink.MAV_FRAME_MISSION else self.MISSION_GLOBAL_COMMANDS
        if allowed is not None and m.command not in allowed:
            return int(mavlink.MAV_MISSION_UNSUPPORTED)
        if m.frame in GLOBAL_FRAMES:
            if not -900_000_000 <= m.x <= 900_000_000:
                return int(mavlink.MAV_MISSION_INVALID_PARAM5_X)
            if not -1_800_000_000 <= m.y <= 1_800_000_000:
                return int(mavlink.MAV_MISSION_INVALID_PARAM6_Y)
        return None

    def _mission_commit(self, items: list[StoredMissionItem]) -> int:
        self.mission_items = tuple(items[1:] if self._mission_home_item() is not None else items)
        self.mission_uploads += 1
        return int(mavlink.MAV_MISSION_ACCEPTED)

    def _mission_clear(self) -> None:
        self.mission_items = ()

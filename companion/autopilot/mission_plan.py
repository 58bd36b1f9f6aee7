"""The autopilot's mission (MAVLink mission protocol, mission_type MAV_MISSION_TYPE_MISSION) as the
companion reads it: one :class:`PlanItem` per MISSION_ITEM_INT, numbered as a ground station shows
it. Which item is the delivery is decided above (companion.delivery.autopilot_mission).

Numbering: ArduPilot keeps its home as item 0 and the operator's first item is 1; PX4 has no home
item and its first item is 0. ``index`` is the number QGroundControl and Mission Planner show
(ArduPilot's seq, PX4's seq + 1), so an error naming an item names the one the operator sees."""

from __future__ import annotations

from dataclasses import dataclass

MAV_MISSION_TYPE_MISSION = 0

MAV_CMD_NAV_WAYPOINT = 16
MAV_CMD_NAV_LAND = 21
MAV_CMD_NAV_TAKEOFF = 22
MAV_CMD_NAV_PAYLOAD_PLACE = 94
MAV_CMD_DO_GRIPPER = 211
GRIPPER_ACTION_RELEASE = 0

MAV_FRAME_GLOBAL = 0
MAV_FRAME_MISSION = 2
MAV_FRAME_GLOBAL_RELATIVE_ALT = 3
MAV_FRAME_GLOBAL_INT = 5
MAV_FRAME_GLOBAL_RELATIVE_ALT_INT = 6

COMMAND_NAMES = {
    16: "NAV_WAYPOINT",
    17: "NAV_LOITER_UNLIM",
    18: "NAV_LOITER_TURNS",
    19: "NAV_LOITER_TIME",
    20: "NAV_RETURN_TO_LAUNCH",
    21: "NAV_LAND",
    22: "NAV_TAKEOFF",
    31: "NAV_LOITER_TO_ALT",
    84: "NAV_VTOL_TAKEOFF",
    85: "NAV_VTOL_LAND",
    93: "NAV_DELAY",
    94: "NAV_PAYLOAD_PLACE",
    177: "DO_JUMP",
    178: "DO_CHANGE_SPEED",
    183: "DO_SET_SERVO",
    189: "DO_LAND_START",
    201: "DO_SET_ROI",
    211: "DO_GRIPPER",
    42600: "DO_WINCH",
}

FRAME_NAMES = {
    0: "MAV_FRAME_GLOBAL",
    1: "MAV_FRAME_LOCAL_NED",
    2: "MAV_FRAME_MISSION",
    3: "MAV_FRAME_GLOBAL_RELATIVE_ALT",
    4: "MAV_FRAME_LOCAL_ENU",
    5: "MAV_FRAME_GLOBAL_INT",
    6: "MAV_FRAME_GLOBAL_RELATIVE_ALT_INT",
    7: "MAV_FRAME_LOCAL_OFFSET_NED",
    8: "MAV_FRAME_BODY_NED",
    9: "MAV_FRAME_BODY_OFFSET_NED",
    10: "MAV_FRAME_GLOBAL_TERRAIN_ALT",
    11: "MAV_FRAME_GLOBAL_TERRAIN_ALT_INT",
    12: "MAV_FRAME_BODY_FRD",
}


def command_name(command: int) -> str:
    """``NAV_WAYPOINT (16)``; a command without a name here: its number."""
    name = COMMAND_NAMES.get(command)
    return f"{name} ({command})" if name else f"command {command}"


def frame_name(frame: int) -> str:
    return FRAME_NAMES.get(frame, f"frame {frame}")


@dataclass(frozen=True, slots=True)
class PlanItem:
    """One mission item as MISSION_ITEM_INT carries it: x/y latitude/longitude in 1e-7 degrees
    (global frames), z altitude in metres in the item's frame."""

    index: int  # the number a ground station shows (see the module's docstring)
    seq: int  # the MAVLink sequence number
    frame: int
    command: int
    param1: float
    param2: float
    param3: float
    param4: float
    x: int
    y: int
    z: float

    def describe(self) -> str:
        return f"item {self.index} {command_name(self.command)}"

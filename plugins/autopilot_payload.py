"""Payload driver that releases the parcel through the autopilot (MAVLink gripper or servo).

The backend decides how: PX4/MAVSDK's gripper plugin, ArduPilot's MAV_CMD_DO_GRIPPER or
MAV_CMD_DO_SET_SERVO (configured on the backend). The simulator's actuator works the same way.
"""

from __future__ import annotations

from typing import ClassVar

from companion.autopilot.interface import Autopilot


class AutopilotPayload:
    api_version: ClassVar[int] = 1

    def __init__(self, autopilot: Autopilot):
        self.autopilot = autopilot
        self.releases = 0

    def start(self) -> None:
        pass  # nothing to open: the autopilot link is owned by the shell

    async def release(self) -> None:
        await self.autopilot.release_payload()
        self.releases += 1

    def stop(self) -> None:
        pass

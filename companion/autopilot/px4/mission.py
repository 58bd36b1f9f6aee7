"""The operator's mission downloaded from PX4 through MAVSDK's mission_raw plugin
(download_mission), which speaks the MAVLink mission protocol with mission_type
MAV_MISSION_TYPE_MISSION and hands the items back as MISSION_ITEM_INT carries them. PX4 has no home
item: its seq 0 is the operator's first item, which a GCS shows as item 1."""

from __future__ import annotations

import asyncio
import logging
from typing import Any

from companion.autopilot.interface import AutopilotError
from companion.autopilot.mission_plan import PlanItem

log = logging.getLogger(__name__)

TRANSFER_TIMEOUT_S = 30.0


class Px4Mission:
    """Mixin of the PX4 backend (uses its MAVSDK ``_system``)."""

    _system: Any
    _mission_raw: Any = None
    _mission_raw_system: Any = None  # the system it was built on (a reconnect makes a new one)

    async def download_mission(self) -> tuple[PlanItem, ...]:
        if self._system is None:
            raise AutopilotError("mission download: not connected")
        if self._mission_raw is None or self._mission_raw_system is not self._system:
            from mavsdk.asyncio.plugins.mission_raw import MissionRawAsync

            self._mission_raw = MissionRawAsync(self._system)
            self._mission_raw_system = self._system
        try:
            got = await asyncio.wait_for(self._mission_raw.download_mission(), TRANSFER_TIMEOUT_S)
        except TimeoutError:
            raise AutopilotError(f"mission download: no end within {TRANSFER_TIMEOUT_S:g} s") from None
        except Exception as err:  # MAVSDK's MissionRawError
            raise AutopilotError(f"mission download failed: {err}") from None
        items = tuple(
            PlanItem(
                it.seq + 1, it.seq, it.frame, it.command, it.param1, it.param2, it.param3, it.param4,
                it.x, it.y, it.z,
            )
            for it in got
        )  # fmt: skip
        log.info("mission downloaded: %d items", len(items))
        return items

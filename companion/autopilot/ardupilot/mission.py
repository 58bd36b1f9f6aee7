"""The operator's mission downloaded from ArduPilot with the MAVLink mission protocol, as a GCS
does (mission_type MAV_MISSION_TYPE_MISSION): MISSION_REQUEST_LIST -> MISSION_COUNT,
MISSION_REQUEST_INT -> MISSION_ITEM_INT for each item, closed by our MISSION_ACK. The same
exchange as the fence read-back (ardupilot.fence), on the other mission type.

ArduPilot's item 0 is its home (AP_Mission::read_cmd_from_storage answers item 0 with the current
home), so a mission of n items counts n + 1 and the operator's items are 1..n."""

from __future__ import annotations

import asyncio
import logging
import time
from typing import Any

from companion.autopilot.ardupilot.dialect import mavlink
from companion.autopilot.ardupilot.fence import STEP_TIMEOUT_S, STEP_TRIES
from companion.autopilot.interface import AutopilotError
from companion.autopilot.mission_plan import MAV_MISSION_TYPE_MISSION, PlanItem

log = logging.getLogger(__name__)


class ArduPilotMission:
    """Mixin of the ArduPilot backend, before :class:`ArduPilotFence` (it routes the mission
    messages of mission_type 0 to its own transfer, the rest to the fence's)."""

    _plan_rx: asyncio.Queue[Any] | None = None
    _send: Any
    _loop: Any
    target_system: int | None
    target_component: int

    def _on_mission_message(self, m: Any) -> None:
        if self._plan_rx is not None and getattr(m, "mission_type", 0) == MAV_MISSION_TYPE_MISSION:
            self._plan_rx.put_nowait(m)
            return
        super()._on_mission_message(m)  # type: ignore[misc]

    async def _plan_next(self, types: set[str], deadline: float, pred: Any = None) -> Any:
        assert self._plan_rx is not None
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            try:
                m = await asyncio.wait_for(self._plan_rx.get(), left)
            except TimeoutError:
                return None
            if m.get_type() in types and (pred is None or pred(m)):
                return m

    async def download_mission(self) -> tuple[PlanItem, ...]:
        if self._loop is None:
            raise AutopilotError("mission download: not connected")
        ts, tc = self.target_system or 1, self.target_component
        kind = MAV_MISSION_TYPE_MISSION
        self._plan_rx = asyncio.Queue()
        try:
            count_msg = None
            for _ in range(STEP_TRIES):
                self._send(lambda mav: mav.mission_request_list_send(ts, tc, kind))
                count_msg = await self._plan_next({"MISSION_COUNT"}, time.monotonic() + STEP_TIMEOUT_S)
                if count_msg is not None:
                    break
            if count_msg is None:
                raise AutopilotError("mission download: the vehicle never sent its mission item count")
            items: list[PlanItem] = []
            for seq in range(count_msg.count):
                got = None
                for _ in range(STEP_TRIES):
                    self._send(lambda mav, seq=seq: mav.mission_request_int_send(ts, tc, seq, kind))
                    got = await self._plan_next(
                        {"MISSION_ITEM_INT"}, time.monotonic() + STEP_TIMEOUT_S, lambda m, seq=seq: m.seq == seq
                    )
                    if got is not None:
                        break
                if got is None:
                    raise AutopilotError(f"mission download: no item {seq} of {count_msg.count}")
                if seq == 0:
                    continue  # ArduPilot's home
                items.append(
                    PlanItem(
                        seq, seq, got.frame, got.command, got.param1, got.param2, got.param3, got.param4,
                        got.x, got.y, got.z,
                    )
                )  # fmt: skip
            self._send(lambda mav: mav.mission_ack_send(ts, tc, mavlink.MAV_MISSION_ACCEPTED, kind))
        finally:
            self._plan_rx = None
        log.info("mission downloaded: %d items", len(items))
        return tuple(items)

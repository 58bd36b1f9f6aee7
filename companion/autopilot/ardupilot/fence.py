"""The MAVLink mission protocol for the fence (mission_type = MAV_MISSION_TYPE_FENCE), as a GCS
speaks it to ArduPilot: upload (MISSION_COUNT, then a MISSION_ITEM_INT for each MISSION_REQUEST
(_INT), closed by the vehicle's MISSION_ACK) and download (MISSION_REQUEST_LIST -> MISSION_COUNT,
MISSION_REQUEST_INT -> MISSION_ITEM_INT for each item, closed by our MISSION_ACK).

ArduPilot keeps the polygons in its fence storage (AC_PolyFence_loader); FENCE_ENABLE / FENCE_TYPE
decide whether it acts on them (checked by ``companion preflight``)."""

from __future__ import annotations

import asyncio
import logging
import math
import time
from typing import Any

from companion.autopilot.ardupilot.dialect import mavlink
from companion.autopilot.fence import (
    MAV_FRAME_GLOBAL,
    MAV_MISSION_TYPE_FENCE,
    AutopilotFence,
    FenceItem,
    FenceItemsError,
    fence_from_items,
    fence_items,
)
from companion.autopilot.interface import AutopilotError

log = logging.getLogger(__name__)

MISSION_MESSAGES = frozenset(
    {"MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK", "MISSION_COUNT", "MISSION_ITEM_INT"}
)
STEP_TIMEOUT_S = 1.5  # per request/answer exchange (MAVLink mission protocol: 1.5 s is usual)
STEP_TRIES = 4
TRANSFER_TIMEOUT_S = 30.0


def mission_result_name(code: int) -> str:
    e = mavlink.enums["MAV_MISSION_RESULT"].get(code)
    return e.name if e is not None else str(code)


class ArduPilotFence:
    """Mixin of the ArduPilot backend (uses its ``_send``, ``_loop``, ``target_system``)."""

    _mission_rx: asyncio.Queue[Any] | None = None
    _send: Any
    _loop: Any
    target_system: int | None
    target_component: int

    def _on_mission_message(self, m: Any) -> None:
        """On the loop: a mission-protocol message from the vehicle."""
        if self._mission_rx is not None and getattr(m, "mission_type", 0) == MAV_MISSION_TYPE_FENCE:
            self._mission_rx.put_nowait(m)

    async def _next(self, types: set[str], deadline: float, pred: Any = None) -> Any:
        assert self._mission_rx is not None
        while True:
            left = deadline - time.monotonic()
            if left <= 0:
                return None
            try:
                m = await asyncio.wait_for(self._mission_rx.get(), left)
            except TimeoutError:
                return None
            if m.get_type() in types and (pred is None or pred(m)):
                return m

    async def upload_fence(self, fence: AutopilotFence) -> None:
        if self._loop is None:
            raise AutopilotError("fence upload: not connected")
        items = fence_items(fence)
        ts, tc = self.target_system or 1, self.target_component
        self._mission_rx = asyncio.Queue()
        try:
            t_end = time.monotonic() + TRANSFER_TIMEOUT_S
            self._send(lambda mav: mav.mission_count_send(ts, tc, len(items), MAV_MISSION_TYPE_FENCE))
            sent_any = False
            tries = 0
            while time.monotonic() < t_end:
                m = await self._next(
                    {"MISSION_REQUEST", "MISSION_REQUEST_INT", "MISSION_ACK"}, time.monotonic() + STEP_TIMEOUT_S
                )
                if m is None:
                    tries += 1
                    if tries >= STEP_TRIES:
                        raise AutopilotError(f"fence upload: no answer from the vehicle after {tries} tries")
                    if not sent_any:  # the count was lost: say it again
                        self._send(lambda mav: mav.mission_count_send(ts, tc, len(items), MAV_MISSION_TYPE_FENCE))
                    continue
                tries = 0
                if m.get_type() == "MISSION_ACK":
                    if m.type == mavlink.MAV_MISSION_ACCEPTED:
                        log.info("fence uploaded: %s", fence.describe())
                        return
                    raise AutopilotError(f"fence upload refused by the vehicle: {mission_result_name(m.type)}")
                if not 0 <= m.seq < len(items):
                    raise AutopilotError(f"fence upload: the vehicle asked for item {m.seq} of {len(items)}")
                it = items[m.seq]
                sent_any = True
                self._send(
                    lambda mav, it=it: mav.mission_item_int_send(
                        ts, tc, it.seq, MAV_FRAME_GLOBAL, it.command, 0, 1,
                        float(it.vertex_count), float(it.group), 0.0, 0.0,
                        it.lat_e7, it.lon_e7, 0.0, MAV_MISSION_TYPE_FENCE,
                    )
                )  # fmt: skip
            raise AutopilotError(f"fence upload did not finish within {TRANSFER_TIMEOUT_S:g} s")
        finally:
            self._mission_rx = None

    async def download_fence(self) -> AutopilotFence:
        if self._loop is None:
            raise AutopilotError("fence download: not connected")
        ts, tc = self.target_system or 1, self.target_component
        self._mission_rx = asyncio.Queue()
        try:
            count_msg = None
            for _ in range(STEP_TRIES):
                self._send(lambda mav: mav.mission_request_list_send(ts, tc, MAV_MISSION_TYPE_FENCE))
                count_msg = await self._next({"MISSION_COUNT"}, time.monotonic() + STEP_TIMEOUT_S)
                if count_msg is not None:
                    break
            if count_msg is None:
                raise AutopilotError("fence download: the vehicle never sent its fence item count")
            items: list[FenceItem] = []
            for seq in range(count_msg.count):
                got = None
                for _ in range(STEP_TRIES):
                    self._send(lambda mav, seq=seq: mav.mission_request_int_send(ts, tc, seq, MAV_MISSION_TYPE_FENCE))
                    got = await self._next(
                        {"MISSION_ITEM_INT"}, time.monotonic() + STEP_TIMEOUT_S, lambda m, seq=seq: m.seq == seq
                    )
                    if got is not None:
                        break
                if got is None:
                    raise AutopilotError(f"fence download: no item {seq} of {count_msg.count}")
                if not (math.isfinite(got.param1) and math.isfinite(got.param2)):  # round() would raise
                    raise AutopilotError(
                        f"fence read back from the vehicle: item {seq}: vertex count {got.param1} and group "
                        f"{got.param2}: expected whole numbers"
                    )
                items.append(FenceItem(seq, got.command, round(got.param1), round(got.param2), got.x, got.y))
            self._send(lambda mav: mav.mission_ack_send(ts, tc, mavlink.MAV_MISSION_ACCEPTED, MAV_MISSION_TYPE_FENCE))
        finally:
            self._mission_rx = None
        try:
            return fence_from_items(items)
        except FenceItemsError as err:
            raise AutopilotError(f"fence read back from the vehicle: {err}") from None

"""Remote ID on the PX4 link (docs/remote-id.md).

PX4 v1.16 takes OPEN_DRONE_ID_OPERATOR_ID, SELF_ID and SYSTEM over MAVLink
(``src/modules/mavlink/mavlink_receiver.cpp``: published on uORB for its DroneCAN Remote ID driver
and its OPEN_DRONE_ID_SYSTEM stream); BASIC_ID it makes itself (the board's GUID), SYSTEM_UPDATE
and ARM_STATUS it does not read. With ``[remote_id] enabled`` the backend sends those three
through MAVSDK's MavlinkDirect, SYSTEM every ``1 / system_update_rate_hz`` (PX4 has no
SYSTEM_UPDATE: SYSTEM carries the operator's location), the other two at ``static_rate_hz``.
PX4's arming check is its own (COM_ARM_ODID, on a MAV_TYPE_ODID heartbeat): no gate here.
"""

from __future__ import annotations

import asyncio
import json
import logging
import time
from typing import Any

from companion.autopilot.interface import TelemetryCache
from companion.autopilot.remote_id.messages import (
    OdidMessage,
    operator_id,
    operator_location,
    self_id,
    system,
)
from companion.config import RemoteIdConfig

log = logging.getLogger(__name__)

TICK_S = 0.1


def odid_json(msg: OdidMessage) -> str:
    """``msg``'s fields as MavlinkDirect's JSON: ``char[n]`` as a string, arrays as lists."""
    return json.dumps({k: (v.decode("ascii") if isinstance(v, bytes) else v) for k, v in msg.fields.items()})


def px4_due(
    cfg: RemoteIdConfig, state: dict[str, float], now_s: float, unix_s: float, home: Any, sysid: int
) -> list[OdidMessage]:
    """The messages PX4 takes that are due at ``now_s``; ``state`` keeps the next times."""
    out: list[OdidMessage] = []
    if now_s >= state.get("static", -1e18):
        state["static"] = now_s + 1.0 / cfg.static_rate_hz
        out += [m for m in (self_id(cfg, sysid), operator_id(cfg, sysid)) if m is not None]
    period = 1.0 / (cfg.system_update_rate_hz or cfg.static_rate_hz)
    where = operator_location(cfg, home)
    if where is not None and now_s >= state.get("system", -1e18):
        state["system"] = now_s + period
        out.append(system(where, unix_s, sysid))
    return out


class Px4RemoteId:
    """The Remote ID part of :class:`~.autopilot.Px4Autopilot`."""

    remote_id: RemoteIdConfig | None = None  # from_config: [remote_id] when enabled
    telemetry: TelemetryCache
    system_id: int
    _direct_sync: Any
    _tasks: list[asyncio.Task[Any]]

    remote_id_sent = 0

    def send_odid(self, msg: OdidMessage) -> bool:
        if self._direct_sync is None:
            return False
        from mavsdk.plugins.mavlink_direct import MavlinkMessage

        f = msg.fields
        try:
            self._direct_sync.send_message(
                MavlinkMessage(msg.name, 0, 0, int(f["target_system"]), int(f["target_component"]), odid_json(msg))
            )
        except Exception as err:  # MAVSDK's MavlinkDirectError, or the link gone
            log.debug("%s not sent: %s", msg.name, err)
            return False
        self.remote_id_sent += 1
        return True

    def _start_remote_id(self) -> None:
        cfg = self.remote_id
        if cfg is None or not cfg.enabled or any(t.get_name() == "px4-remote-id" and not t.done() for t in self._tasks):
            return
        self._tasks.append(asyncio.get_running_loop().create_task(self._remote_id_loop(cfg), name="px4-remote-id"))
        log.info("Remote ID: sending OPERATOR_ID, SELF_ID and SYSTEM to PX4 (BASIC_ID is PX4's own)")

    async def _remote_id_loop(self, cfg: RemoteIdConfig) -> None:
        state: dict[str, float] = {}
        while True:
            for msg in px4_due(cfg, state, time.monotonic(), time.time(), self.telemetry.home, self.system_id):
                self.send_odid(msg)
            await asyncio.sleep(TICK_S)

"""The companion's own MAVLink component on the PX4 link (``docs/gcs.md``).

MAVSDK speaks with one identity, fixed when it is created: the backend creates it with the
component's ids (``component_system_id``, ``component_id``), so MAVSDK's own HEARTBEAT
(companion-computer configuration: MAV_TYPE_ONBOARD_CONTROLLER, MAV_AUTOPILOT_INVALID) is the
component's, and whatever MavlinkDirect sends goes out from it. COMMAND_LONGs from the operator's
GCS come from another system, which MAVSDK's per-system plugins do not see: they are read from
MAVSDK's incoming-message interceptor (every message the core receives, decoded to JSON). PX4
passes messages between its MAVLink instances that have forwarding on (MAV_n_FORWARD; both
SITL instances are started with ``-f``): broadcasts, and messages addressed to another component.
"""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import time
from collections.abc import Callable
from typing import Any

from companion.autopilot.component import ComponentCommand
from companion.autopilot.interface import AutopilotError
from companion.autopilot.px4.mavsdk_core import intercept_messages_json

log = logging.getLogger(__name__)


class Px4Component:
    """``open_component`` / ``send_from_component`` of :class:`~.autopilot.Px4Autopilot`."""

    _mavsdk: Any
    _direct_sync: Any
    _system: Any
    component_system_id: int
    component_id: int
    component_commands: int
    _component_unhook: Callable[[], None] | None

    def open_component(
        self, component_id: int, system_id: int, on_command: Callable[[ComponentCommand], None]
    ) -> tuple[int, int]:
        if self._mavsdk is None or self._system is None:
            raise AutopilotError("open_component: not connected")
        want_sys = system_id or self.component_system_id
        if (want_sys, component_id) != (self.component_system_id, self.component_id):
            raise AutopilotError(
                f"open_component {want_sys}/{component_id}: MAVSDK speaks as {self.component_system_id}/"
                f"{self.component_id}, fixed when it was created (Px4Autopilot(component_id=..., "
                "component_system_id=...), from [gcs] in the parameters)"
            )
        loop = asyncio.get_running_loop()
        sysid, compid = self.component_system_id, self.component_id

        def on_message(msg: Any) -> None:  # MAVSDK's thread
            if msg.message_name != b"COMMAND_LONG":
                return
            try:
                f = json.loads(msg.fields_json)
                if int(f["target_system"]) != sysid or int(f["target_component"]) != compid:
                    return
                cmd = ComponentCommand(
                    time.monotonic(),
                    int(msg.system_id),
                    int(msg.component_id),
                    int(f["command"]),
                    int(f.get("confirmation", 0)),
                    tuple(float(f[f"param{i}"]) for i in range(1, 8)),  # type: ignore[arg-type]
                ).validate()
            except (ValueError, KeyError, TypeError) as err:
                log.warning("COMMAND_LONG for the companion not understood (%s): %s", err, msg.fields_json)
                return
            self.component_commands += 1
            with contextlib.suppress(RuntimeError):  # the loop is closing
                loop.call_soon_threadsafe(on_command, cmd)

        self.close_component()
        unhook = intercept_messages_json(self._mavsdk, "incoming", on_message)
        if unhook is None:
            raise AutopilotError("open_component: this MAVSDK build does not report incoming messages")
        self._component_unhook = unhook
        log.info("companion component %d/%d on the PX4 link (MAVSDK's identity)", sysid, compid)
        return sysid, compid

    def close_component(self) -> None:
        unhook, self._component_unhook = self._component_unhook, None
        if unhook is not None and self._mavsdk is not None:
            with contextlib.suppress(Exception):
                unhook()

    def send_from_component(self, name: str, fields: dict[str, Any]) -> bool:
        if self._system is None or self._direct_sync is None:
            return False
        from mavsdk.plugins.mavlink_direct import MavlinkMessage

        tsys = int(fields.get("target_system", 0))
        tcomp = int(fields.get("target_component", 0))
        try:
            self._direct_sync.send_message(MavlinkMessage(name, 0, 0, tsys, tcomp, json.dumps(fields)))
        except Exception as err:
            log.debug("%s from the companion component not sent: %s", name, err)
            return False
        return True

"""The companion's own MAVLink component on the ArduPilot link (``docs/gcs.md``).

Its messages go out on the same pymavlink connection with the vehicle's system id and the
component's id (the backend's own traffic keeps its ``source_system``, SYSID_MYGCS for ArduPilot's
RC override and GCS failsafe); ArduPilot learns the route to (system, component) from the
heartbeat and forwards the component's broadcast messages (HEARTBEAT, STATUSTEXT,
ONBOARD_COMPUTER_STATUS) to its other links and a COMMAND_LONG addressed to it back here
(``libraries/GCS_MAVLink/MAVLink_routing.cpp``).
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

from companion.autopilot.ardupilot.dialect import mavlink
from companion.autopilot.component import ComponentCommand
from companion.autopilot.interface import AutopilotError
from companion.autopilot.signing import SigningSetup

log = logging.getLogger(__name__)


class ArduPilotComponent:
    """``open_component`` / ``send_from_component`` of :class:`~.autopilot.ArduPilotAutopilot`."""

    _conn: Any
    target_system: int | None
    _component: tuple[int, int, Callable[[ComponentCommand], None]] | None
    signing: SigningSetup | None
    component_commands: int

    # from ArduPilotLink (later in the MRO): declared for the type checker only
    _send: Callable[[Callable[[Any], None]], bool]
    _post: Callable[..., None]

    def open_component(
        self, component_id: int, system_id: int, on_command: Callable[[ComponentCommand], None]
    ) -> tuple[int, int]:
        sysid = system_id or self.target_system
        if self._conn is None or sysid is None:
            raise AutopilotError("open_component: not connected (the vehicle's system id is not known yet)")
        if not 1 <= component_id <= 255:
            raise AutopilotError(f"open_component: component id {component_id} is not 1..255")
        self._component = (int(sysid), int(component_id), on_command)
        self._component_heartbeat()
        log.info("companion component %d/%d on the ArduPilot link", sysid, component_id)
        return int(sysid), int(component_id)

    def close_component(self) -> None:
        self._component = None

    def send_from_component(self, name: str, fields: dict[str, Any]) -> bool:
        comp = self._component
        if comp is None or self._conn is None:
            return False
        cls = getattr(mavlink, f"MAVLink_{name.lower()}_message", None)
        if cls is None:
            raise AutopilotError(f"send_from_component: no MAVLink message {name!r} in the ardupilotmega dialect")
        msg = cls(**{k: (v.encode() if isinstance(v, str) else v) for k, v in fields.items()})
        sysid, compid = comp[0], comp[1]

        def send(mav: Any) -> None:  # under the send lock: the ids are ours for this one packet
            keep = mav.srcSystem, mav.srcComponent
            mav.srcSystem, mav.srcComponent = sysid, compid
            try:
                mav.send(msg)
            finally:
                mav.srcSystem, mav.srcComponent = keep

        return self._send(send)

    def _component_heartbeat(self) -> None:
        """Called each second by the reader thread (and on open): the component's HEARTBEAT."""
        if self._component is None:
            return
        self.send_from_component(
            "HEARTBEAT",
            {
                "type": mavlink.MAV_TYPE_ONBOARD_CONTROLLER,
                "autopilot": mavlink.MAV_AUTOPILOT_INVALID,
                "base_mode": 0,
                "custom_mode": 0,
                "system_status": mavlink.MAV_STATE_ACTIVE,
                "mavlink_version": 3,
            },
        )

    def _on_component_command(self, m: Any) -> None:
        """A COMMAND_LONG from anyone (reader thread): handed over when addressed to our component."""
        comp = self._component
        if comp is None or m.target_system != comp[0] or m.target_component != comp[1]:
            return
        cmd = ComponentCommand(
            time.monotonic(),
            m.get_srcSystem(),
            m.get_srcComponent(),
            int(m.command),
            int(m.confirmation),
            (m.param1, m.param2, m.param3, m.param4, m.param5, m.param6, m.param7),
            # True only when its signature verified with our key (pymavlink's sig_ok)
            bool(m.get_signed()) if self.signing is not None else None,
        )
        self.component_commands += 1
        self._post(comp[2], cmd)

"""Remote ID on the ArduPilot link (docs/remote-id.md).

With ``[remote_id] enabled`` the backend sends BASIC_ID, SELF_ID, OPERATOR_ID and SYSTEM at
``static_rate_hz`` and SYSTEM_UPDATE at ``system_update_rate_hz``, addressed to the autopilot:
AP_OpenDroneID (libraries/AP_OpenDroneID/AP_OpenDroneID.cpp, ``handle_msg``) keeps the latest of
each, from any link, and re-sends its copies to the transponder on DID_MAVPORT (or DroneCAN);
LOCATION it builds itself from its own position. The transponder's OPEN_DRONE_ID_ARM_STATUS
(ArduPilot takes it only on DID_MAVPORT's link and forwards it, a broadcast, to its other links:
MAVLink_routing.cpp) is kept typed in :attr:`ArduPilotRemoteId.remote_id_arm_status`, from any
source system; :meth:`ArduPilotRemoteId.remote_id_gate` is the arming gate on it.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import time
from collections.abc import Callable
from typing import Any

from companion.autopilot.ardupilot.dialect import mavlink
from companion.autopilot.interface import TelemetryCache
from companion.autopilot.remote_id.arm_status import ArmStatusReport, GateDecision, arm_gate
from companion.autopilot.remote_id.messages import OdidMessage
from companion.autopilot.remote_id.schedule import RemoteIdSchedule
from companion.config import RemoteIdConfig

log = logging.getLogger(__name__)

TICK_S = 0.1  # the sender's period: the rates (at most 10 Hz) are kept to within it


class ArduPilotRemoteId:
    """The Remote ID part of :class:`~.autopilot.ArduPilotAutopilot`."""

    remote_id: RemoteIdConfig | None
    telemetry: TelemetryCache
    target_system: int | None
    _send: Callable[[Callable[[Any], None]], bool]
    _post: Callable[..., None]

    remote_id_arm_status: ArmStatusReport | None = None
    remote_id_sent = 0  # OpenDroneID messages sent
    _remote_id_task: asyncio.Task[None] | None = None

    def _on_odid_arm_status(self, m: Any, now: float) -> None:
        """An OPEN_DRONE_ID_ARM_STATUS (reader thread): kept, a change of status logged."""
        report = ArmStatusReport.decode(now, m.status, m.error, m.get_srcSystem(), m.get_srcComponent())
        self._post(self._set_arm_status, report)

    def _set_arm_status(self, report: ArmStatusReport) -> None:
        old = self.remote_id_arm_status
        self.remote_id_arm_status = report
        if old is None or old.status is not report.status or old.error != report.error:
            log.info(
                "Remote ID transponder %d/%d: %s%s",
                report.src_system,
                report.src_component,
                report.status.name,
                f" ({report.error})" if report.error else "",
            )

    def remote_id_gate(self, now_s: float | None = None) -> GateDecision:
        """May the vehicle be armed for a delivery, on the transponder's ARM_STATUS?"""
        cfg = self.remote_id
        return arm_gate(
            cfg is not None and cfg.enabled,
            self.remote_id_arm_status,
            time.monotonic() if now_s is None else now_s,
            cfg.arm_status_max_age_s if cfg is not None else 0.0,
        )

    def send_odid(self, msg: OdidMessage) -> bool:
        """Pack and send one OpenDroneID message from the backend's own ids."""
        cls = getattr(mavlink, f"MAVLink_{msg.name.lower()}_message")
        packet = cls(**msg.fields)
        ok = self._send(lambda mav: mav.send(packet))
        self.remote_id_sent += ok
        return ok

    def _start_remote_id(self) -> None:
        cfg = self.remote_id
        if cfg is None or not cfg.enabled or self._remote_id_task is not None or self.target_system is None:
            return
        schedule = RemoteIdSchedule(cfg, self.target_system)
        self._remote_id_task = asyncio.get_running_loop().create_task(self._remote_id_loop(schedule))
        log.info(
            "Remote ID: sending BASIC_ID (%s), SELF_ID, OPERATOR_ID, SYSTEM at %g Hz, SYSTEM_UPDATE at %g Hz",
            cfg.uas_id,
            cfg.static_rate_hz,
            cfg.system_update_rate_hz,
        )

    async def _stop_remote_id(self) -> None:
        task, self._remote_id_task = self._remote_id_task, None
        if task is not None:
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

    async def _remote_id_loop(self, schedule: RemoteIdSchedule) -> None:
        while True:
            for msg in schedule.due(time.monotonic(), time.time(), self.telemetry.home):
                self.send_odid(msg)
            await asyncio.sleep(TICK_S)

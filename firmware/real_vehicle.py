"""A real autopilot SITL with its ground truth, ready for the companion: one place that knows how
PX4 SIH and ArduCopter SITL are started, where truth comes from and which backend talks to them
(used by the real landing campaign, the parity campaign and the firmware probe).

- ``px4``: :class:`Px4Sitl` (clean parameters), MAVSDK on udp 14540, HIL_STATE_QUATERNION truth
  on the GCS link 14550.
- ``ardupilot``: :class:`ArduCopterSitl` (clean eeprom), pymavlink on tcp 5760, SIM_STATE truth
  on SERIAL1 (udp). Arming waits for EKF3 on GPS (~41 s of simulated time
  after boot, spent at 10x: ~4 s).
"""

from __future__ import annotations

import asyncio
import contextlib
from collections.abc import AsyncIterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from companion.autopilot.interface import Autopilot
from companion.config import CompanionConfig
from companion_firmware.ardupilot_sitl import ArduCopterSitl, find_ardupilot
from companion_firmware.px4_sitl import Px4Sitl, find_px4
from companion_firmware.truth_feed import MavlinkTruth
from companion_sitl.mavlink.link import free_udp_port

REAL_AUTOPILOTS = ("px4", "ardupilot")
PX4_OFFBOARD_URL = "udpin://127.0.0.1:14540"
PX4_GCS_URL = "udpin:127.0.0.1:14550"
# ArduCopter options the delivery uses, set from boot (GRIP_* need a reboot): servo gripper on output 9
ARDUCOPTER_GRIPPER_SERVO9 = {"GRIP_ENABLE": 1, "GRIP_TYPE": 1, "SERVO9_FUNCTION": 28}


@dataclass
class RealVehicle:
    autopilot_name: str
    sitl: Px4Sitl | ArduCopterSitl
    truth: MavlinkTruth
    connection: str
    landings_flown: int = 0

    def backend(self, config: CompanionConfig) -> Autopilot:
        """The backend ``config`` selects, pointed at this SITL (not yet connected)."""
        cfg = config.model_copy(update={"autopilot": self.autopilot_name, "connection": self.connection})
        if self.autopilot_name == "px4":
            from companion.autopilot.px4 import Px4Autopilot

            return Px4Autopilot.from_config(cfg)
        from companion.autopilot.ardupilot import ArduPilotAutopilot

        return ArduPilotAutopilot.from_config(cfg, arm_timeout_s=90.0)


@contextlib.asynccontextmanager
async def real_vehicle(
    autopilot: str,
    log_dir: Path,
    extra_params: dict[str, float] | None = None,
    root: Path | None = None,
    watch: tuple[str, ...] = (),
) -> AsyncIterator[RealVehicle]:
    """Start the SITL (with ``extra_params`` from boot) and its truth feed (keeping the ``watch``
    messages, MavlinkTruth); stop both on exit. Raises ``Px4NotFound`` / ``ArduPilotNotFound``
    (saying where it looked) without a build."""
    log_dir.mkdir(parents=True, exist_ok=True)
    if autopilot == "px4":
        px4 = Px4Sitl(root or find_px4(), params=dict(extra_params or {}), log_path=log_dir / "px4.log")
        with px4, MavlinkTruth(PX4_GCS_URL, watch=watch) as truth:
            await asyncio.to_thread(truth.wait, 30.0)
            yield RealVehicle("px4", px4, truth, PX4_OFFBOARD_URL)
        return
    if autopilot == "ardupilot":
        port = free_udp_port()
        params: dict[str, Any] = {**ARDUCOPTER_GRIPPER_SERVO9, **(extra_params or {})}
        ac = ArduCopterSitl(
            root or find_ardupilot(),
            extra_params=params,
            serials={1: f"udpclient:127.0.0.1:{port}"},
            log_path=log_dir / "arducopter.log",
        )
        with ac, MavlinkTruth(f"udpin:127.0.0.1:{port}", message="SIM_STATE", watch=watch) as truth:
            await asyncio.to_thread(truth.wait, 15.0)
            yield RealVehicle("ardupilot", ac, truth, ac.connection)
        return
    raise ValueError(f"autopilot {autopilot!r}: expected one of {REAL_AUTOPILOTS}")

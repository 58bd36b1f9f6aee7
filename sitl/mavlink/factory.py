"""Builds the MAVLink sim vehicle of a dialect by name (``"px4"`` or ``"ardupilot"``)."""

from __future__ import annotations

from typing import Any

from companion_sitl.mavlink.ardupilot import ArduPilotSimVehicle
from companion_sitl.mavlink.px4 import Px4SimVehicle
from companion_sitl.mavlink.vehicle import Dialect, MavlinkSimVehicle
from companion_sitl.params import SimConfig

DIALECTS: dict[str, type[MavlinkSimVehicle]] = {"px4": Px4SimVehicle, "ardupilot": ArduPilotSimVehicle}


def mavlink_sim_vehicle(cfg: SimConfig, dialect: Dialect = "px4", **kwargs: Any) -> MavlinkSimVehicle:
    """The sim vehicle speaking ``dialect``; ``kwargs`` are :class:`MavlinkSimVehicle`'s."""
    if dialect not in DIALECTS:
        raise ValueError(f"dialect {dialect!r}: must be 'px4' or 'ardupilot'")
    return DIALECTS[dialect](cfg, dialect, **kwargs)

"""Pick the autopilot backend named in the configuration."""

from __future__ import annotations

import logging
import os
from typing import Any

from companion.autopilot.interface import Autopilot, AutopilotError, LinkDeviceMissing
from companion.config import CompanionConfig

log = logging.getLogger(__name__)


def make_autopilot(config: CompanionConfig, **kwargs: Any) -> Autopilot:
    """``config.autopilot``: "px4" (MAVSDK) or "ardupilot" (pymavlink).

    Extra keyword arguments go to the backend's constructor (e.g. ``release="servo"``, ``tlog=``).
    Backends are imported lazily so a missing optional dependency only matters when chosen. The
    embedded simulator ("sim") is not a backend of this package: the command line wires it
    (:func:`companion.cli.fly.make_autopilot`).
    """
    kind = config.autopilot
    log.info("autopilot backend %s on %s", kind, config.connection)
    if kind == "px4":
        from companion.autopilot.px4 import Px4Autopilot

        return Px4Autopilot.from_config(config, **kwargs)
    if kind == "ardupilot":
        from companion.autopilot.ardupilot import ArduPilotAutopilot

        return ArduPilotAutopilot.from_config(config, **kwargs)
    raise AutopilotError(f"unknown autopilot backend {kind!r} (sim, px4, ardupilot)")


def check_connection(config: CompanionConfig) -> None:
    """Check ``config.connection`` for the backend ``config.autopilot`` names without opening it:
    :class:`~companion.autopilot.interface.ConnectionUrlError` when malformed,
    :class:`~companion.autopilot.interface.LinkDeviceMissing` when its serial device does not
    exist. Lets a command fail before it starts anything else."""
    if config.autopilot == "px4":
        from companion.autopilot.px4.mavsdk_core import check_connection_url

        check_connection_url(config.connection)
    elif config.autopilot == "ardupilot":
        from companion.autopilot.ardupilot.link import parse_connection

        device, _, kind = parse_connection(config.connection)
        if kind == "serial" and not os.path.exists(device):
            raise LinkDeviceMissing(f"serial device {device} does not exist (connection {config.connection!r})")

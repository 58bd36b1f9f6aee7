"""Pick the autopilot backend named in the configuration."""

from __future__ import annotations

import logging
from typing import Any

from companion.autopilot.interface import Autopilot, AutopilotError
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

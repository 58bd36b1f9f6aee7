"""A delivery's destination from outside the parameter file.

The pad normally comes from ``[mission.pad]``. A delivery order from the ground and a mission the
operator uploaded to the autopilot name the pad (and optionally an alternate) by latitude,
longitude and altitude instead; :func:`config_for_destination` turns one into the configuration
the delivery is flown with, validated by the same schema as the file (limits, fence), so an order
and a parameter file are refused for the same reasons, with the same words.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, TypeVar

from companion.config import CompanionConfig, ConfigError, validate_config


class DestinationError(ValueError):
    """A destination that cannot be flown: ``reason`` says which value and what is expected."""

    def __init__(self, reason: str):
        super().__init__(reason)
        self.reason = reason


@dataclass(frozen=True, slots=True)
class GeoPad:
    """A pad's centre on the ground (WGS-84). ``alt_amsl_m`` None: at the home's ground altitude."""

    lat_deg: float
    lon_deg: float
    alt_amsl_m: float | None = None

    def check(self, what: str) -> None:
        """Refuse a non-finite or out-of-range coordinate, naming it."""
        for name, value, limit in (("lat_deg", self.lat_deg, 90.0), ("lon_deg", self.lon_deg, 180.0)):
            if isinstance(value, bool) or not isinstance(value, (int, float)):
                raise DestinationError(f"{what}.{name} = {value!r}: expected a number of degrees")
            if not math.isfinite(value) or abs(value) > limit:
                raise DestinationError(f"{what}.{name} = {value!r}: expected a finite value within +-{limit:g} deg")
        alt = self.alt_amsl_m
        if alt is not None and (isinstance(alt, bool) or not isinstance(alt, (int, float)) or not math.isfinite(alt)):
            raise DestinationError(f"{what}.alt_amsl_m = {alt!r}: expected a finite altitude in metres, or none")

    def as_table(self, size_m: float) -> dict[str, Any]:
        table: dict[str, Any] = {"lat_deg": float(self.lat_deg), "lon_deg": float(self.lon_deg), "size_m": size_m}
        if self.alt_amsl_m is not None:
            table["alt_amsl_m"] = float(self.alt_amsl_m)
        return table


@dataclass(frozen=True, slots=True)
class Destination:
    """Where one delivery goes, and who said so (``source``, for the events and the logs)."""

    pad: GeoPad
    source: str
    alternate: GeoPad | None = None


_C = TypeVar("_C", bound=CompanionConfig)


def config_for_destination(config: _C, dest: Destination) -> _C:
    """``config`` with its pad (and alternate pad) replaced by ``dest``'s; the pad size stays the
    configured one, and the config keeps its schema (the simulator's checks its [sim] again). Raises
    :class:`DestinationError` when the schema refuses the result (a pad outside the fence, a
    coordinate out of range)."""
    dest.pad.check("pad")
    if dest.alternate is not None:
        dest.alternate.check("alternate_pad")
    data = config.model_dump()
    mission = data["mission"]
    mission["pad"] = dest.pad.as_table(config.mission.pad.size_m)
    if dest.alternate is not None:
        size = (config.mission.alternate_pad or config.mission.pad).size_m
        mission["alternate_pad"] = dest.alternate.as_table(size)
    try:
        return validate_config(type(config), data, dest.source)
    except ConfigError as err:
        raise DestinationError("; ".join(err.problems)) from None

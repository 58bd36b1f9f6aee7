"""The OpenDroneID messages the companion gives the autopilot, built from ``[remote_id]``
(docs/remote-id.md). Pure functions: each returns an :class:`OdidMessage`, the MAVLink message's
name and its fields encoded as MAVLink common.xml says, ready for a backend to pack.

Encodings (common.xml, OPEN_DRONE_ID_*): ``uint8_t[20]`` arrays (``id_or_mac``, ``uas_id``) are
lists of 20 byte values, the text NUL-padded; ``char[n]`` fields (``operator_id`` [20],
``description`` [23]) are bytes of at most n, which the packer NUL-pads; latitudes and longitudes
are int32 in 1e-7 degrees; altitudes float metres, -1000 for unknown; ``timestamp`` uint32 seconds
since 2019-01-01 00:00:00 UTC. ``id_or_mac`` is all zeros: it is only for messages received from
other aircraft.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import IntEnum
from typing import Any

from companion.config import RemoteIdConfig

#: Unix time of the OpenDroneID epoch, 2019-01-01 00:00:00 UTC (the SYSTEM ``timestamp``'s zero)
ODID_EPOCH_UNIX_S = 1546300800
#: the spec's value for an unknown altitude or area floor / ceiling (m)
ALT_UNKNOWN_M = -1000.0
ID_LEN = 20  # BASIC_ID uas_id, OPERATOR_ID operator_id, id_or_mac
DESCRIPTION_LEN = 23  # SELF_ID description
MAV_COMP_ID_AUTOPILOT1 = 1


class IdType(IntEnum):
    """MAV_ODID_ID_TYPE."""

    NONE = 0
    SERIAL_NUMBER = 1
    CAA_REGISTRATION_ID = 2
    UTM_ASSIGNED_UUID = 3
    SPECIFIC_SESSION_ID = 4


class OperatorLocationType(IntEnum):
    """MAV_ODID_OPERATOR_LOCATION_TYPE."""

    TAKEOFF = 0
    LIVE_GNSS = 1
    FIXED = 2


class DescType(IntEnum):
    """MAV_ODID_DESC_TYPE."""

    TEXT = 0
    EMERGENCY = 1
    EXTENDED_STATUS = 2


class ClassificationType(IntEnum):
    """MAV_ODID_CLASSIFICATION_TYPE."""

    UNDECLARED = 0
    EU = 1


MAV_ODID_OPERATOR_ID_TYPE_CAA = 0


@dataclass(frozen=True, slots=True)
class OdidMessage:
    """One MAVLink message: ``name`` (``"OPEN_DRONE_ID_BASIC_ID"``, ...) and its fields by name."""

    name: str
    fields: dict[str, Any]


@dataclass(frozen=True, slots=True)
class OperatorLocation:
    """Where the operator is, as SYSTEM / SYSTEM_UPDATE carry it."""

    kind: OperatorLocationType
    lat_deg: float
    lon_deg: float
    alt_geo_m: float = ALT_UNKNOWN_M


def padded(text: str, length: int) -> list[int]:
    """``text`` as a ``uint8_t[length]`` array: its ASCII bytes, NUL-padded; ValueError when it
    does not fit or is not ASCII."""
    raw = text.encode("ascii")
    if len(raw) > length:
        raise ValueError(f"{text!r}: {len(raw)} characters, the field holds {length}")
    return list(raw) + [0] * (length - len(raw))


def chars(text: str, length: int) -> bytes:
    """``text`` for a ``char[length]`` field (ASCII, at most ``length``)."""
    raw = text.encode("ascii")
    if len(raw) > length:
        raise ValueError(f"{text!r}: {len(raw)} characters, the field holds {length}")
    return raw


def deg_e7(deg: float) -> int:
    """Degrees as MAVLink's int32 1e-7 degrees (rounded)."""
    if not math.isfinite(deg) or abs(deg) > 180.0:
        raise ValueError(f"{deg!r} is not an angle in degrees")
    return round(deg * 1e7)


def odid_timestamp(unix_s: float) -> int:
    """Unix time as the SYSTEM ``timestamp``: whole seconds since 2019-01-01 00:00:00 UTC."""
    if not math.isfinite(unix_s) or unix_s < ODID_EPOCH_UNIX_S:
        raise ValueError(f"unix time {unix_s!r} is before the OpenDroneID epoch (2019-01-01)")
    return min(int(unix_s - ODID_EPOCH_UNIX_S), 0xFFFFFFFF)


def _target(target_system: int) -> dict[str, Any]:
    # addressed to the autopilot: ArduPilot handles it and does not forward it to its other links
    # (MAVLink_routing.cpp); the transponder gets the autopilot's own copy
    return {"target_system": target_system, "target_component": MAV_COMP_ID_AUTOPILOT1, "id_or_mac": [0] * ID_LEN}


def basic_id(cfg: RemoteIdConfig, target_system: int) -> OdidMessage:
    return OdidMessage(
        "OPEN_DRONE_ID_BASIC_ID",
        {
            **_target(target_system),
            "id_type": int(IdType(cfg.id_type)),
            "ua_type": cfg.ua_type,
            "uas_id": padded(cfg.uas_id, ID_LEN),
        },
    )


def self_id(cfg: RemoteIdConfig, target_system: int) -> OdidMessage | None:
    """SELF_ID with the configured text; None when there is none."""
    if not cfg.self_id:
        return None
    return OdidMessage(
        "OPEN_DRONE_ID_SELF_ID",
        {
            **_target(target_system),
            "description_type": int(DescType.TEXT),
            "description": chars(cfg.self_id, DESCRIPTION_LEN),
        },
    )


def operator_id(cfg: RemoteIdConfig, target_system: int) -> OdidMessage | None:
    """OPERATOR_ID (type CAA); None when no operator id is configured."""
    if not cfg.operator_id:
        return None
    return OdidMessage(
        "OPEN_DRONE_ID_OPERATOR_ID",
        {
            **_target(target_system),
            "operator_id_type": MAV_ODID_OPERATOR_ID_TYPE_CAA,
            "operator_id": chars(cfg.operator_id, ID_LEN),
        },
    )


def operator_location(cfg: RemoteIdConfig, home: Any | None) -> OperatorLocation | None:
    """The operator's location by ``cfg.operator_location``: the fixed one, or the autopilot's home
    (``home``: a :class:`~companion.autopilot.types.HomePosition`, its AMSL altitude standing in
    for the geodetic one); None while home is not known."""
    if cfg.operator_location == "fixed":
        return OperatorLocation(
            OperatorLocationType.FIXED, cfg.operator_lat_deg, cfg.operator_lon_deg, cfg.operator_alt_m
        )
    if home is None:
        return None
    alt = float(home.alt_amsl_m)
    return OperatorLocation(
        OperatorLocationType.TAKEOFF, home.lat_deg, home.lon_deg, alt if math.isfinite(alt) else ALT_UNKNOWN_M
    )


def system(where: OperatorLocation, unix_s: float, target_system: int) -> OdidMessage:
    """SYSTEM: the operator's location, one area of radius 0, no ceiling / floor, classification
    undeclared (category and class EU undeclared)."""
    return OdidMessage(
        "OPEN_DRONE_ID_SYSTEM",
        {
            **_target(target_system),
            "operator_location_type": int(where.kind),
            "classification_type": int(ClassificationType.UNDECLARED),
            "operator_latitude": deg_e7(where.lat_deg),
            "operator_longitude": deg_e7(where.lon_deg),
            "area_count": 1,
            "area_radius": 0,
            "area_ceiling": ALT_UNKNOWN_M,
            "area_floor": ALT_UNKNOWN_M,
            "category_eu": 0,
            "class_eu": 0,
            "operator_altitude_geo": float(where.alt_geo_m),
            "timestamp": odid_timestamp(unix_s),
        },
    )


def system_update(where: OperatorLocation, unix_s: float, target_system: int) -> OdidMessage:
    """SYSTEM_UPDATE: the operator location and time, SYSTEM's dynamic part."""
    return OdidMessage(
        "OPEN_DRONE_ID_SYSTEM_UPDATE",
        {
            "target_system": target_system,
            "target_component": MAV_COMP_ID_AUTOPILOT1,
            "operator_latitude": deg_e7(where.lat_deg),
            "operator_longitude": deg_e7(where.lon_deg),
            "operator_altitude_geo": float(where.alt_geo_m),
            "timestamp": odid_timestamp(unix_s),
        },
    )


def static_messages(cfg: RemoteIdConfig, home: Any | None, unix_s: float, target_system: int) -> list[OdidMessage]:
    """BASIC_ID, SELF_ID, OPERATOR_ID and SYSTEM, those that apply (SYSTEM once the operator's
    location is known)."""
    out = [basic_id(cfg, target_system)]
    for m in (self_id(cfg, target_system), operator_id(cfg, target_system)):
        if m is not None:
            out.append(m)
    where = operator_location(cfg, home)
    if where is not None:
        out.append(system(where, unix_s, target_system))
    return out

"""MAVLink codecs. The messages the companion sends, built in one place for every sender: the
pymavlink backend sends them, the simulator's tlog encoder logs them, the MAVSDK backend uses the
mask. :class:`MavlinkPacker` encodes decoded messages (MAVSDK's JSON) back into MAVLink 2 packets."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Mapping
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from companion.guidance.setpoint import VelocitySetpoint

VELOCITY_YAW_MASK = 0b0000_1101_1100_0111  # SET_POSITION_TARGET_LOCAL_NED: use vx, vy, vz and yaw only


def velocity_setpoint_message(
    time_boot_ms: int, target_system: int, target_component: int, sp: VelocitySetpoint
) -> Any:
    """SET_POSITION_TARGET_LOCAL_NED carrying a velocity in local NED and an absolute yaw."""
    return mavlink2.MAVLink_set_position_target_local_ned_message(
        time_boot_ms & 0xFFFFFFFF,
        target_system,
        target_component,
        mavlink2.MAV_FRAME_LOCAL_NED,
        VELOCITY_YAW_MASK,
        0.0,
        0.0,
        0.0,
        sp.north_m_s,
        sp.east_m_s,
        sp.down_m_s,
        0.0,
        0.0,
        0.0,
        sp.yaw_rad,
        0.0,
    )


_FLOAT_TYPES = ("float", "double")


class MavlinkPacker:
    """MAVLink 2 packets in pymavlink's ``ardupilotmega`` dialect (a superset of ``common``),
    with one sequence counter per source (system, component). Not thread-safe: use it from one
    thread (e.g. inside functions handed to a :class:`~companion.autopilot.interface.PacketSink`)."""

    def __init__(self) -> None:
        self._mav: dict[tuple[int, int], Any] = {}

    def pack(self, msg: Any, system_id: int, component_id: int) -> bytes:
        key = (system_id, component_id)
        mav = self._mav.get(key)
        if mav is None:
            mav = self._mav[key] = mavlink2.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        buf = bytes(msg.pack(mav))
        mav.seq = (mav.seq + 1) % 256
        return buf

    @staticmethod
    def message_from_fields(name_or_id: str | int, fields: Mapping[str, Any]) -> Any:
        """A pymavlink message from decoded field values (missing fields are 0; None, as in
        MAVSDK's JSON for NaN, is NaN for float fields and 0 otherwise)."""
        if isinstance(name_or_id, int):
            cls = mavlink2.mavlink_map.get(name_or_id)
        else:
            cls = getattr(mavlink2, f"MAVLink_{name_or_id.lower()}_message", None)
        if cls is None:
            raise KeyError(f"MAVLink message {name_or_id!r} is not in pymavlink's ardupilotmega dialect")
        lengths = dict(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))  # wire order
        args: list[Any] = []
        for name, ftype in zip(cls.fieldnames, cls.fieldtypes, strict=True):  # constructor order
            v, n = fields.get(name), lengths[name]
            if ftype == "char":
                s = v if isinstance(v, (bytes, bytearray)) else str(v or "").encode("utf-8", errors="replace")
                args.append(bytes(s[: max(n, 1)]))
                continue
            blank = math.nan if ftype in _FLOAT_TYPES else 0
            if n:
                seq = list(v) if isinstance(v, (list, tuple, bytes, bytearray)) else []
                seq = [blank if x is None else x for x in seq[:n]]
                args.append(seq + [0] * (n - len(seq)))
            else:
                args.append(blank if v is None else v)
        return cls(*args)

    def pack_fields(self, name_or_id: str | int, fields: Mapping[str, Any], system_id: int, component_id: int) -> bytes:
        return self.pack(self.message_from_fields(name_or_id, fields), system_id, component_id)

    def pack_json(self, name: str, fields_json: str, system_id: int, component_id: int) -> bytes:
        """A packet from one of MAVSDK's decoded messages (``message_name`` and ``fields_json``)."""
        fields = json.loads(fields_json) if fields_json else {}
        return self.pack_fields(fields.get("message_id", name), fields, system_id, component_id)

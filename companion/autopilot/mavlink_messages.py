"""MAVLink codecs. The messages the companion sends, built in one place for every sender: the
pymavlink backend sends them, the simulator's tlog encoder logs them, the MAVSDK backend uses the
mask. :class:`MavlinkPacker` encodes decoded messages (MAVSDK's JSON) back into MAVLink 2 packets."""

from __future__ import annotations

import binascii
import inspect
import json
import math
import operator
import os
import struct
from binascii import crc_hqx
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from companion.guidance.setpoint import VelocitySetpoint

# SET_POSITION_TARGET_LOCAL_NED's type_mask (POSITION_TARGET_TYPEMASK): ignore x, y, z (1, 2, 4),
# the accelerations (64, 128, 256) and the yaw rate (2048); use vx, vy, vz and yaw (1024 clear):
# the vehicle flies the path's heading (delivery 4.3, psi_r = 0 in F_I), as the embedded simulator does.
VELOCITY_YAW_MASK = 0b0000_1001_1100_0111  # 2503
# the same with the accelerations used (VelocitySetpoint.accel_ne_m_s2; afz sent as 0)
VELOCITY_ACCEL_YAW_MASK = 0b0000_1000_0000_0111  # 2055


def velocity_setpoint_message(
    time_boot_ms: int, target_system: int, target_component: int, sp: VelocitySetpoint
) -> Any:
    """SET_POSITION_TARGET_LOCAL_NED carrying a velocity in local NED and an absolute yaw."""
    return mavlink2.MAVLink_set_position_target_local_ned_message(
        *velocity_setpoint_fields(time_boot_ms, target_system, target_component, sp)
    )


def velocity_setpoint_fields(
    time_boot_ms: int, target_system: int, target_component: int, sp: VelocitySetpoint
) -> tuple[Any, ...]:
    """:func:`velocity_setpoint_message`'s field values, in its constructor's order."""
    acc = sp.accel_ne_m_s2
    return (
        time_boot_ms & 0xFFFFFFFF,
        target_system,
        target_component,
        mavlink2.MAV_FRAME_LOCAL_NED,
        VELOCITY_YAW_MASK if acc is None else VELOCITY_ACCEL_YAW_MASK,
        0.0,
        0.0,
        0.0,
        sp.north_m_s,
        sp.east_m_s,
        sp.down_m_s,
        0.0 if acc is None else acc[0],
        0.0 if acc is None else acc[1],
        0.0,
        sp.yaw_rad,
        0.0,
    )


_FLOAT_TYPES = ("float", "double")


class UnknownMessage(KeyError):
    """A message pymavlink's ardupilotmega dialect does not define (a newer common message, a
    PX4-only one): it cannot be packed into a .tlog; the writer counts these by name."""

    def __init__(self, name_or_id: str | int):
        super().__init__(f"MAVLink message {name_or_id!r} is not in pymavlink's ardupilotmega dialect")
        self.name_or_id = name_or_id


class MavlinkPacker:
    """MAVLink 2 packets in pymavlink's ``ardupilotmega`` dialect (a superset of ``common``),
    with one sequence counter per source (system, component). Messages from decoded fields
    (:meth:`pack_fields`, :meth:`pack_json`) are packed by a :class:`DirectPacker` without
    building pymavlink's message object; both paths share the counters. Not thread-safe: use it
    from one thread (e.g. inside functions handed to a
    :class:`~companion.autopilot.interface.PacketSink`)."""

    def __init__(self) -> None:
        self._mav: dict[tuple[int, int], Any] = {}
        self._direct = DirectPacker()

    def pack(self, msg: Any, system_id: int, component_id: int) -> bytes:
        key = (system_id, component_id)
        mav = self._mav.get(key)
        if mav is None:
            mav = self._mav[key] = mavlink2.MAVLink(None, srcSystem=system_id, srcComponent=component_id)
        mav.seq = self._direct.next_seq(key)
        return bytes(msg.pack(mav))

    @staticmethod
    def message_args(name_or_id: str | int, fields: Mapping[str, Any]) -> tuple[Any, list[Any]]:
        """The pymavlink message class and its constructor's arguments from decoded field values
        (missing fields are 0; None, as in MAVSDK's JSON for NaN, is NaN for float fields and 0
        otherwise)."""
        if isinstance(name_or_id, int):
            cls = mavlink2.mavlink_map.get(name_or_id)
        else:
            cls = getattr(mavlink2, f"MAVLink_{name_or_id.lower()}_message", None)
        if cls is None:
            raise UnknownMessage(name_or_id)
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
        return cls, args

    @staticmethod
    def message_from_fields(name_or_id: str | int, fields: Mapping[str, Any]) -> Any:
        """A pymavlink message from decoded field values (see :meth:`message_args`)."""
        cls, args = MavlinkPacker.message_args(name_or_id, fields)
        return cls(*args)

    def pack_fields(self, name_or_id: str | int, fields: Mapping[str, Any], system_id: int, component_id: int) -> bytes:
        cls, args = self.message_args(name_or_id, fields)
        return self._direct.pack(cls, args, system_id, component_id)

    def pack_json(self, name: str, fields_json: str, system_id: int, component_id: int) -> bytes:
        """A packet from one of MAVSDK's decoded messages (``message_name`` and ``fields_json``)."""
        fields = json.loads(fields_json) if fields_json else {}
        return self.pack_fields(fields.get("message_id", name), fields, system_id, component_id)


# ------------------------------------------------------------------------------ direct packing
_REV8 = bytes(int(f"{i:08b}"[::-1], 2) for i in range(256))  # each byte with its bits reversed
_HEADER_V2 = struct.Struct("<BBBBBBBHB")  # magic, len, incompat, compat, seq, sysid, compid, msgid (24 bit)
_CRC = struct.Struct("<H")


def _reflect16(x: int) -> int:
    return (_REV8[x & 0xFF] << 8) | _REV8[x >> 8]


def x25crc(data: bytes, crc: int = 0xFFFF) -> int:
    """MAVLink's checksum, CRC-16/MCRF4XX (pymavlink's ``x25crc``: polynomial 0x1021 reflected,
    initial 0xFFFF), in C: a reflected CRC is the bit-reversed MSB-first CRC (``binascii.crc_hqx``,
    the same polynomial) of the bit-reversed bytes from the bit-reversed initial value. pymavlink's
    own falls back to a slow Python loop over the bytes without the ``fastcrc`` wheel."""
    return _reflect16(binascii.crc_hqx(data.translate(_REV8), _reflect16(crc)))


@dataclass(frozen=True, slots=True)
class _Layout:
    msg_id: int
    crc_extra: int
    crc_extra_reflected: bytes  # the CRC_EXTRA byte with its bits reversed (see x25crc)
    payload: struct.Struct
    wire_order: Callable[[Sequence[Any]], Any]  # constructor-order values -> wire order
    arrays: tuple[int, ...]  # positions (wire order) of numeric arrays, flattened into the payload
    n_args: int
    n_required: int  # the fields before the constructor's defaults (MAVLink 2 extension fields)
    defaults: tuple[Any, ...]  # every field's default, for the values not given


def _layout(cls: Any) -> _Layout:
    index = {name: i for i, name in enumerate(cls.fieldnames)}
    order = [index[name] for name in cls.ordered_fieldnames]
    arrays = tuple(
        k
        for k, (name, n) in enumerate(zip(cls.ordered_fieldnames, cls.array_lengths, strict=True))
        if n and cls.fieldtypes[index[name]] != "char"  # char arrays are one 's' item
    )
    getter = operator.itemgetter(*order)
    wire = getter if len(order) > 1 else (lambda args: (getter(args),))
    params = list(inspect.signature(cls.__init__).parameters.values())[1:]  # after self
    if [p.name for p in params] != list(cls.fieldnames):
        raise TypeError(f"{cls.msgname}: constructor arguments are not its fields")
    defaults = tuple(p.default for p in params)
    n_required = sum(1 for p in params if p.default is inspect.Parameter.empty)
    extra = bytes((_REV8[cls.crc_extra],))
    return _Layout(cls.id, cls.crc_extra, extra, cls.unpacker, wire, arrays, len(order), n_required, defaults)


class DirectPacker:
    """MAVLink 2 packets from a pymavlink message class and its field values in the constructor's
    order, without building the message object: the same bytes as :class:`MavlinkPacker` (payload
    trailing zeros stripped to at least one byte, one sequence counter per source, CRC with the
    message's CRC_EXTRA; tested against it), at a fifth of its cost. Unsigned packets only. Not
    thread-safe: one thread packs."""

    def __init__(self) -> None:
        self._seq: dict[tuple[int, int], int] = {}
        self._layouts: dict[Any, _Layout] = {}

    def next_seq(self, source: tuple[int, int]) -> int:
        """The sequence number of the source's next packet (0 first, wrapping after 255)."""
        seq = self._seq.get(source, 0)
        self._seq[source] = (seq + 1) & 0xFF
        return seq

    def pack(self, cls: Any, args: Sequence[Any], system_id: int, component_id: int) -> bytes:
        lay = self._layouts.get(cls)
        if lay is None:
            lay = self._layouts[cls] = _layout(cls)
        if len(args) != lay.n_args:
            if not lay.n_required <= len(args) <= lay.n_args:
                raise TypeError(f"{cls.msgname}: {len(args)} values for {lay.n_required}..{lay.n_args} fields")
            args = (*args, *lay.defaults[len(args) :])  # the extension fields' defaults, as the constructor
        vals = lay.wire_order(args)
        if lay.arrays:
            flat: list[Any] = []
            for k, v in enumerate(vals):
                if k in lay.arrays:
                    flat.extend(v)
                else:
                    flat.append(v)
            vals = flat
        payload = lay.payload.pack(*vals).rstrip(b"\0") or b"\0"  # MAVLink 2: trailing zeros go, one byte stays
        seq = self.next_seq((system_id, component_id))
        mid = lay.msg_id
        frame = _HEADER_V2.pack(0xFD, len(payload), 0, 0, seq, system_id, component_id, mid & 0xFFFF, mid >> 16)
        frame += payload
        # x25crc(CRC_EXTRA, x25crc(frame[1:])) in one pass: the bit-reversed CRC of the bit-reversed
        # bytes from 0xFFFF (its own reflection), then the result reflected back
        c = crc_hqx(lay.crc_extra_reflected, crc_hqx(frame[1:].translate(_REV8), 0xFFFF))
        return frame + _CRC.pack((_REV8[c & 0xFF] << 8) | _REV8[c >> 8])

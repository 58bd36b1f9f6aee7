"""The sim vehicle's parameter server: PARAM_REQUEST_LIST, PARAM_REQUEST_READ, PARAM_SET and
PARAM_VALUE, with integer parameters typed and sent as the firmware does."""

from __future__ import annotations

import math
import os
import struct
from typing import Any, ClassVar

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion_sitl.mavlink.link import MavlinkLink


def _param_id(m: Any) -> str:
    pid = m.param_id if isinstance(m.param_id, str) else m.param_id.decode(errors="replace")
    return str(pid.rstrip("\x00"))


class ParameterServer(MavlinkLink):
    """The parameters (name -> value, in the order they are listed) and the PARAM_* messages."""

    # parameters the firmware types as integers (the rest are REAL32), and how it sends them:
    # byte-wise in the float field (PX4) or cast to a float (ArduPilot)
    INT_PARAMS: ClassVar[frozenset[str]] = frozenset()
    PARAM_BYTEWISE: ClassVar[bool] = False
    _params: dict[str, float]

    def _param_request_list(self) -> None:
        names = list(self._params)
        for i, name in enumerate(names):
            self._param_value(name, i)

    def _param_request_read(self, m: Any) -> None:
        names = list(self._params)
        pid = _param_id(m)
        if m.param_index >= 0 and m.param_index < len(names):
            self._param_value(names[m.param_index], m.param_index)
        elif pid in self._params:
            self._param_value(pid, names.index(pid))

    def _param_set(self, m: Any) -> None:
        pid = _param_id(m)
        value = self.param_decode(pid, m.param_value)
        if math.isfinite(value):
            self._params[pid] = value
        self._param_value(pid, list(self._params).index(pid) if pid in self._params else 65535)

    def _param_value(self, name: str, index: int) -> None:
        self._send(self.param_value_message(name, index))

    def param_value_message(self, name: str, index: int) -> Any:
        """The PARAM_VALUE the vehicle answers with for ``name`` at ``index`` (PX4's integers
        byte-wise in the float, ArduPilot's cast to it); built, not sent."""
        val = self._params.get(name, math.nan)
        ptype = mavlink.MAV_PARAM_TYPE_REAL32
        if name in self.INT_PARAMS and math.isfinite(val):
            ptype = mavlink.MAV_PARAM_TYPE_INT32
            if self.PARAM_BYTEWISE:  # the int32's bytes in the float field
                val = struct.unpack("<f", struct.pack("<i", int(val)))[0]
        return self._enc.param_value_encode(name.encode()[:16], val, ptype, len(self._params), index)

    def param_decode(self, name: str, value: float) -> float:
        """A PARAM_SET value as the firmware reads it (byte-wise int32 for PX4's integers)."""
        if name in self.INT_PARAMS and self.PARAM_BYTEWISE:
            return float(struct.unpack("<i", struct.pack("<f", value))[0])
        return float(value)

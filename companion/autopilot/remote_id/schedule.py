"""When each Remote ID message is due (docs/remote-id.md): the static ones (BASIC_ID, SELF_ID,
OPERATOR_ID, SYSTEM) every ``1 / static_rate_hz``, SYSTEM_UPDATE every ``1 /
system_update_rate_hz``. Pure: the caller gives the clock, home and the wall time, and sends
what :meth:`RemoteIdSchedule.due` returns."""

from __future__ import annotations

import math
from typing import Any

from companion.autopilot.remote_id.messages import OdidMessage, operator_location, static_messages, system_update
from companion.config import RemoteIdConfig

_LOCATION = ("OPEN_DRONE_ID_SYSTEM", "OPEN_DRONE_ID_SYSTEM_UPDATE")


class RemoteIdSchedule:
    def __init__(self, cfg: RemoteIdConfig, target_system: int):
        self.cfg = cfg
        self.target_system = target_system
        self._next_static = -math.inf
        self._next_update = -math.inf

    def due(self, now_s: float, unix_s: float, home: Any | None) -> list[OdidMessage]:
        """The messages due at ``now_s`` (monotonic s), their time ``unix_s``; ``home``: the
        autopilot's home position or None."""
        out: list[OdidMessage] = []
        if now_s >= self._next_static:
            self._next_static = now_s + 1.0 / self.cfg.static_rate_hz
            out = static_messages(self.cfg, home, unix_s, self.target_system)
        elif self.cfg.system_update_rate_hz > 0 and now_s >= self._next_update:
            where = operator_location(self.cfg, home)
            if where is not None:
                out.append(system_update(where, unix_s, self.target_system))
        if self.cfg.system_update_rate_hz > 0 and any(m.name in _LOCATION for m in out):
            # a SYSTEM carries the location too: the next update one period after it
            self._next_update = now_s + 1.0 / self.cfg.system_update_rate_hz
        return out

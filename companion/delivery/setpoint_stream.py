"""The setpoint stream and its watchdog.

Each guidance tick sends the setpoint it computed at once (:meth:`SetpointStream.send`). The
stream (:meth:`SetpointStream.run`, its own task), half a period out of phase with guidance, only
resends the latest setpoint when guidance has sent none for a stream period (guidance slower than
the stream, or a late tick), and it is the watchdog: if guidance stops refreshing the setpoint,
streaming stops, so the autopilot's own offboard-loss failsafe fires (a stale setpoint must never
be resent forever, cf. MAVSDK-Python issue 374).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable
from typing import Protocol

from companion.autopilot.interface import Autopilot
from companion.config import CompanionConfig
from companion.delivery.hooks import ShellHooks
from companion.delivery.observers import ShellObserver
from companion.delivery.shell_stats import ShellStats
from companion.guidance.setpoint import VelocitySetpoint
from companion.scheduling import LoopClock

log = logging.getLogger(__name__)


class Owner(Protocol):
    """What the stream reads of the shell: its configuration (``[runtime]``), when it starts."""

    config: CompanionConfig


class SetpointStream:
    def __init__(
        self,
        owner: Owner,
        autopilot: Autopilot,
        clock: LoopClock,
        stats: ShellStats,
        hooks: ShellHooks,
        watching: Callable[[], list[ShellObserver]],
    ):
        self.owner = owner
        self.autopilot = autopilot
        self.clock = clock
        self.stats = stats
        self.hooks = hooks
        self.watching = watching
        # the newest setpoint guidance computed and when (None: none to stream, on purpose)
        self.latest: tuple[float, VelocitySetpoint] | None = None
        self._last_sent_s = -math.inf  # when a setpoint last went to the autopilot
        self._streaming = False

    def send(self, now: float, sp: VelocitySetpoint) -> None:
        """``sp`` to the autopilot now, and to the observers."""
        self.autopilot.set_velocity_ned(sp)
        self.stats.setpoints_sent += 1
        self._last_sent_s = now
        for ob in self.watching():
            ob.on_setpoint(now, sp)
        self._streaming = True

    async def run(self) -> None:
        """The stream's task, until cancelled."""
        rt = self.owner.config.runtime
        period = 1.0 / rt.setpoint_rate_hz
        # half a period after the guidance ticks (same rate by default): a resend is decided on a
        # clock instant guidance never ticks on, so the order of two tasks due at once plays no part
        rate = self.hooks.rate_loop(self.clock, rt.setpoint_rate_hz, start_s=self.clock.now() + period / 2.0)
        while True:
            now = await rate.tick()
            self.stats.setpoint_overruns = rate.overruns
            sp = self.latest
            if sp is not None and now - sp[0] <= rt.setpoint_stale_s:
                # guidance sends every setpoint it computes; resend only what a stream period
                # without a send would otherwise leave the autopilot without
                if now - self._last_sent_s >= period * (1.0 - 1e-9):
                    self.send(now, sp[1])
            elif self._streaming:
                self._streaming = False
                if sp is not None:  # stale, not merely finished
                    self.stats.stream_stops += 1
                    log.error(
                        "setpoint is %.2f s old: control task stalled, setpoint stream stopped "
                        "so the autopilot's failsafe acts",
                        now - sp[0],
                    )

"""How a bench or a test instruments the Dart shell without changing its flight:
:class:`DartHooks`, whose every field defaults to what a flight uses.

- ``stage_timer``: ``(stage, fn) -> fn``, applied once where the shell binds a stage (never per
  call): ``"imu"`` (the autopilot's IMU samples queued, the estimator's IMU update),
  ``"detect"`` (the pad detector, on the vision thread), ``"vision"`` (the estimator's marker
  update), ``"control"`` (the control step), ``"commands"`` (a command built and mixed),
  ``"rc_override"`` / ``"attitude"`` (the RC override or the attitude setpoint handed to the
  backend), ``"logging"`` (a CSV row written). None (a flight): nothing is wrapped, nothing costs.
- ``rate_loop``: how the shell builds its fixed-rate loops (IMU, control, commands, log).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

from companion.scheduling import RateLoop, RateLoopFactory, StageTimer, timed

F = TypeVar("F", bound=Callable[..., Any])

DART_STAGES = ("imu", "detect", "vision", "control", "commands", "rc_override", "attitude", "logging")


@dataclass(frozen=True)
class DartHooks:
    stage_timer: StageTimer | None = None
    rate_loop: RateLoopFactory = RateLoop

    def timed(self, stage: str, fn: F) -> F:
        """``fn`` timed as ``stage`` when a stage timer is set, else ``fn`` itself."""
        assert stage in DART_STAGES, stage
        return timed(self.stage_timer, stage, fn)


__all__ = ["DART_STAGES", "DartHooks"]

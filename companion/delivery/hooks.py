"""How a bench or a test instruments the delivery shell without changing its flight:
:class:`ShellHooks`, whose every field defaults to what a flight uses.

- ``stage_timer``: a function ``(stage, fn) -> fn`` the shell wraps its own named stages with,
  once, where it binds them (never per call): ``"guidance"`` (the pose estimator's update and the
  mission's step), and its own observers by job: ``"logging"`` (flight log, recorder),
  ``"telemetry"`` (the Zenoh publisher's tick), ``"gcs"`` (the operator's GCS component). None
  (a flight): nothing is wrapped, nothing costs.
- ``rate_loop``: how the shell builds its fixed-rate loops (guidance, setpoint stream, the landing
  sensors' polls): a factory with :class:`~companion.scheduling.RateLoop`'s arguments, so a bench
  can read every loop's ticks and overruns.
- ``fusion``: how the shell builds its landing fusion, ``(FusionSetup, start time) -> fusion``.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, TypeVar

from companion.delivery.fusion import FusionSetup, LandingFusion
from companion.delivery.gonogo import GoNoGoVerdict
from companion.delivery.mission import RequestResult
from companion.delivery.observers import DeliveryShell, ShellObserver, ShellTick
from companion.events import MissionEvent
from companion.guidance.setpoint import VelocitySetpoint
from companion.scheduling import RateLoop, RateLoopFactory, StageTimer, timed, untimed
from companion.uwb.measurements import UwbFix

F = TypeVar("F", bound=Callable[..., Any])

FusionFactory = Callable[[FusionSetup, float], Any]

# (StageTimer, RateLoopFactory and untimed live in companion.scheduling, shared with the Dart shell)
__all__ = ["FusionFactory", "RateLoopFactory", "ShellHooks", "StageTimer", "TimedObserver", "untimed"]


@dataclass(frozen=True)
class ShellHooks:
    stage_timer: StageTimer | None = None
    rate_loop: RateLoopFactory = RateLoop
    fusion: FusionFactory = LandingFusion

    def timed(self, stage: str, fn: F) -> F:
        """``fn`` timed as ``stage`` when a stage timer is set, else ``fn`` itself."""
        return timed(self.stage_timer, stage, fn)


class TimedObserver(ShellObserver):
    """One of the shell's own observers with the hooks it implements timed as ``stage`` (the
    hooks it leaves to the base class are called untimed: nothing to time)."""

    def __init__(self, inner: ShellObserver, stage: str, timer: StageTimer):
        self.inner = inner

        def hook(name: str) -> Callable[..., Any]:
            fn = getattr(inner, name)
            return fn if getattr(type(inner), name) is getattr(ShellObserver, name) else timer(stage, fn)

        self._start, self._events, self._tick = hook("on_start"), hook("on_events"), hook("on_tick")
        self._setpoint, self._marker, self._fused = hook("on_setpoint"), hook("on_marker"), hook("on_marker_fused")
        self._uwb, self._result, self._command = hook("on_uwb"), hook("on_result"), hook("on_command")
        self._abort, self._go, self._text = hook("on_abort"), hook("on_go_no_go"), hook("on_text")

    def on_start(self, shell: DeliveryShell) -> None:
        self._start(shell)

    def on_events(self, time_s: float, events: tuple[MissionEvent, ...]) -> None:
        self._events(time_s, events)

    def on_tick(self, tick: ShellTick) -> None:
        self._tick(tick)

    def on_setpoint(self, time_s: float, setpoint: VelocitySetpoint) -> None:
        self._setpoint(time_s, setpoint)

    def on_marker(self, time_s: float, obs: Any, image: Any) -> None:
        self._marker(time_s, obs, image)

    def on_marker_fused(self, time_s: float, obs: Any, outcome: Any) -> None:
        self._fused(time_s, obs, outcome)

    def on_uwb(self, time_s: float, fix: UwbFix) -> None:
        self._uwb(time_s, fix)

    def on_result(self, time_s: float, kind: str, result: RequestResult) -> None:
        self._result(time_s, kind, result)

    def on_command(self, time_s: float, kind: str, sender: str, reply: str) -> None:
        self._command(time_s, kind, sender, reply)

    def on_abort(self, time_s: float, reason: str) -> None:
        self._abort(time_s, reason)

    def on_go_no_go(self, time_s: float, verdict: GoNoGoVerdict, detail: str) -> None:
        self._go(time_s, verdict, detail)

    def on_text(self, text: str, severity: int) -> None:
        self._text(text, severity)

    async def close(self, shell: DeliveryShell) -> None:
        await self.inner.close(shell)

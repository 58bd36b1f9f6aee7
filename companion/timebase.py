"""The vehicle's time for signed ground requests: Unix time that a clock step cannot move.

Freshness of a ground command or order is judged against :class:`VehicleClock`: the wall clock
read once (at start, and again each time the pre-flight check finds it agreeing with the
autopilot's UTC) and carried forward on the monotonic clock. A wall clock stepped after that (NTP,
an operator, an attacker with a shell) changes nothing the request checks see; the step is
measured and logged. :class:`ClockVerdict` is the pre-flight clock check's verdict, and decides
whether signed requests are accepted at all (docs/orders.md#clocks).
"""

from __future__ import annotations

import enum
import logging
import threading
import time
from collections.abc import Callable

log = logging.getLogger(__name__)


class ClockVerdict(enum.Enum):
    """The pre-flight check of the companion's wall clock against the autopilot's UTC."""

    AGREES = "agrees"  # within the tolerance: the clock is re-anchored here
    OFF = "off"  # beyond the tolerance: signed requests are refused until a check agrees
    UNKNOWN = "unknown"  # no UTC from the autopilot: the anchored clock is kept, a warning logged
    NOT_CHECKED = "not_checked"  # no pre-flight check has run (--no-preflight, before the first)

    @property
    def accepts_signed_requests(self) -> bool:
        return self is not ClockVerdict.OFF


class VehicleClock:
    """Unix seconds as ``wall`` said at the last anchor plus ``monotonic`` time since. Thread-safe."""

    def __init__(self, wall: Callable[[], float] = time.time, monotonic: Callable[[], float] = time.monotonic) -> None:
        self._wall = wall
        self._mono = monotonic
        self._lock = threading.Lock()
        self._anchor_wall = wall()
        self._anchor_mono = monotonic()
        self.verdict = ClockVerdict.NOT_CHECKED
        self.offset_s: float | None = None  # the autopilot's UTC minus the wall clock, at the check

    def monotonic(self) -> float:
        return self._mono()

    def now(self) -> float:
        """The vehicle's Unix time: immune to wall-clock steps since the last anchor."""
        with self._lock:
            return self._anchor_wall + (self._mono() - self._anchor_mono)

    def step_s(self) -> float:
        """How far the wall clock has moved from :meth:`now` (a step, or drift) since the anchor."""
        wall = self._wall()
        return wall - self.now()

    def judge(self, verdict: ClockVerdict, offset_s: float | None = None) -> float:
        """Record the pre-flight verdict; AGREES re-anchors on the wall clock (checked good now).
        Returns how far the vehicle time moved (seconds; 0 unless re-anchored)."""
        with self._lock:
            self.verdict = verdict
            self.offset_s = offset_s
            if verdict is not ClockVerdict.AGREES:
                moved = 0.0
            else:
                wall, mono = self._wall(), self._mono()
                moved = wall - (self._anchor_wall + (mono - self._anchor_mono))
                self._anchor_wall, self._anchor_mono = wall, mono
        level = logging.INFO if verdict.accepts_signed_requests else logging.ERROR
        log.log(level, "vehicle clock: pre-flight verdict %s (offset %s s)", verdict.value, offset_s)
        return moved


_process_clock: VehicleClock | None = None
_process_lock = threading.Lock()


def vehicle_clock() -> VehicleClock:
    """The process's vehicle clock (one per companion process: the pre-flight check judges it)."""
    global _process_clock
    with _process_lock:
        if _process_clock is None:
            _process_clock = VehicleClock()
        return _process_clock

"""The landing camera's detections paced to a share of one core (``runtime.vision_cpu_budget``).

On a board whose core is several times slower than a server's (docs/cpu-budget.md), the detector
on every frame at 30 fps takes more CPU than the whole application may have, and the guidance and
setpoint stream starve with it. Given a budget (a fraction of one core), each detection's own CPU
time sets the earliest start of the next: a detection that took ``c`` seconds of CPU is followed by
the next no sooner than ``c / budget`` seconds after it began, so the detector's share stays within
the budget whatever the frame rate and the machine. The frames in between are not read (the camera
hands over its newest frame at the next read). The cost is smoothed over a few detections, so a
single slow frame does not stop the camera for long.
"""

from __future__ import annotations

import math


class DetectionPacer:
    """Whether a detection is due, from the CPU time the last ones took and a share of one core."""

    def __init__(self, budget_core: float, smoothing: float = 0.3) -> None:
        if not (math.isfinite(budget_core) and budget_core > 0.0):
            raise ValueError(f"vision CPU budget {budget_core!r}: must be a positive share of one core")
        if not 0.0 < smoothing <= 1.0:
            raise ValueError(f"smoothing {smoothing!r}: must be in (0, 1]")
        self.budget_core = budget_core
        self.smoothing = smoothing
        self.cost_s: float | None = None  # smoothed CPU seconds per detection
        self._next_s = -math.inf
        self.detections = 0
        self.skipped = 0

    def due(self, now_s: float) -> bool:
        """A detection may start now (counts a skip when not)."""
        if now_s >= self._next_s:
            return True
        self.skipped += 1
        return False

    def done(self, start_s: float, cpu_s: float) -> None:
        """A detection that began at ``start_s`` (the clock of :meth:`due`) took ``cpu_s`` of CPU."""
        cpu_s = max(0.0, cpu_s)
        self.cost_s = cpu_s if self.cost_s is None else self.cost_s + self.smoothing * (cpu_s - self.cost_s)
        self.detections += 1
        self._next_s = start_s + self.cost_s / self.budget_core

    @property
    def rate_hz(self) -> float:
        """The detection rate the budget allows at the current cost (inf before the first)."""
        return math.inf if not self.cost_s else self.budget_core / self.cost_s

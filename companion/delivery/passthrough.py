"""GPS-only baseline: the autopilot's own fused pose (delivery 4.2, "DJI-SDK pose")."""

from __future__ import annotations

from companion.autopilot.types import Attitude, PositionNed
from companion.estimation.types import StateEstimate


class AutopilotPoseEstimator:
    """Turns the autopilot's local position and attitude into a :class:`StateEstimate`.

    Pure and synchronous: the shell feeds it the newest samples, it returns the estimate (or
    ``None`` until both a position and an attitude have been seen).
    """

    def __init__(self) -> None:
        self._last: StateEstimate | None = None

    def update(self, position: PositionNed | None, attitude: Attitude | None) -> StateEstimate | None:
        if position is None or attitude is None:
            return self._last
        if self._last is not None and position.time_s <= self._last.time_s:
            return self._last
        self._last = StateEstimate(
            time_s=position.time_s,
            north_m=position.north_m,
            east_m=position.east_m,
            down_m=position.down_m,
            north_m_s=position.north_m_s,
            east_m_s=position.east_m_s,
            down_m_s=position.down_m_s,
            roll_rad=attitude.roll_rad,
            pitch_rad=attitude.pitch_rad,
            yaw_rad=attitude.yaw_rad,
            source="autopilot",
        )
        return self._last

"""Messages produced by estimation."""

from __future__ import annotations

from dataclasses import dataclass, replace


@dataclass(frozen=True, slots=True)
class StateEstimate:
    """The vehicle state the guidance uses, in world NED (metres, radians).

    ``time_s`` is the time the estimate is valid at. ``gps_bias_ned_m`` is the estimated
    GPS bias relative to the pad (delivery eq 10), zero when no local sensor has been fused.
    """

    time_s: float
    north_m: float
    east_m: float
    down_m: float
    north_m_s: float
    east_m_s: float
    down_m_s: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    source: str = "autopilot"
    gps_bias_north_m: float = 0.0
    gps_bias_east_m: float = 0.0
    gps_bias_down_m: float = 0.0

    @property
    def position_ned(self) -> tuple[float, float, float]:
        return (self.north_m, self.east_m, self.down_m)

    @property
    def velocity_ned(self) -> tuple[float, float, float]:
        return (self.north_m_s, self.east_m_s, self.down_m_s)

    def predicted(self, time_s: float, max_s: float) -> StateEstimate:
        """The estimate carried forward to ``time_s`` at its own velocity (constant-velocity
        prediction, as an autopilot's output predictor does between its fusion steps): guidance
        ticks between the autopilot's samples, and at 5-10 Hz streams a 0.1-0.2 s old position
        flown as the present one puts the landing loop that far behind the vehicle.

        Unchanged when ``time_s`` is not after ``time_s`` of the estimate or more than ``max_s``
        after it: an estimate that old keeps its own time, so its staleness stays visible to
        whoever checks it (the mission's ``estimate_timeout_s``). ``max_s = 0`` turns it off.
        """
        dt = time_s - self.time_s
        if not 0.0 < dt <= max_s:
            return self
        return replace(
            self,
            time_s=time_s,
            north_m=self.north_m + self.north_m_s * dt,
            east_m=self.east_m + self.east_m_s * dt,
            down_m=self.down_m + self.down_m_s * dt,
        )

"""Messages produced by estimation."""

from __future__ import annotations

from dataclasses import dataclass


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

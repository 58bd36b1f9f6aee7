"""Typed telemetry samples and commands exchanged with an autopilot.

Every sample carries ``time_s``: when it was *measured*, on the shell's monotonic clock.
Units and frames are in the field names (MAVSDK style).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, fields


class FlightMode(enum.Enum):
    UNKNOWN = "unknown"
    MANUAL = "manual"
    POSITION = "position"  # pilot position control (PX4 POSCTL, ArduPilot LOITER)
    HOLD = "hold"  # autopilot holds position (PX4 AUTO.LOITER, ArduPilot BRAKE/LOITER)
    TAKEOFF = "takeoff"
    LAND = "land"
    RTL = "rtl"
    MISSION = "mission"
    OFFBOARD = "offboard"  # companion control (PX4 OFFBOARD, ArduPilot GUIDED)


class LandedState(enum.Enum):
    UNKNOWN = "unknown"
    ON_GROUND = "on_ground"
    TAKING_OFF = "taking_off"
    IN_AIR = "in_air"
    LANDING = "landing"


def _check_finite(sample: object) -> None:
    for f in fields(sample):  # type: ignore[arg-type]
        v = getattr(sample, f.name)
        if isinstance(v, float) and not math.isfinite(v):
            raise ValueError(f"{type(sample).__name__}.{f.name} is not finite ({v})")


@dataclass(frozen=True, slots=True)
class PositionNed:
    """The autopilot's own local position estimate (MAVLink LOCAL_POSITION_NED)."""

    time_s: float
    north_m: float
    east_m: float
    down_m: float
    north_m_s: float
    east_m_s: float
    down_m_s: float

    def validate(self) -> PositionNed:
        _check_finite(self)
        return self


@dataclass(frozen=True, slots=True)
class GlobalPosition:
    """The autopilot's fused global position (MAVLink GLOBAL_POSITION_INT)."""

    time_s: float
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    alt_rel_m: float

    def validate(self) -> GlobalPosition:
        _check_finite(self)
        return self


@dataclass(frozen=True, slots=True)
class Attitude:
    time_s: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    rollspeed_rad_s: float
    pitchspeed_rad_s: float
    yawspeed_rad_s: float

    def validate(self) -> Attitude:
        _check_finite(self)
        return self


@dataclass(frozen=True, slots=True)
class Imu:
    """Body-frame (FRD) specific force and angular rate (MAVLink HIGHRES_IMU)."""

    time_s: float
    accel_x_m_s2: float
    accel_y_m_s2: float
    accel_z_m_s2: float
    gyro_x_rad_s: float
    gyro_y_rad_s: float
    gyro_z_rad_s: float

    def validate(self) -> Imu:
        _check_finite(self)
        return self


@dataclass(frozen=True, slots=True)
class GpsRaw:
    time_s: float
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    fix_type: int  # 0-1 no fix, 2 2D, 3 3D, 4 DGPS, 5 RTK float, 6 RTK fixed
    satellites: int
    eph_m: float

    def validate(self) -> GpsRaw:
        _check_finite(self)
        return self


@dataclass(frozen=True, slots=True)
class VehicleStatus:
    time_s: float
    armed: bool
    mode: FlightMode
    landed: LandedState
    healthy: bool  # armable: estimator and GPS ready, home set
    battery_pct: float
    payload_released: bool

    def validate(self) -> VehicleStatus:
        _check_finite(self)
        return self


@dataclass(frozen=True, slots=True)
class HomePosition:
    time_s: float
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float

    def validate(self) -> HomePosition:
        _check_finite(self)
        return self


@dataclass(frozen=True, slots=True)
class StatusText:
    time_s: float
    severity: int
    text: str


TelemetrySample = PositionNed | GlobalPosition | Attitude | Imu | GpsRaw | VehicleStatus | HomePosition | StatusText


@dataclass(frozen=True, slots=True)
class VelocitySetpoint:
    """Offboard velocity setpoint in local NED with an absolute NED yaw."""

    north_m_s: float
    east_m_s: float
    down_m_s: float
    yaw_rad: float

"""Typed telemetry samples and commands exchanged with an autopilot.

Every sample carries ``time_s``: when it was *measured*, on the shell's monotonic clock.
Units and frames are in the field names (MAVSDK style).
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass, fields
from typing import Self


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


class _Finite:
    """Mixin: ``validate()`` raises ValueError naming the first non-finite float field."""

    __slots__ = ()

    def validate(self) -> Self:
        cls = type(self)
        names = _FIELD_NAMES.get(cls)
        if names is None:  # the dataclass's fields, in order, looked up once per class
            names = _FIELD_NAMES[cls] = tuple(f.name for f in fields(self))  # type: ignore[arg-type]
        for name in names:
            v = getattr(self, name)
            if isinstance(v, float) and not math.isfinite(v):
                raise ValueError(f"{cls.__name__}.{name} is not finite ({v})")
        return self


_FIELD_NAMES: dict[type, tuple[str, ...]] = {}


@dataclass(frozen=True, slots=True)
class PositionNed(_Finite):
    """The autopilot's own local position estimate (MAVLink LOCAL_POSITION_NED)."""

    time_s: float
    north_m: float
    east_m: float
    down_m: float
    north_m_s: float
    east_m_s: float
    down_m_s: float


@dataclass(frozen=True, slots=True)
class GlobalPosition(_Finite):
    """The autopilot's fused global position (MAVLink GLOBAL_POSITION_INT)."""

    time_s: float
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    alt_rel_m: float


@dataclass(frozen=True, slots=True)
class Attitude(_Finite):
    time_s: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    rollspeed_rad_s: float
    pitchspeed_rad_s: float
    yawspeed_rad_s: float


@dataclass(frozen=True, slots=True)
class Imu(_Finite):
    """Body-frame (FRD) specific force and angular rate (MAVLink HIGHRES_IMU)."""

    time_s: float
    accel_x_m_s2: float
    accel_y_m_s2: float
    accel_z_m_s2: float
    gyro_x_rad_s: float
    gyro_y_rad_s: float
    gyro_z_rad_s: float


@dataclass(frozen=True, slots=True)
class GpsRaw(_Finite):
    time_s: float
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    fix_type: int  # 0-1 no fix, 2 2D, 3 3D, 4 DGPS, 5 RTK float, 6 RTK fixed
    satellites: int
    eph_m: float


@dataclass(frozen=True, slots=True)
class VehicleStatus(_Finite):
    time_s: float
    armed: bool
    mode: FlightMode
    landed: LandedState
    healthy: bool  # armable: estimator and GPS ready, home set
    battery_pct: float
    payload_released: bool


@dataclass(frozen=True, slots=True)
class Wind(_Finite):
    """The autopilot's wind estimate: the air's velocity over the ground (where it blows to), NED."""

    time_s: float
    north_m_s: float
    east_m_s: float

    @property
    def speed_m_s(self) -> float:
        return math.hypot(self.north_m_s, self.east_m_s)


#: MAV_SENSOR_ORIENTATION of a rangefinder looking down (ArduPilot RNGFND1_ORIENT = 25, PX4 SIH's)
MAV_SENSOR_ROTATION_PITCH_270 = 25


@dataclass(frozen=True, slots=True)
class RangefinderReading(_Finite):
    """One DISTANCE_SENSOR: the range the sensor measured along its axis (m, not tilt-corrected),
    the range it can measure (a reading outside it is no measurement), its orientation
    (MAV_SENSOR_ORIENTATION; only MAV_SENSOR_ROTATION_PITCH_270, downward, is a height) and its
    signal quality (1-100 %; None: not reported, MAVLink's 0)."""

    time_s: float
    distance_m: float
    min_distance_m: float
    max_distance_m: float
    orientation: int = MAV_SENSOR_ROTATION_PITCH_270
    signal_quality_pct: int | None = None

    @property
    def downward(self) -> bool:
        return self.orientation == MAV_SENSOR_ROTATION_PITCH_270


@dataclass(frozen=True, slots=True)
class HomePosition(_Finite):
    """Home as the autopilot reports it (MAVLink HOME_POSITION): geodetic, and where it lies in
    the autopilot's local NED frame, whose origin (the EKF origin) need not be home (PX4 may put
    home metres from its local origin on a fresh start)."""

    time_s: float
    lat_deg: float
    lon_deg: float
    alt_amsl_m: float
    north_m: float = 0.0
    east_m: float = 0.0
    down_m: float = 0.0


@dataclass(frozen=True, slots=True)
class StatusText:
    time_s: float
    severity: int
    text: str


TelemetrySample = PositionNed | GlobalPosition | Attitude | Imu | GpsRaw | VehicleStatus | HomePosition | StatusText


@dataclass(frozen=True, slots=True)
class LandingTarget:
    """LANDING_TARGET (MAVLink #149) contents, see :mod:`companion.autopilot.landing_target`.

    ``time_s``: the exposure time on the loop clock. Angles (rad) and distance (m) of the pad's
    centre as ArduPilot reads them; ``north_m``/``east_m``/``down_m`` the pad in the autopilot's
    local NED frame, meaningful only when ``position_valid`` (MAV_FRAME_LOCAL_NED, as PX4 reads it).
    """

    time_s: float
    angle_x_rad: float
    angle_y_rad: float
    distance_m: float
    size_x_rad: float
    size_y_rad: float
    north_m: float
    east_m: float
    down_m: float
    position_valid: bool

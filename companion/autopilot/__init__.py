"""Autopilot interface, telemetry types, the MAVSDK (PX4) and pymavlink (ArduPilot) backends and MAVLink codecs."""

from companion.autopilot.interface import Autopilot, AutopilotError, CommandRejected, TelemetryCache
from companion.autopilot.types import (
    Attitude,
    FlightMode,
    GlobalPosition,
    GpsRaw,
    HomePosition,
    Imu,
    LandedState,
    PositionNed,
    StatusText,
    TelemetrySample,
    VehicleStatus,
)

__all__ = [
    "Attitude",
    "Autopilot",
    "AutopilotError",
    "CommandRejected",
    "FlightMode",
    "GlobalPosition",
    "GpsRaw",
    "HomePosition",
    "Imu",
    "LandedState",
    "PositionNed",
    "StatusText",
    "TelemetryCache",
    "TelemetrySample",
    "VehicleStatus",
]

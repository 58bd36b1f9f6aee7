"""Autopilot interface, telemetry types and (later) the MAVSDK and pymavlink backends."""

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
    VelocitySetpoint,
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
    "VelocitySetpoint",
]

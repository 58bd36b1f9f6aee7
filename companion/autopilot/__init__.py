"""Autopilot interface, telemetry types, the MAVSDK (PX4) and pymavlink (ArduPilot) backends and MAVLink codecs."""

from companion.autopilot.interface import (
    Autopilot,
    AutopilotError,
    AutopilotUnreachable,
    CommandRejected,
    ConnectionUrlError,
    LinkDeviceMissing,
    TelemetryCache,
)
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
    "AutopilotUnreachable",
    "CommandRejected",
    "ConnectionUrlError",
    "FlightMode",
    "GlobalPosition",
    "GpsRaw",
    "HomePosition",
    "Imu",
    "LandedState",
    "LinkDeviceMissing",
    "PositionNed",
    "StatusText",
    "TelemetryCache",
    "TelemetrySample",
    "VehicleStatus",
]

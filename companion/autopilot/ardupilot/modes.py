"""ArduCopter's flight modes (HEARTBEAT custom_mode numbers) and landed states, and what they
mean to the shell (:class:`~companion.autopilot.types.FlightMode`, :class:`LandedState`)."""

from __future__ import annotations

from companion.autopilot.types import FlightMode, LandedState

COPTER_MODES: dict[str, int] = {
    "STABILIZE": 0,
    "ACRO": 1,
    "ALT_HOLD": 2,
    "AUTO": 3,
    "GUIDED": 4,
    "LOITER": 5,
    "RTL": 6,
    "CIRCLE": 7,
    "LAND": 9,
    "DRIFT": 11,
    "SPORT": 13,
    "POSHOLD": 16,
    "BRAKE": 17,
    "SMART_RTL": 21,
}

COPTER_TO_FLIGHT_MODE: dict[int, FlightMode] = {
    0: FlightMode.MANUAL,
    1: FlightMode.MANUAL,
    2: FlightMode.MANUAL,
    3: FlightMode.MISSION,
    4: FlightMode.OFFBOARD,
    5: FlightMode.POSITION,
    6: FlightMode.RTL,
    9: FlightMode.LAND,
    11: FlightMode.MANUAL,
    13: FlightMode.MANUAL,
    16: FlightMode.POSITION,
    17: FlightMode.HOLD,
    21: FlightMode.RTL,
}

LANDED_STATES = {
    1: LandedState.ON_GROUND,
    2: LandedState.IN_AIR,
    3: LandedState.TAKING_OFF,
    4: LandedState.LANDING,
}

"""PX4 backend through MAVSDK 4.x (the native ``mavsdk`` binding; no mavsdk_server).

:mod:`.mavsdk_core` routes MAVSDK's log and intercepts its messages for the MAVLink log,
:mod:`.link` holds the MAVSDK session and its plugins, :mod:`.telemetry` the streams,
:mod:`.requests` the calls, commands, parameters and clock, and :mod:`.autopilot` is
:class:`Px4Autopilot` itself: its configuration, the flight commands and the setpoints.
"""

from companion.autopilot.px4.autopilot import Px4Autopilot

__all__ = ["Px4Autopilot"]

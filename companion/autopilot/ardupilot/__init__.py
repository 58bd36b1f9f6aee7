"""ArduPilot (ArduCopter) backend over pymavlink: UDP, TCP or a serial port.

:mod:`.link` holds the connection and its reader thread, :mod:`.telemetry` decodes what arrives
into samples, :mod:`.requests` sends commands, stream requests, parameter reads and signing keys,
and :mod:`.autopilot` is :class:`ArduPilotAutopilot` itself: its configuration and the flight
commands (GUIDED, arming, takeoff, hold, land, release).
"""

from companion.autopilot.ardupilot.autopilot import ArduPilotAutopilot

__all__ = ["ArduPilotAutopilot"]

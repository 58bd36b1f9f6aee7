"""pymavlink set up for ArduPilot: MAVLink 2 and the ardupilotmega dialect (commands, modes,
gripper actions). Imported before anything else of this package touches pymavlink."""

import os
from typing import Any

os.environ["MAVLINK20"] = "1"  # before mavutil picks its dialect module
from pymavlink import mavutil

mavutil.set_dialect("ardupilotmega")
mavlink: Any = mavutil.mavlink

__all__ = ["mavlink", "mavutil"]

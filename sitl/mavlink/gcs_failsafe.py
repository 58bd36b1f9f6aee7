"""ArduCopter's GCS failsafe for the ArduPilot dialect of the MAVLink sim vehicle.

As ``Copter::failsafe_gcs_check`` (ArduCopter/events.cpp) and ``GCS_MAVLINK::handle_heartbeat``:
the GCS is the system ``MAV_GCS_SYSID`` (255; SYSID_MYGCS before 4.7), seen by its HEARTBEATs (and
RC overrides). With ``FS_GCS_ENABLE`` set, once one has been seen, no heartbeat from it for
``FS_GCS_TIMEOUT`` while armed and flying is the failsafe: it continues a landing and (FS_OPTIONS
bit 4) a pilot-controlled mode, otherwise it switches to the action's mode (5: LAND; 1-4 and 6:
RTL, SmartRTL and DO_LAND_START taken as RTL; 7: BRAKE). FS_OPTIONS bit 5 opens the gripper, as
``do_failsafe_action`` does. A heartbeat again clears it ("GCS Failsafe Cleared"); the mode stays.
"""

from __future__ import annotations

import math
import os
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

COPTER_RTL = 6
COPTER_LAND = 9
COPTER_BRAKE = 17
# modes the pilot flies (Mode::has_manual_throttle or pilot position control), FS_OPTIONS bit 4
PILOT_MODES = frozenset({0, 1, 2, 5, 11, 13, 14, 16})  # STABILIZE ACRO ALT_HOLD LOITER DRIFT SPORT FLIP POSHOLD
FS_OPTION_CONTINUE_PILOT = 16
FS_OPTION_CONTINUE_LANDING = 8
FS_OPTION_RELEASE_GRIPPER = 32
# FS_GCS_ENABLE -> the mode it switches to
_ACTION_MODES = {
    1: COPTER_RTL,
    2: COPTER_RTL,
    3: COPTER_RTL,  # SmartRTL
    4: COPTER_RTL,  # SmartRTL or LAND
    5: COPTER_LAND,
    6: COPTER_RTL,  # DO_LAND_START or RTL
    7: COPTER_BRAKE,
}


class GcsFailsafe:
    """Mixed into :class:`~companion_sitl.mavlink.ardupilot.ArduPilotSimVehicle`."""

    _params: dict[str, float]
    _ap_mode: int
    vehicle: Any
    now: float
    _gcs_seen_s: float = -math.inf
    gcs_failsafe: bool = False  # in force now
    gcs_failsafes = 0  # how many times it fired

    # from the vehicle (later in the MRO): declared for the type checker only
    _statustext: Any
    _set_copter_mode: Any

    def _gcs_sysid(self) -> int:
        return int(self._params.get("MAV_GCS_SYSID", 255.0))

    def _heartbeat_in(self, m: Any) -> None:
        if m.get_srcSystem() == self._gcs_sysid():
            self._gcs_seen_s = self.now

    def _failsafes(self, now: float) -> None:
        enable = int(self._params.get("FS_GCS_ENABLE", 0.0))
        if enable == 0 or self._gcs_seen_s == -math.inf:
            return
        late = now - self._gcs_seen_s > self._params.get("FS_GCS_TIMEOUT", 5.0)
        if not late:
            if self.gcs_failsafe:
                self.gcs_failsafe = False
                self._statustext("GCS Failsafe Cleared", mavlink.MAV_SEVERITY_CRITICAL)
            return
        if self.gcs_failsafe:
            return
        self.gcs_failsafe = True
        v = self.vehicle
        if not v.armed:
            return
        self.gcs_failsafes += 1
        self._statustext("GCS Failsafe", mavlink.MAV_SEVERITY_CRITICAL)
        options = int(self._params.get("FS_OPTIONS", 16.0))
        if self._ap_mode == COPTER_LAND and options & FS_OPTION_CONTINUE_LANDING:
            return
        if self._ap_mode in PILOT_MODES and options & FS_OPTION_CONTINUE_PILOT:
            return
        if options & FS_OPTION_RELEASE_GRIPPER and self._params.get("GRIP_ENABLE", 0.0) >= 0.5:
            v.release_payload()
        mode = _ACTION_MODES.get(enable, COPTER_LAND)
        if mode != self._ap_mode:
            self._set_copter_mode(mode)

"""The ArduPilot (ArduCopter) dialect of the MAVLink sim vehicle (:class:`ArduPilotSimVehicle`).

HEARTBEAT as MAV_AUTOPILOT_ARDUPILOTMEGA with Copter mode numbers, nothing streamed but the
heartbeat until asked, GUIDED velocity with a timeout, arming refused until the EKF/GPS delay has
passed or in a non-armable mode, the flight-mode switch on RC channel 5 (FLTMODE1..6), the
pilot's sticks handed to a stick vehicle, LANDING_TARGET in its angle form (AC_PrecLand_Companion),
the GCS failsafe on the GCS's heartbeat (:mod:`companion_sitl.mavlink.gcs_failsafe`).
"""

from __future__ import annotations

import math
import os
from typing import Any, ClassVar

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.autopilot.types import FlightMode
from companion.autopilot.winch import WinchAction, WinchCommand
from companion.guidance.setpoint import VelocitySetpoint
from companion_sitl.mavlink.gcs_failsafe import GcsFailsafe
from companion_sitl.mavlink.mission import StoredMissionItem
from companion_sitl.mavlink.vehicle import Dialect, MavlinkSimVehicle
from companion_sitl.params import SimConfig

# ArduCopter mode numbers
COPTER_STABILIZE = 0
COPTER_ACRO = 1
COPTER_ALT_HOLD = 2
COPTER_AUTO = 3
COPTER_GUIDED = 4
COPTER_LOITER = 5
COPTER_RTL = 6
COPTER_LAND = 9
COPTER_POSHOLD = 16
COPTER_BRAKE = 17

COPTER_MODE_NAMES = {
    COPTER_STABILIZE: "STABILIZE",
    COPTER_ACRO: "ACRO",
    COPTER_ALT_HOLD: "ALT_HOLD",
    COPTER_AUTO: "AUTO",
    COPTER_GUIDED: "GUIDED",
    COPTER_LOITER: "LOITER",
    COPTER_RTL: "RTL",
    COPTER_LAND: "LAND",
    COPTER_POSHOLD: "POSHOLD",
    COPTER_BRAKE: "BRAKE",
}


def copter_flight_mode(custom_mode: int) -> FlightMode:
    """ArduCopter mode number -> :class:`FlightMode` (GUIDED is companion control)."""
    return {
        COPTER_STABILIZE: FlightMode.MANUAL,
        COPTER_ACRO: FlightMode.MANUAL,
        COPTER_ALT_HOLD: FlightMode.MANUAL,
        COPTER_AUTO: FlightMode.MISSION,
        COPTER_GUIDED: FlightMode.OFFBOARD,
        COPTER_LOITER: FlightMode.POSITION,
        COPTER_POSHOLD: FlightMode.POSITION,
        COPTER_RTL: FlightMode.RTL,
        COPTER_LAND: FlightMode.LAND,
        COPTER_BRAKE: FlightMode.HOLD,
    }.get(custom_mode, FlightMode.UNKNOWN)


FLIGHT_MODE_TO_COPTER = {
    FlightMode.MANUAL: COPTER_STABILIZE,
    FlightMode.POSITION: COPTER_LOITER,
    FlightMode.HOLD: COPTER_BRAKE,
    FlightMode.LAND: COPTER_LAND,
    FlightMode.RTL: COPTER_RTL,
    FlightMode.MISSION: COPTER_AUTO,
    FlightMode.OFFBOARD: COPTER_GUIDED,
    FlightMode.TAKEOFF: COPTER_GUIDED,
}

# Copter FLTMODE1..6 on the mode switch channel (FLTMODE_CH = 5), by PWM band
COPTER_FLTMODES = (COPTER_STABILIZE, COPTER_ALT_HOLD, COPTER_LOITER, COPTER_RTL, COPTER_LAND, COPTER_GUIDED)
_FLTMODE_PWM_EDGES = (1230, 1360, 1490, 1620, 1749)


def fltmode_slot(pwm: int) -> int:
    for i, edge in enumerate(_FLTMODE_PWM_EDGES):
        if pwm <= edge:
            return i
    return 5


class ArduPilotSimVehicle(GcsFailsafe, MavlinkSimVehicle):
    """The sim vehicle speaking ArduCopter (see :class:`~companion_sitl.mavlink.vehicle.MavlinkSimVehicle`)."""

    FENCE_VERTEX_COUNT_PER_ITEM = False  # write_fence checks the polygons once the upload is complete

    dialect: Dialect = "ardupilot"
    SOFTWARE_VERSION: ClassVar[int] = (4 << 24) | (8 << 16) | (0 << 8) | 0  # 4.8.0 dev
    SIGNING: ClassVar[bool] = True  # SETUP_SIGNING as GCS_Signing.cpp (see MavlinkSimVehicle)
    RC_OVERRIDE_TIMEOUT_S: ClassVar[float] = 3.0  # RC_OVERRIDE_TIME, copter.parm default

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        self._ap_mode = COPTER_STABILIZE
        super().__init__(*args, **kwargs)
        self._fltmode_slot = fltmode_slot(self._rc[4])

    def _mission_home_item(self) -> StoredMissionItem:
        """Item 0 of a download is the home, in MAV_FRAME_GLOBAL (altitude AMSL; sitl/mavlink/mission.py)."""
        h = self.vehicle.home()
        home = self.cfg.home if h is None else h
        return StoredMissionItem(
            mavlink.MAV_FRAME_GLOBAL, mavlink.MAV_CMD_NAV_WAYPOINT, 0.0, 0.0, 0.0, 0.0,
            round(home.lat_deg * 1e7), round(home.lon_deg * 1e7), float(home.alt_amsl_m),
        )  # fmt: skip

    @property
    def copter_mode(self) -> int:
        return self._ap_mode

    def _vehicle_config(self, cfg: SimConfig, guided_timeout_s: float, ekf_delay_s: float | None) -> SimConfig:
        # ArduPilot: GUIDED velocity times out after 3 s (the vehicle stops, stays GUIDED);
        # arming waits for EKF/GPS
        vc = cfg.vehicle.model_copy(update={"offboard_loss_timeout_s": guided_timeout_s})
        upd: dict[str, Any] = {"vehicle": vc}
        if ekf_delay_s is not None:
            upd["ready_delay_s"] = ekf_delay_s
        return cfg.model_copy(update=upd)

    def _default_params(self, cfg: SimConfig, system_id: int, guided_timeout_s: float) -> dict[str, float]:
        return {
            "SYSID_THISMAV": float(system_id),
            "GRIP_ENABLE": 0.0,  # ArduCopter's default: DO_GRIPPER answers FAILED
            "FLTMODE_CH": 5.0,
            "GUID_TIMEOUT": guided_timeout_s,
            "RC_OVERRIDE_TIME": self.rc_override_timeout_s,
            "FS_GCS_ENABLE": 0.0,  # copter.parm: GCS failsafe off
            "FS_GCS_TIMEOUT": 5.0,  # ArduCopter 4.7's defaults
            "FS_OPTIONS": 16.0,  # continue in pilot-controlled modes on a GCS failsafe; gripper not released
            "PLND_ENABLED": 0.0,  # copter.parm: no precision landing (LAND ignores LANDING_TARGET)
            "PLND_TYPE": 0.0,
            # ArduCopter 4.7's fence and battery failsafe defaults (no DID_ENABLE: SITL has no OpenDroneID)
            "FENCE_ENABLE": 0.0,
            "FENCE_TYPE": 7.0,  # max altitude, circle, polygon
            "FENCE_ACTION": 1.0,  # RTL or Land
            "FENCE_ALT_MAX": 100.0,
            "BATT_FS_LOW_ACT": 0.0,
            "BATT_FS_CRT_ACT": 0.0,
            "BATT_LOW_VOLT": 10.5,
            "BATT_CRT_VOLT": 0.0,
            "BATT_LOW_MAH": 0.0,
            "BATT_CRT_MAH": 0.0,
            # outputs 1-4 drive the motors (33-36), the others have no function
            **{f"SERVO{n}_FUNCTION": float(32 + n if n <= 4 else 0) for n in range(1, 17)},
            "WPNAV_SPEED_UP": 100.0 * cfg.vehicle.takeoff_speed_m_s,
            "LAND_SPEED": 100.0 * cfg.vehicle.land_speed_m_s,
            # AP_Winch: WINCH_TYPE 1 (PWM) when the simulated winch is fitted, else none
            "WINCH_TYPE": 1.0 if cfg.winch.fitted else 0.0,
            "WINCH_RATE_MAX": cfg.winch.rate_max_m_s,
            "WINCH_POS_P": cfg.winch.pos_p,
            **{f"FLTMODE{i + 1}": float(m) for i, m in enumerate(COPTER_FLTMODES)},
        }

    def _pilot_mode(self, mode: FlightMode) -> None:
        self._set_copter_mode(FLIGHT_MODE_TO_COPTER.get(mode, COPTER_LOITER), pilot=True)

    def _mode_flags(self) -> int:
        b = mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if self._ap_mode in (COPTER_GUIDED, COPTER_AUTO, COPTER_RTL, COPTER_LAND):
            b |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        return b

    def _heartbeat_autopilot(self) -> tuple[int, int]:
        return mavlink.MAV_AUTOPILOT_ARDUPILOTMEGA, self._ap_mode

    def _arm_refused(self) -> int | None:
        if not self.vehicle.healthy:
            self._statustext("PreArm: EKF3 waiting for GPS config data", mavlink.MAV_SEVERITY_CRITICAL)
            return mavlink.MAV_RESULT_FAILED
        if self._ap_mode in (COPTER_LAND, COPTER_RTL, COPTER_AUTO):
            self._statustext("Arm: Mode not armable", mavlink.MAV_SEVERITY_CRITICAL)
            return mavlink.MAV_RESULT_FAILED
        return None

    def _gripper(self, p: tuple[float, ...]) -> int:
        # ArduCopter answers FAILED while the gripper library is off (GRIP_ENABLE = 0, its default)
        if self._params.get("GRIP_ENABLE", 0.0) < 0.5:
            return mavlink.MAV_RESULT_FAILED
        return super()._gripper(p)

    def _winch(self, p: tuple[float, ...]) -> int:
        # GCS_MAVLINK_Copter::handle_MAV_CMD_DO_WINCH: FAILED without an enabled winch (WINCH_TYPE = 0)
        # or for an action it does not implement; param 1 (instance) is ignored
        if self.vehicle.winch is None or not math.isfinite(p[1]):
            return mavlink.MAV_RESULT_FAILED
        try:
            action = WinchAction(int(p[1]))
        except ValueError:
            return mavlink.MAV_RESULT_FAILED
        length = p[2] if math.isfinite(p[2]) else 0.0
        rate = p[3] if math.isfinite(p[3]) else 0.0
        self.vehicle.winch_command(WinchCommand(1, action, length, rate))
        return mavlink.MAV_RESULT_ACCEPTED

    def _takeoff(self, p: tuple[float, ...]) -> int:
        if self._ap_mode != COPTER_GUIDED:
            self._statustext("Takeoff: only in GUIDED", mavlink.MAV_SEVERITY_WARNING)
            return mavlink.MAV_RESULT_FAILED
        self.vehicle.takeoff(p[6])
        return mavlink.MAV_RESULT_ACCEPTED

    def _land(self) -> int:
        return self._set_copter_mode(COPTER_LAND)

    def _rtl(self) -> int:
        return self._set_copter_mode(COPTER_RTL)

    def _set_mode(self, base: float, custom_main: float, custom_sub: float) -> int:
        return self._set_copter_mode(int(custom_main))

    def _landing_target_angles(self, m: Any) -> None:
        v = self.vehicle
        los = [-math.tan(m.angle_y), math.tan(m.angle_x), 1.0]
        n = math.sqrt(sum(c * c for c in los))
        if not (math.isfinite(n) and math.isfinite(m.distance) and m.distance > 0):
            self._statustext("PrecLand: bad LANDING_TARGET ignored", mavlink.MAV_SEVERITY_WARNING)
            return
        from companion.geometry.rotations import euler_to_rotmat

        rel = euler_to_rotmat(v.roll, v.pitch, v.yaw) @ [c * m.distance / n for c in los]
        pn, pe, _ = v._local()
        v.set_landing_target(pn + float(rel[0]), pe + float(rel[1]))

    def _set_copter_mode(self, mode: int, pilot: bool = False) -> int:
        v = self.vehicle
        if mode not in COPTER_MODE_NAMES:
            return mavlink.MAV_RESULT_FAILED
        if mode == COPTER_GUIDED:
            if v.mode is not FlightMode.TAKEOFF:
                v.hold()
        elif mode == COPTER_BRAKE:
            v.hold()
        elif mode == COPTER_LAND:
            if v.armed and self._params.get("PLND_ENABLED", 0.0) >= 0.5:
                v.precision_land()  # PLND_ENABLED = 1, PLND_TYPE = 1: steered by LANDING_TARGET if any
            elif v.armed:
                v.land()
            else:
                v.mode = FlightMode.LAND
        else:
            v.hold()
            v.mode = copter_flight_mode(mode)
        if mode != self._ap_mode:
            self._ap_mode = mode
            who = "pilot" if pilot else "command"
            self._statustext(f"Mode {COPTER_MODE_NAMES[mode]} ({who})", mavlink.MAV_SEVERITY_INFO)
        return mavlink.MAV_RESULT_ACCEPTED

    def _rc_switch(self, now: float) -> None:
        self._rc_effective(now)
        slot = fltmode_slot(self._rc[4])
        if slot != self._fltmode_slot:
            self._fltmode_slot = slot
            self._set_copter_mode(int(self._params.get(f"FLTMODE{slot + 1}", COPTER_FLTMODES[slot])), pilot=True)
        feed = getattr(self.vehicle, "set_rc_input", None)
        if feed is not None:
            feed(COPTER_MODE_NAMES.get(self._ap_mode, ""), tuple(self._rc[:4]))

    def _velocity_setpoint(self, sp: VelocitySetpoint) -> None:
        v = self.vehicle
        if self._ap_mode != COPTER_GUIDED or not v.armed or v.mode is FlightMode.TAKEOFF:
            self.stats.setpoints_rejected += 1
            return
        v.set_velocity(sp)
        if v.mode is not FlightMode.OFFBOARD:
            v.mode = FlightMode.OFFBOARD  # GUIDED velocity control resumes at once

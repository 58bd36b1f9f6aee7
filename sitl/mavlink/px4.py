"""The PX4 dialect of the MAVLink sim vehicle (:class:`Px4SimVehicle`).

HEARTBEAT as MAV_AUTOPILOT_PX4 with PX4 custom modes (main mode << 16 | sub mode << 24),
PX4-like default streams from boot, OFFBOARD velocity setpoints with PX4's rules, takeoff to
MIS_TAKEOFF_ALT, AUTO.PRECLAND, LANDING_TARGET in its position form only, PX4 parameters.
"""

from __future__ import annotations

import math
import os
from typing import ClassVar

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.autopilot.types import FlightMode
from companion.guidance.setpoint import VelocitySetpoint
from companion_sitl.mavlink.messages import PX4_DEFAULT_STREAMS_HZ
from companion_sitl.mavlink.vehicle import Dialect, MavlinkSimVehicle
from companion_sitl.params import SimConfig

# PX4 custom modes (px4_custom_mode.h)
PX4_MAIN_MANUAL = 1
PX4_MAIN_ALTCTL = 2
PX4_MAIN_POSCTL = 3
PX4_MAIN_AUTO = 4
PX4_MAIN_ACRO = 5
PX4_MAIN_OFFBOARD = 6
PX4_MAIN_STABILIZED = 7
PX4_SUB_AUTO_READY = 1
PX4_SUB_AUTO_TAKEOFF = 2
PX4_SUB_AUTO_LOITER = 3
PX4_SUB_AUTO_MISSION = 4
PX4_SUB_AUTO_RTL = 5
PX4_SUB_AUTO_LAND = 6
PX4_SUB_AUTO_PRECLAND = 9

PX4_MODES: dict[FlightMode, tuple[int, int]] = {
    FlightMode.UNKNOWN: (0, 0),
    FlightMode.MANUAL: (PX4_MAIN_MANUAL, 0),
    FlightMode.POSITION: (PX4_MAIN_POSCTL, 0),
    FlightMode.HOLD: (PX4_MAIN_AUTO, PX4_SUB_AUTO_LOITER),
    FlightMode.TAKEOFF: (PX4_MAIN_AUTO, PX4_SUB_AUTO_TAKEOFF),
    FlightMode.LAND: (PX4_MAIN_AUTO, PX4_SUB_AUTO_LAND),
    FlightMode.RTL: (PX4_MAIN_AUTO, PX4_SUB_AUTO_RTL),
    FlightMode.MISSION: (PX4_MAIN_AUTO, PX4_SUB_AUTO_MISSION),
    FlightMode.OFFBOARD: (PX4_MAIN_OFFBOARD, 0),
}


# COM_OBL_RC_ACT -> the mode offboard loss goes to (0 Position, 1 Altitude, 2 Manual, 3 Return,
# 4 Land, 5 Hold; Terminate and Disarm are not modelled: Position)
OFFBOARD_LOSS_ACTIONS = {
    0: FlightMode.POSITION,
    1: FlightMode.MANUAL,
    2: FlightMode.MANUAL,
    3: FlightMode.RTL,
    4: FlightMode.LAND,
    5: FlightMode.HOLD,
}


def px4_custom_mode(mode: FlightMode) -> int:
    main, sub = PX4_MODES[mode]
    return (main << 16) | (sub << 24)


def px4_flight_mode(custom_mode: int) -> FlightMode:
    """Decode a PX4 custom_mode (HEARTBEAT / DO_SET_MODE) into a :class:`FlightMode`."""
    main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
    if main in (PX4_MAIN_MANUAL, PX4_MAIN_ALTCTL, PX4_MAIN_ACRO, PX4_MAIN_STABILIZED):
        return FlightMode.MANUAL
    if main == PX4_MAIN_AUTO:
        for mode, (m, s) in PX4_MODES.items():
            if m == PX4_MAIN_AUTO and s == sub:
                return mode
        if sub == PX4_SUB_AUTO_PRECLAND:
            return FlightMode.LAND  # AUTO.PRECLAND: a landing steered by LANDING_TARGET
        return FlightMode.HOLD if sub == PX4_SUB_AUTO_READY else FlightMode.UNKNOWN
    for mode, (m, _s) in PX4_MODES.items():
        if m == main and m != 0:
            return mode
    return FlightMode.UNKNOWN


class Px4SimVehicle(MavlinkSimVehicle):
    """The sim vehicle speaking PX4 (see :class:`~companion_sitl.mavlink.vehicle.MavlinkSimVehicle`)."""

    # mavlink_mission.cpp parse_mavlink_mission_item (v1.16): the frames and commands PX4's mission takes
    MISSION_GLOBAL_FRAMES = (0, 3, 5, 6)  # GLOBAL, GLOBAL_RELATIVE_ALT and their _INT
    MISSION_GLOBAL_COMMANDS = frozenset(
        {16, 17, 19, 21, 22, 31, 80, 201, 195, 84, 85, 4501, 5000, 5001, 5002, 5003, 5004, 5100}
    )  # fmt: skip
    MISSION_FRAME_COMMANDS = frozenset(
        {177, 80, 201, 42600, 211, 178, 179, 189, 2003, 203, 204, 205, 1000, 1001, 531, 2000, 2001, 2500, 2501,
         200, 206, 260, 214, 530, 532, 534, 3000, 93, 20, 196, 197, 112, 114, 187, 212, 400}
    )  # fmt: skip

    dialect: Dialect = "px4"
    DEFAULT_STREAMS_HZ: ClassVar[dict[int, float]] = PX4_DEFAULT_STREAMS_HZ
    HOME_ALWAYS: ClassVar[bool] = True
    LOCAL_Z_OFFSET_M: ClassVar[float] = 0.04  # PX4's EKF reports a few cm, not 0, for z at rest on the ground
    SOFTWARE_VERSION: ClassVar[int] = (1 << 24) | (16 << 16) | (0 << 8) | 0xFF  # 1.16.0 release
    INT_PARAMS: ClassVar[frozenset[str]] = frozenset(
        {"COM_OBL_RC_ACT", "COM_RC_OVERRIDE", "EKF2_GPS_CTRL", "EKF2_HGT_REF", "SYS_AUTOSTART"}
    )
    PARAM_BYTEWISE: ClassVar[bool] = True  # PX4 sends int32 parameters byte-wise

    def _default_params(self, cfg: SimConfig, system_id: int, guided_timeout_s: float) -> dict[str, float]:
        return {
            "MIS_TAKEOFF_ALT": 2.5,
            "COM_OF_LOSS_T": cfg.vehicle.offboard_loss_timeout_s,
            "COM_OBL_RC_ACT": 0.0,
            "MPC_XY_VEL_MAX": 12.0,
            "MPC_LAND_SPEED": cfg.vehicle.land_speed_m_s,
            "MPC_TKO_SPEED": cfg.vehicle.takeoff_speed_m_s,
            "NAV_MC_ALT_RAD": cfg.vehicle.takeoff_altitude_acceptance_m,
            "SYS_AUTOSTART": 10040.0,
            # PX4 v1.16 defaults of what `companion preflight` checks
            "COM_RC_OVERRIDE": 1.0,
            "EKF2_GPS_CTRL": 7.0,
            "EKF2_HGT_REF": 1.0,
            "PLD_BTOUT": 5.0,
            "PLD_HACC_RAD": 0.2,
            "GF_ACTION": 2.0,  # Hold
            "GF_MAX_VER_DIST": 0.0,
            "COM_LOW_BAT_ACT": 3.0,  # the SITL's rcS: return at critical, land at emergency
            "BAT_CRIT_THR": 0.07,
            "COM_ARM_ODID": 0.0,
        }

    # PX4 v1.16 SIH, measured over MAVLink (see companion/autopilot/px4.py):
    #   boots in POSCTL; arming: TEMPORARILY_REJECTED in POSCTL without RC and in AUTO.TAKEOFF /
    #   AUTO.LAND, DENIED in OFFBOARD without a setpoint stream, ACCEPTED in HOLD;
    #   DO_GRIPPER and DO_SET_ACTUATOR ACCEPTED, DO_SET_SERVO UNSUPPORTED.
    BOOT_MODE: ClassVar[FlightMode] = FlightMode.POSITION
    # offboard lost (COM_OF_LOSS_T) with COM_OBL_RC_ACT = 0: PX4 v1.16 SIH goes to POSCTL, not HOLD
    # (tests/real_px4/test_px4_link_and_pilot.py)
    OFFBOARD_LOSS_MODE: ClassVar[FlightMode] = FlightMode.POSITION
    release_actuator: int = 1

    def _failsafes(self, now: float) -> None:
        # where the offboard-loss failsafe goes: COM_OBL_RC_ACT (PX4 v1.16 values), read each tick
        # so that a PARAM_SET takes effect at once; without RC, Position and Altitude hold
        act = int(self._params.get("COM_OBL_RC_ACT", 0.0))
        self.vehicle.offboard_loss_mode = OFFBOARD_LOSS_ACTIONS.get(act, self.OFFBOARD_LOSS_MODE)

    def _prearm_ok(self) -> bool:
        """PX4 reports itself not armable while disarmed in OFFBOARD without a setpoint stream (the
        mode a companion-flown landing leaves): its arming checks run for the current mode."""
        v = self.vehicle
        if not v.armed and v.mode is FlightMode.OFFBOARD and not v.setpoint_fresh():
            return False
        return bool(v.healthy)

    def _arm_refused(self) -> int | None:
        v = self.vehicle
        if v.armed:
            return None
        if v.mode in (FlightMode.POSITION, FlightMode.TAKEOFF, FlightMode.LAND):
            self._statustext(f"Arming denied: not armable in {v.mode.value} here", mavlink.MAV_SEVERITY_CRITICAL)
            return mavlink.MAV_RESULT_TEMPORARILY_REJECTED
        if v.mode is FlightMode.OFFBOARD and not v.setpoint_fresh():
            self._statustext("Arming denied: no offboard signal", mavlink.MAV_SEVERITY_CRITICAL)
            return mavlink.MAV_RESULT_DENIED
        return None

    def _set_servo(self, p: tuple[float, ...]) -> int:
        return mavlink.MAV_RESULT_UNSUPPORTED

    def _set_actuator(self, p: tuple[float, ...]) -> int | None:
        value = p[self.release_actuator - 1]
        if math.isfinite(value) and value > 0.0:
            self.vehicle.release_payload()
        return mavlink.MAV_RESULT_ACCEPTED

    def _pilot_mode(self, mode: FlightMode) -> None:
        self.vehicle.pilot_set_mode(mode)

    def _mode_flags(self) -> int:
        b = 0
        mode = self.vehicle.mode
        if mode is not FlightMode.MANUAL:
            b |= mavlink.MAV_MODE_FLAG_STABILIZE_ENABLED
        if mode in (FlightMode.HOLD, FlightMode.TAKEOFF, FlightMode.LAND, FlightMode.RTL, FlightMode.MISSION):
            b |= mavlink.MAV_MODE_FLAG_AUTO_ENABLED
        if mode is FlightMode.OFFBOARD:
            b |= mavlink.MAV_MODE_FLAG_GUIDED_ENABLED
        return b

    def _heartbeat_autopilot(self) -> tuple[int, int]:
        return mavlink.MAV_AUTOPILOT_PX4, px4_custom_mode(self.vehicle.mode)

    def _takeoff(self, p: tuple[float, ...]) -> int:
        v = self.vehicle
        home = v.home()
        if math.isfinite(p[6]) and home is not None:
            alt_rel = p[6] - home.alt_amsl_m
        else:
            alt_rel = self._params.get("MIS_TAKEOFF_ALT", 2.5)
        v.takeoff(alt_rel)
        return mavlink.MAV_RESULT_ACCEPTED

    def _land(self) -> int:
        self.vehicle.land()
        return mavlink.MAV_RESULT_ACCEPTED

    def _rtl(self) -> int:
        v = self.vehicle
        v.hold()
        v.mode = FlightMode.RTL
        return mavlink.MAV_RESULT_ACCEPTED

    def _set_mode(self, base: float, custom_main: float, custom_sub: float) -> int:
        v = self.vehicle
        if not int(base) & mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED:
            return mavlink.MAV_RESULT_UNSUPPORTED
        mode = px4_flight_mode((int(custom_main) << 16) | (int(custom_sub) << 24))
        if mode is FlightMode.UNKNOWN:
            return mavlink.MAV_RESULT_UNSUPPORTED
        if mode is FlightMode.OFFBOARD:
            v.start_offboard()
        elif mode is FlightMode.HOLD:
            v.hold()
        elif mode is FlightMode.LAND:
            if int(custom_main) == PX4_MAIN_AUTO and int(custom_sub) == PX4_SUB_AUTO_PRECLAND:
                v.precision_land()
            else:
                v.land()
        elif mode is FlightMode.TAKEOFF:
            v.takeoff(self._params.get("MIS_TAKEOFF_ALT", 2.5))
        else:
            v.hold()
            v.mode = mode
        return mavlink.MAV_RESULT_ACCEPTED

    def _velocity_setpoint(self, sp: VelocitySetpoint) -> None:
        self.vehicle.set_velocity(sp)

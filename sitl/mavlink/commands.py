"""Commands and setpoints of the sim vehicle: COMMAND_LONG / COMMAND_INT, velocity setpoints
(SET_POSITION_TARGET_LOCAL_NED), offboard attitude (SET_ATTITUDE_TARGET) and LANDING_TARGET,
with the dialect's hooks for what each autopilot does differently."""

from __future__ import annotations

import abc
import math
import os
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.geometry.rotations import quat_to_euler
from companion.guidance.setpoint import VelocitySetpoint
from companion_sitl.mavlink.messages import MessageStreams
from companion_sitl.vehicle import SimCommandError

# type_mask bits of SET_POSITION_TARGET_LOCAL_NED
MASK_POS = 0b111
MASK_VEL = 0b111000
MASK_ACC = 0b111000000
MASK_YAW = 1 << 10
MASK_YAW_RATE = 1 << 11


def _i(x: float) -> int:
    """A command parameter as an int (MAVSDK sends NaN for unused parameters)."""
    return int(x) if math.isfinite(x) else 0


class CommandHandler(MessageStreams):
    """COMMAND_LONG / COMMAND_INT and the setpoints, on the hooks a dialect fills in."""

    release_servo: int
    release_pwm: int

    def _arm_refused(self) -> int | None:
        """A MAV_RESULT if the dialect refuses to arm now, else None."""
        return None

    @abc.abstractmethod
    def _takeoff(self, p: tuple[float, ...]) -> int: ...

    def _gripper(self, p: tuple[float, ...]) -> int:
        """MAV_CMD_DO_GRIPPER (param 2: 0 = release)."""
        if _i(p[1]) == mavlink.GRIPPER_ACTION_RELEASE:
            self.vehicle.release_payload()
        return mavlink.MAV_RESULT_ACCEPTED

    def _set_servo(self, p: tuple[float, ...]) -> int:
        """MAV_CMD_DO_SET_SERVO (param 1 output, param 2 PWM)."""
        if _i(p[0]) == self.release_servo and _i(p[1]) >= self.release_pwm - 100:
            self.vehicle.release_payload()
        return mavlink.MAV_RESULT_ACCEPTED

    def _winch(self, p: tuple[float, ...]) -> int:
        """MAV_CMD_DO_WINCH (param 1 instance, 2 action, 3 length m, 4 rate m/s); a dialect without
        a winch answers UNSUPPORTED."""
        return mavlink.MAV_RESULT_UNSUPPORTED

    def _set_actuator(self, p: tuple[float, ...]) -> int | None:
        """MAV_CMD_DO_SET_ACTUATOR; None: not a command of this dialect."""
        return None

    @abc.abstractmethod
    def _land(self) -> int: ...

    @abc.abstractmethod
    def _rtl(self) -> int: ...

    @abc.abstractmethod
    def _set_mode(self, base: float, custom_main: float, custom_sub: float) -> int: ...

    def _landing_target_angles(self, m: Any) -> None:
        """LANDING_TARGET without a valid local position (the angle form)."""
        return None  # optional hook: this dialect ignores it

    @abc.abstractmethod
    def _velocity_setpoint(self, sp: VelocitySetpoint) -> None: ...

    def _command(self, cmd: int, p: tuple[float, ...], m: Any) -> int | None:
        v = self.vehicle
        A, D, U = mavlink.MAV_RESULT_ACCEPTED, mavlink.MAV_RESULT_DENIED, mavlink.MAV_RESULT_UNSUPPORTED
        try:
            if cmd == mavlink.MAV_CMD_COMPONENT_ARM_DISARM:
                if p[0] >= 0.5:
                    refused = self._arm_refused()
                    if refused is not None:
                        return refused
                    v.arm()
                else:
                    if _i(p[1]) == 21196 and v.armed:  # forced disarm
                        v.armed = False
                    else:
                        v.disarm()
                return A
            if cmd == mavlink.MAV_CMD_NAV_TAKEOFF:
                return self._takeoff(p)
            if cmd == mavlink.MAV_CMD_NAV_LAND:
                return self._land()
            if cmd == mavlink.MAV_CMD_NAV_RETURN_TO_LAUNCH:
                return self._rtl()
            if cmd == mavlink.MAV_CMD_DO_SET_MODE:
                return self._set_mode(*(float(_i(x)) for x in p[:3]))
            if cmd == mavlink.MAV_CMD_DO_GRIPPER:
                return self._gripper(p)
            if cmd == mavlink.MAV_CMD_DO_SET_SERVO:
                result = self._set_servo(p)
                if result == U:
                    self.stats.unsupported_commands[cmd] += 1
                return result
            if cmd == mavlink.MAV_CMD_DO_WINCH:
                result = self._winch(p)
                if result == U:
                    self.stats.unsupported_commands[cmd] += 1
                return result
            if cmd == mavlink.MAV_CMD_DO_SET_ACTUATOR:
                actuator = self._set_actuator(p)
                if actuator is not None:
                    return actuator
            if cmd == mavlink.MAV_CMD_SET_MESSAGE_INTERVAL:
                return self._set_interval(_i(p[0]), p[1] if math.isfinite(p[1]) else 0.0)
            if cmd == mavlink.MAV_CMD_REQUEST_MESSAGE:
                msg = self.build_message(_i(p[0]))
                if msg is None:
                    return U
                self._ack(cmd, A, m)
                self._send(msg)
                return None
            if cmd == mavlink.MAV_CMD_REQUEST_AUTOPILOT_CAPABILITIES:
                self._ack(cmd, A, m)
                self._send(self.build_message(mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION))
                return None
        except SimCommandError as err:
            self._statustext(str(err), mavlink.MAV_SEVERITY_CRITICAL)
            return D
        self.stats.unsupported_commands[cmd] += 1
        return U

    def _landing_target(self, m: Any) -> None:
        """LANDING_TARGET as each autopilot reads it: PX4 the position form in MAV_FRAME_LOCAL_NED;
        ArduPilot (AC_PrecLand_Companion) angle_x / angle_y / distance as the body-frame line of
        sight (-tan(angle_y), tan(angle_x), 1), rotated by the attitude and added to its position."""
        v = self.vehicle
        self.stats.landing_targets += 1
        if m.position_valid and m.frame == mavlink.MAV_FRAME_LOCAL_NED:
            v.set_landing_target(float(m.x), float(m.y))
            return
        self._landing_target_angles(m)  # PX4's landing_target_estimator takes the position form only

    def _attitude_target(self, m: Any) -> None:
        """SET_ATTITUDE_TARGET (offboard attitude) for a vehicle that flies it (``set_attitude_target``:
        companion_sitl.dart_link.StickSimVehicle): roll and pitch from the quaternion, the body yaw
        rate, the thrust; anything else (attitude ignored, no such vehicle) is rejected."""
        feed = getattr(self.vehicle, "set_attitude_target", None)
        if feed is None or m.type_mask & 0b1000_0000 or m.type_mask & 0b0100_0000:
            self.stats.setpoints_rejected += 1
            return
        roll, pitch, _yaw = quat_to_euler(m.q)
        yaw_rate = 0.0 if m.type_mask & 0b100 else float(m.body_yaw_rate)
        feed(roll, pitch, yaw_rate, float(m.thrust))
        self.stats.setpoints += 1

    def _setpoint(self, m: Any) -> None:
        v = self.vehicle
        mask = m.type_mask
        if m.coordinate_frame != mavlink.MAV_FRAME_LOCAL_NED or (mask & MASK_VEL) == MASK_VEL:
            self.stats.setpoints_rejected += 1
            return
        # a part is used when its bits are clear and, as PX4's receiver takes it, not all NaN
        # (MAVSDK's position-velocity-acceleration setpoint leaves the position NaN)
        if (mask & MASK_POS) != MASK_POS and not all(math.isnan(x) for x in (m.x, m.y, m.z)):
            self.stats.setpoints_rejected += 1  # position control is not simulated
            return
        yaw = v.estimated_yaw() if mask & MASK_YAW else m.yaw  # YAW_IGNORE: hold the heading
        # the horizontal acceleration, fed forward as the firmware does (PX4: added to its velocity
        # loop's output); the vertical one is not simulated
        acc = None
        if (mask & MASK_ACC) != MASK_ACC and not all(math.isnan(x) for x in (m.afx, m.afy, m.afz)):
            acc = (float(m.afx), float(m.afy))
        self._velocity_setpoint(VelocitySetpoint(m.vx, m.vy, m.vz, yaw, acc))
        self.stats.setpoints += 1

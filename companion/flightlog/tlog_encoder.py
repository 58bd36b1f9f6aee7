"""MAVLink for an autopilot that has no MAVLink link (:class:`TelemetryEncoder`): what the
embedded simulator reports (:mod:`companion.autopilot.types` samples) and what the companion
sends it, packed into the MAVLink 2 packets of a ``.tlog``."""

from __future__ import annotations

import logging
import math
import struct
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol

from pymavlink.dialects.v20 import ardupilotmega as mavlink2

from companion.autopilot.mavlink_messages import DirectPacker, velocity_setpoint_fields
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
from companion.guidance.setpoint import VelocitySetpoint

log = logging.getLogger(__name__)


class PackedRecords(Protocol):
    """Where a :class:`TelemetryEncoder` puts its packets (:class:`~companion.flightlog.tlog_writer.TlogWriter`, or
    :class:`~companion.flightlog.tlog_replay.TlogReplayer` in the logging process)."""

    path: Path
    encode_errors: int

    def write_packed(self, packet: bytes, t_unix_s: float | None = None) -> None: ...


_LANDED = {
    LandedState.UNKNOWN: mavlink2.MAV_LANDED_STATE_UNDEFINED,
    LandedState.ON_GROUND: mavlink2.MAV_LANDED_STATE_ON_GROUND,
    LandedState.IN_AIR: mavlink2.MAV_LANDED_STATE_IN_AIR,
    LandedState.TAKING_OFF: mavlink2.MAV_LANDED_STATE_TAKEOFF,
    LandedState.LANDING: mavlink2.MAV_LANDED_STATE_LANDING,
}
_U16_MAX = 65535


def _i32(x: float) -> int:
    return max(-(2**31), min(2**31 - 1, round(float(x))))


class TelemetryEncoder:
    """MAVLink for an autopilot that has no MAVLink link (the embedded simulator).

    :meth:`sample` encodes what the autopilot reports (HEARTBEAT with mode and armed flag,
    SYS_STATUS, BATTERY_STATUS and EXTENDED_SYS_STATE from a status; ATTITUDE; HIGHRES_IMU;
    LOCAL_POSITION_NED; GLOBAL_POSITION_INT; GPS_RAW_INT; HOME_POSITION; STATUSTEXT) from
    ``system_id``/``component_id``; :meth:`setpoint`, :meth:`command` and :meth:`command_ack`
    encode what the companion sends (SET_POSITION_TARGET_LOCAL_NED, COMMAND_LONG from
    ``companion_component``) and the autopilot's answer. ``custom_mode`` maps a
    :class:`FlightMode` onto the autopilot's HEARTBEAT custom mode. Each packet is
    packed at once by a :class:`~companion.autopilot.mavlink_messages.DirectPacker` (the bytes
    pymavlink gives, without building its message objects) and handed to the writer in chunks
    (:meth:`PackedRecords.write_packed`); ``boot_s`` is the clock time of the autopilot's boot
    (``time_boot_ms``). Use it from one thread.
    """

    def __init__(
        self,
        writer: PackedRecords,
        *,
        boot_s: float,
        clock: Callable[[], float],
        custom_mode: Callable[[FlightMode], int],
        autopilot: int = mavlink2.MAV_AUTOPILOT_PX4,
        vehicle_type: int = mavlink2.MAV_TYPE_QUADROTOR,
        system_id: int = 1,
        component_id: int = mavlink2.MAV_COMP_ID_AUTOPILOT1,
        companion_component: int = mavlink2.MAV_COMP_ID_ONBOARD_COMPUTER,
    ):
        self.writer = writer
        self.boot_s = boot_s
        self.clock = clock
        self.custom_mode = custom_mode
        self.autopilot = autopilot
        self.vehicle_type = vehicle_type
        self.vehicle_id = (system_id, component_id)
        self.companion_id = (system_id, companion_component)
        self._packer = DirectPacker()
        self._velocity = (0.0, 0.0, 0.0)
        self._yaw = 0.0

    def _emit(self, source: tuple[int, int], cls: Any, args: tuple[Any, ...]) -> None:
        try:
            packet = self._packer.pack(cls, args, *source)
        except (struct.error, TypeError, ValueError, OverflowError):  # a value the field cannot hold
            w = self.writer
            w.encode_errors += 1
            if w.encode_errors in (1, 100, 10000):
                log.exception("%s: cannot encode %s (%d so far)", w.path, cls.msgname, w.encode_errors)
            return
        self.writer.write_packed(packet)

    def _ms(self, t: float) -> int:
        return max(0, int((t - self.boot_s) * 1000.0)) & 0xFFFFFFFF

    def _us(self, t: float) -> int:
        return max(0, int((t - self.boot_s) * 1e6))

    def sample(self, s: TelemetrySample) -> None:
        """Encode one reported sample (at the clock's current time)."""
        t = self.clock()
        ms, us = self._ms(t), self._us(t)
        m = self._attitude_messages(s, ms, us)
        if m is None:
            m = self._position_messages(s, ms, us)
        if m is None:
            m = self._state_messages(s, us)
        if m is None:
            return
        for cls, args in m:
            self._emit(self.vehicle_id, cls, args)

    def _attitude_messages(self, s: TelemetrySample, ms: int, us: int) -> list[tuple[Any, tuple[Any, ...]]] | None:
        """ATTITUDE, HIGHRES_IMU (None: not an attitude or IMU sample)."""
        match s:
            case Attitude():
                self._yaw = s.yaw_rad
                return [
                    (
                        mavlink2.MAVLink_attitude_message,
                        (
                            ms,
                            s.roll_rad,
                            s.pitch_rad,
                            s.yaw_rad,
                            s.rollspeed_rad_s,
                            s.pitchspeed_rad_s,
                            s.yawspeed_rad_s,
                        ),
                    )
                ]
            case Imu():
                return [
                    (
                        mavlink2.MAVLink_highres_imu_message,
                        (
                            us,
                            s.accel_x_m_s2,
                            s.accel_y_m_s2,
                            s.accel_z_m_s2,
                            s.gyro_x_rad_s,
                            s.gyro_y_rad_s,
                            s.gyro_z_rad_s,
                            0.0,
                            0.0,
                            0.0,
                            0.0,
                            0.0,
                            0.0,
                            0.0,
                            0b111111,  # fields_updated: accelerometer and gyro
                            0,
                        ),
                    )
                ]
        return None

    def _position_messages(self, s: TelemetrySample, ms: int, us: int) -> list[tuple[Any, tuple[Any, ...]]] | None:
        """LOCAL_POSITION_NED, GLOBAL_POSITION_INT, GPS_RAW_INT (None: not a position sample)."""
        match s:
            case PositionNed():
                self._velocity = (s.north_m_s, s.east_m_s, s.down_m_s)
                return [
                    (
                        mavlink2.MAVLink_local_position_ned_message,
                        (ms, s.north_m, s.east_m, s.down_m, s.north_m_s, s.east_m_s, s.down_m_s),
                    )
                ]
            case GlobalPosition():
                vn, ve, vd = self._velocity
                hdg = round(math.degrees(self._yaw) % 360.0 * 100.0) % 36000
                return [
                    (
                        mavlink2.MAVLink_global_position_int_message,
                        (
                            ms,
                            _i32(s.lat_deg * 1e7),
                            _i32(s.lon_deg * 1e7),
                            _i32(s.alt_amsl_m * 1000.0),
                            _i32(s.alt_rel_m * 1000.0),
                            round(float(vn) * 100.0),
                            round(float(ve) * 100.0),
                            round(float(vd) * 100.0),
                            hdg,
                        ),
                    )
                ]
            case GpsRaw():
                eph = _U16_MAX if not math.isfinite(s.eph_m) else min(_U16_MAX - 1, round(float(s.eph_m) * 100.0))
                return [
                    (
                        mavlink2.MAVLink_gps_raw_int_message,
                        (
                            us,
                            s.fix_type,
                            _i32(s.lat_deg * 1e7),
                            _i32(s.lon_deg * 1e7),
                            _i32(s.alt_amsl_m * 1000.0),
                            eph,
                            _U16_MAX,
                            _U16_MAX,
                            _U16_MAX,
                            s.satellites,
                        ),
                    )
                ]
        return None

    def _state_messages(self, s: TelemetrySample, us: int) -> list[tuple[Any, tuple[Any, ...]]] | None:
        """The status's messages, HOME_POSITION, STATUSTEXT (None: a sample with no message)."""
        match s:
            case VehicleStatus():
                return self._status(s)
            case HomePosition():
                return [
                    (
                        mavlink2.MAVLink_home_position_message,
                        (
                            _i32(s.lat_deg * 1e7),
                            _i32(s.lon_deg * 1e7),
                            _i32(s.alt_amsl_m * 1000.0),
                            s.north_m,
                            s.east_m,
                            s.down_m,
                            [1.0, 0.0, 0.0, 0.0],
                            0.0,
                            0.0,
                            0.0,
                            us,
                        ),
                    )
                ]
            case StatusText():
                return [
                    (
                        mavlink2.MAVLink_statustext_message,
                        (s.severity, s.text.encode("utf-8", errors="replace")[:50], 0, 0),
                    )
                ]
        return None

    def _status(self, s: VehicleStatus) -> list[tuple[Any, tuple[Any, ...]]]:
        base = mavlink2.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if s.armed:
            base |= mavlink2.MAV_MODE_FLAG_SAFETY_ARMED
        state = mavlink2.MAV_STATE_ACTIVE if s.armed else mavlink2.MAV_STATE_STANDBY
        prearm = mavlink2.MAV_SYS_STATUS_PREARM_CHECK
        remaining = max(0, min(100, round(float(s.battery_pct))))
        return [
            (
                mavlink2.MAVLink_heartbeat_message,
                (self.vehicle_type, self.autopilot, base, self.custom_mode(s.mode), state, 3),
            ),
            (
                mavlink2.MAVLink_sys_status_message,
                (prearm, prearm, prearm if s.healthy else 0, 0, _U16_MAX, -1, remaining, 0, 0, 0, 0, 0, 0),
            ),
            (
                mavlink2.MAVLink_battery_status_message,
                (
                    0,
                    mavlink2.MAV_BATTERY_FUNCTION_ALL,
                    mavlink2.MAV_BATTERY_TYPE_LIPO,
                    32767,
                    [_U16_MAX] * 10,
                    -1,
                    -1,
                    -1,
                    remaining,
                ),
            ),
            (mavlink2.MAVLink_extended_sys_state_message, (mavlink2.MAV_VTOL_STATE_UNDEFINED, _LANDED[s.landed])),
        ]

    def setpoint(self, sp: VelocitySetpoint) -> None:
        """The companion's velocity setpoint, as SET_POSITION_TARGET_LOCAL_NED."""
        ms = self._ms(self.clock())
        ts, tc = self.vehicle_id
        fields = velocity_setpoint_fields(ms, ts, tc, sp)
        self._emit(self.companion_id, mavlink2.MAVLink_set_position_target_local_ned_message, fields)

    def command(self, command: int, params: Sequence[float] = ()) -> None:
        """A COMMAND_LONG from the companion (up to seven parameters)."""
        p = [float(x) for x in params][:7]
        p += [0.0] * (7 - len(p))
        ts, tc = self.vehicle_id
        self._emit(self.companion_id, mavlink2.MAVLink_command_long_message, (ts, tc, command, 0, *p))

    def command_ack(self, command: int, result: int) -> None:
        """The autopilot's COMMAND_ACK to the companion."""
        ts, tc = self.companion_id
        self._emit(self.vehicle_id, mavlink2.MAVLink_command_ack_message, (command, result, 0, 0, ts, tc))

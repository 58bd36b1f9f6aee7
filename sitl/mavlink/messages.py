"""What the sim vehicle sends: the message builders (:meth:`MessageStreams.build_message`) and the streams
that schedule them (the dialect's defaults, SET_MESSAGE_INTERVAL, REQUEST_DATA_STREAM).

Ground truth goes out as HIL_STATE_QUATERNION when requested.
"""

from __future__ import annotations

import abc
import math
import os
import time
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

os.environ.setdefault("MAVLINK20", "1")
from pymavlink.dialects.v20 import ardupilotmega as mavlink

from companion.autopilot.types import FlightMode, LandedState
from companion.geometry.earth import LocalTangentPlane
from companion_sitl.mavlink.rc_input import RcInput
from companion_sitl.vehicle import G

_IMU = mavlink.MAV_SYS_STATUS_SENSOR_3D_GYRO | mavlink.MAV_SYS_STATUS_SENSOR_3D_ACCEL
SENSORS_BASE = _IMU | mavlink.MAV_SYS_STATUS_SENSOR_3D_MAG
SENSORS_BASE |= mavlink.MAV_SYS_STATUS_SENSOR_ABSOLUTE_PRESSURE | mavlink.MAV_SYS_STATUS_AHRS
SENSORS_GPS = mavlink.MAV_SYS_STATUS_SENSOR_GPS
SENSORS_PREARM = mavlink.MAV_SYS_STATUS_PREARM_CHECK

PX4_DEFAULT_STREAMS_HZ: dict[int, float] = {
    mavlink.MAVLINK_MSG_ID_ATTITUDE: 50.0,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: 50.0,
    mavlink.MAVLINK_MSG_ID_HIGHRES_IMU: 50.0,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: 40.0,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: 30.0,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: 8.0,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: 5.0,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: 5.0,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: 1.0,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: 0.5,
}

# ArduPilot REQUEST_DATA_STREAM groups (GCS_MAVLink stream ids)
AP_STREAM_GROUPS: dict[int, tuple[int, ...]] = {
    mavlink.MAV_DATA_STREAM_RAW_SENSORS: (mavlink.MAVLINK_MSG_ID_RAW_IMU, mavlink.MAVLINK_MSG_ID_HIGHRES_IMU),
    mavlink.MAV_DATA_STREAM_EXTENDED_STATUS: (
        mavlink.MAVLINK_MSG_ID_SYS_STATUS,
        mavlink.MAVLINK_MSG_ID_GPS_RAW_INT,
        mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE,
    ),
    mavlink.MAV_DATA_STREAM_RC_CHANNELS: (mavlink.MAVLINK_MSG_ID_RC_CHANNELS,),
    mavlink.MAV_DATA_STREAM_POSITION: (
        mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
        mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
    ),
    mavlink.MAV_DATA_STREAM_EXTRA1: (mavlink.MAVLINK_MSG_ID_ATTITUDE,),
    mavlink.MAV_DATA_STREAM_EXTRA3: (mavlink.MAVLINK_MSG_ID_BATTERY_STATUS,),
}


def euler_to_quaternion(roll: float, pitch: float, yaw: float) -> tuple[float, float, float, float]:
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return (
        cr * cp * cy + sr * sp * sy,
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
    )


class MessageStreams(RcInput):
    """The message builders and the stream schedule (message id -> [interval_s, next_due])."""

    DEFAULT_STREAMS_HZ: ClassVar[dict[int, float]] = {}  # streamed from boot unless stream_rates_hz
    HOME_ALWAYS: ClassVar[bool] = False  # send HOME_POSITION on change even when not streamed
    LOCAL_Z_OFFSET_M: ClassVar[float] = 0.0  # added to LOCAL_POSITION_NED z
    SOFTWARE_VERSION: ClassVar[int] = 0  # AUTOPILOT_VERSION flight_sw_version
    clock_offset_s: float  # added to the UTC this vehicle reports (SYSTEM_TIME)
    _streams: dict[int, list[float]]
    unsupported_messages: frozenset[int]  # SET_MESSAGE_INTERVAL answers UNSUPPORTED for these
    _hb_period: float
    _hb_next: float
    _texts_sent: int
    _home_sent: tuple[float, float, float] | None
    _ltp: LocalTangentPlane

    @abc.abstractmethod
    def _mode_flags(self) -> int: ...

    @abc.abstractmethod
    def _heartbeat_autopilot(self) -> tuple[int, int]:
        """(MAV_AUTOPILOT, custom_mode) of the HEARTBEAT."""
        ...

    def _send_due(self, now: float) -> None:
        if now >= self._hb_next:
            self._hb_next = now + self._hb_period
            self._send(self._heartbeat())
        for mid, st in self._streams.items():
            if now >= st[1]:
                st[1] = max(st[1] + st[0], now)
                msg = self.build_message(mid)
                if msg is not None:
                    self._send(msg)
        v = self.vehicle
        while self._texts_sent < len(v.status_texts):
            _ts, text = v.status_texts[self._texts_sent]
            self._texts_sent += 1
            self._statustext(text, mavlink.MAV_SEVERITY_INFO)
        home = v.home()
        if home is not None:
            key = (home.lat_deg, home.lon_deg, home.alt_amsl_m)
            wanted = self.HOME_ALWAYS or mavlink.MAVLINK_MSG_ID_HOME_POSITION in self._streams
            if key != self._home_sent and wanted:
                self._home_sent = key
                self._send(self.build_message(mavlink.MAVLINK_MSG_ID_HOME_POSITION))

    # ------------------------------------------------------------------ message builders
    def _base_mode(self) -> int:
        b = mavlink.MAV_MODE_FLAG_CUSTOM_MODE_ENABLED
        if self.vehicle.armed:
            b |= mavlink.MAV_MODE_FLAG_SAFETY_ARMED
        return b | self._mode_flags()

    def _heartbeat(self) -> Any:
        v = self.vehicle
        ap, custom = self._heartbeat_autopilot()
        state = mavlink.MAV_STATE_ACTIVE if v.armed else mavlink.MAV_STATE_STANDBY
        return self._enc.heartbeat_encode(mavlink.MAV_TYPE_QUADROTOR, ap, self._base_mode(), custom, state, 3)

    def _local(self) -> tuple[float, float, float, float, float, float]:
        p = self.vehicle.position_ned()
        dz = self.LOCAL_Z_OFFSET_M
        return p.north_m, p.east_m, p.down_m + dz, p.north_m_s, p.east_m_s, p.down_m_s

    def _prearm_ok(self) -> bool:
        """SYS_STATUS's pre-arm bit (what MAVSDK reads as ``is_armable``): the estimate is ready."""
        return bool(self.vehicle.healthy)

    def _landed_state(self) -> int:
        v = self.vehicle
        if v.landed is LandedState.ON_GROUND:
            return mavlink.MAV_LANDED_STATE_ON_GROUND
        if v.mode is FlightMode.LAND:
            return mavlink.MAV_LANDED_STATE_LANDING
        if v.mode is FlightMode.TAKEOFF:
            return mavlink.MAV_LANDED_STATE_TAKEOFF
        return mavlink.MAV_LANDED_STATE_IN_AIR

    def build_message(self, mid: int) -> Any:
        """The message ``mid`` as the vehicle is now, or None when it has none to send (no
        builder, no fix, no home, no winch)."""
        build = _BUILDERS.get(mid)
        return build(self) if build is not None else None

    def _t_ms(self) -> int:
        """time_boot_ms: the vehicle's clock in ms, wrapped to 32 bits."""
        return int(self.vehicle.time_s * 1000) & 0xFFFFFFFF

    def _t_us(self) -> int:
        """time_usec: the vehicle's clock in microseconds."""
        return int(self.vehicle.time_s * 1e6)

    def _msg_attitude(self) -> Any:
        v, e = self.vehicle, self._enc
        t_ms = self._t_ms()
        a = v.attitude()
        return e.attitude_encode(
            t_ms, a.roll_rad, a.pitch_rad, a.yaw_rad, a.rollspeed_rad_s, a.pitchspeed_rad_s, a.yawspeed_rad_s
        )

    def _msg_attitude_quaternion(self) -> Any:
        v, e = self.vehicle, self._enc
        t_ms = self._t_ms()
        a = v.attitude()
        q = euler_to_quaternion(a.roll_rad, a.pitch_rad, a.yaw_rad)
        return e.attitude_quaternion_encode(t_ms, *q, a.rollspeed_rad_s, a.pitchspeed_rad_s, a.yawspeed_rad_s)

    def _msg_highres_imu(self) -> Any:
        v, e = self.vehicle, self._enc
        t_us = self._t_us()
        i = v.imu()
        alt = -v.pd + self.cfg.home.alt_amsl_m
        p_hpa = 1013.25 * (1.0 - 2.25577e-5 * alt) ** 5.25588
        return e.highres_imu_encode(
            t_us,
            i.accel_x_m_s2,
            i.accel_y_m_s2,
            i.accel_z_m_s2,
            i.gyro_x_rad_s,
            i.gyro_y_rad_s,
            i.gyro_z_rad_s,
            0.2,
            0.0,
            0.4,
            p_hpa,
            0.0,
            alt,
            25.0,
            0x1FFF,
        )

    def _msg_raw_imu(self) -> Any:
        v, e = self.vehicle, self._enc
        t_us = self._t_us()
        i = v.imu()
        mg = 1000.0 / G
        return e.raw_imu_encode(
            t_us,
            *(round(x * mg) for x in (i.accel_x_m_s2, i.accel_y_m_s2, i.accel_z_m_s2)),
            *(round(x * 1000.0) for x in (i.gyro_x_rad_s, i.gyro_y_rad_s, i.gyro_z_rad_s)),
            200,
            0,
            400,
        )

    def _msg_global_position_int(self) -> Any:
        v, e = self.vehicle, self._enc
        t_ms = self._t_ms()
        if not v.healthy:
            return None
        g = v.global_position()
        hdg = round(math.degrees(v.estimated_yaw()) * 100) % 36000  # the estimate, as ATTITUDE
        return e.global_position_int_encode(
            t_ms,
            round(g.lat_deg * 1e7),
            round(g.lon_deg * 1e7),
            round(g.alt_amsl_m * 1000),
            round(g.alt_rel_m * 1000),
            round(v.vn * 100),
            round(v.ve * 100),
            round(v.vd * 100),
            hdg,
        )

    def _msg_local_position_ned(self) -> Any:
        v, e = self.vehicle, self._enc
        t_ms = self._t_ms()
        if not v.healthy:
            return None
        return e.local_position_ned_encode(t_ms, *self._local())

    def _msg_gps_raw_int(self) -> Any:
        v, e = self.vehicle, self._enc
        t_us = self._t_us()
        gr = v.gps_raw()
        speed = math.hypot(v.vn, v.ve)
        cog = round(math.degrees(math.atan2(v.ve, v.vn)) * 100) % 36000 if speed > 0.2 else 0xFFFF
        return e.gps_raw_int_encode(
            t_us,
            gr.fix_type,
            round(gr.lat_deg * 1e7),
            round(gr.lon_deg * 1e7),
            round(gr.alt_amsl_m * 1000),
            int(gr.eph_m * 100),
            120,
            int(speed * 100),
            cog,
            gr.satellites,
        )

    def _msg_sys_status(self) -> Any:
        v, e = self.vehicle, self._enc
        present = SENSORS_BASE | SENSORS_GPS | SENSORS_PREARM
        health = SENSORS_BASE | (SENSORS_GPS if v.healthy else 0) | (SENSORS_PREARM if self._prearm_ok() else 0)
        volts = int(12600 - 2000 * (1.0 - v.battery_pct / 100.0))
        return e.sys_status_encode(
            present, present, health, 250, volts, 1000 if v.armed else 50, int(v.battery_pct), 0, 0, 0, 0, 0, 0
        )

    def _msg_extended_sys_state(self) -> Any:
        e = self._enc
        return e.extended_sys_state_encode(mavlink.MAV_VTOL_STATE_UNDEFINED, self._landed_state())

    def _msg_battery_status(self) -> Any:
        v, e = self.vehicle, self._enc
        volts = int(12600 - 2000 * (1.0 - v.battery_pct / 100.0))
        cells = [volts // 3] * 3 + [65535] * 7
        return e.battery_status_encode(
            0,
            mavlink.MAV_BATTERY_FUNCTION_ALL,
            mavlink.MAV_BATTERY_TYPE_LIPO,
            32767,
            cells,
            1000 if v.armed else 50,
            -1,
            -1,
            int(v.battery_pct),
        )

    def _msg_system_time(self) -> Any:
        """SYSTEM_TIME (the host's UTC, as a SITL reports it)."""
        e = self._enc
        t_ms = self._t_ms()
        return e.system_time_encode(int((time.time() + self.clock_offset_s) * 1e6), t_ms)

    def _msg_home_position(self) -> Any:
        v, e = self.vehicle, self._enc
        t_us = self._t_us()
        h = v.home()
        if h is None:
            return None
        return e.home_position_encode(
            round(h.lat_deg * 1e7),
            round(h.lon_deg * 1e7),
            round(h.alt_amsl_m * 1000),
            0.0,
            0.0,
            0.0,
            (1.0, 0.0, 0.0, 0.0),
            0.0,
            0.0,
            0.0,
            t_us,
        )

    def _msg_hil_state_quaternion(self) -> Any:
        v, e = self.vehicle, self._enc
        t_us = self._t_us()
        g = self._ltp.to_geo(v.pn, v.pe, v.pd)
        a = v.attitude()
        mg = 1000.0 / G
        acc = v.imu()
        return e.hil_state_quaternion_encode(
            t_us,
            euler_to_quaternion(v.roll, v.pitch, v.yaw),
            a.rollspeed_rad_s,
            a.pitchspeed_rad_s,
            a.yawspeed_rad_s,
            # degE7 truncated toward zero, as PX4 and ArduPilot do (C's int32 conversion)
            int(g.lat_deg * 1e7),
            int(g.lon_deg * 1e7),
            round(g.alt_amsl_m * 1000),
            int(v.vn * 100),
            int(v.ve * 100),
            int(v.vd * 100),
            0,
            0,
            *(round(x * mg) for x in (acc.accel_x_m_s2, acc.accel_y_m_s2, acc.accel_z_m_s2)),
        )

    def _msg_rc_channels(self) -> Any:
        e = self._enc
        t_ms = self._t_ms()
        n = max(8, max((i + 1 for i, us in enumerate(self._rc) if us), default=8))
        return e.rc_channels_encode(t_ms, n, *self._rc, 255)

    def _msg_winch_status(self) -> Any:
        v, e = self.vehicle, self._enc
        t_us = self._t_us()
        # AP_Winch_PWM::send_status: its own line estimate and rate, no tension, voltage, current
        # (a load-cell winch, [sim.winch] load_cell, sends the tension)
        w = getattr(v, "winch", None)
        if w is None or self.dialect != "ardupilot":
            return None  # nothing sent without a winch backend
        nan = math.nan
        tension = v.payload.line_tension_kg()
        return e.winch_status_encode(t_us, w.length_m, w.speed_m_s, tension, nan, nan, 32767, w.flags())

    def _rangefinder(self) -> tuple[float, float, int, float] | None:
        """The rangefinder the vehicle's parameters configure: (min m, max m, MAV_SENSOR_ORIENTATION,
        noise m), None: none. ArduCopter: RNGFND1_TYPE != 0 (100: the SITL's), RNGFND1_MIN/MAX (m, 4.7's
        defaults 0.2 and 7), RNGFND1_ORIENT (25: down), SIM_SONAR_RND (the SITL's noise, m). PX4 SIH
        streams its own (SIH_DISTSNSR_MIN/MAX, 0-100 m, downward) on every onboard link, measured; this
        vehicle only when its parameters name SIH_DISTSNSR_MAX, so the links of the flights before it
        carry what they did."""
        p = self._params
        if self.dialect == "ardupilot":
            if p.get("RNGFND1_TYPE", 0.0) == 0.0:
                return None
            rnd = p.get("SIM_SONAR_RND", 0.0)
            return p.get("RNGFND1_MIN", 0.2), p.get("RNGFND1_MAX", 7.0), int(p.get("RNGFND1_ORIENT", 25.0)), rnd
        if "SIH_DISTSNSR_MAX" not in p:
            return None
        return p.get("SIH_DISTSNSR_MIN", 0.0), p["SIH_DISTSNSR_MAX"], mavlink.MAV_SENSOR_ROTATION_PITCH_270, 0.0

    def _msg_distance_sensor(self) -> Any:
        """DISTANCE_SENSOR from the true height above the flat ground along the sensor's axis (a
        downward one tilts with the vehicle), with the SITL's uniform noise from a generator of its
        own (the seed's), in centimetres as the firmware sends it."""
        rf = self._rangefinder()
        if rf is None:
            return None
        lo, hi, orient, noise = rf
        v = self.vehicle
        rng = getattr(self, "_rng_rangefinder", None)
        if rng is None:
            rng = self._rng_rangefinder = np.random.default_rng([v.cfg.seed, 0x524E])
        cos_tilt = math.cos(v.roll) * math.cos(v.pitch)
        d = max(0.0, -v.pd) / max(cos_tilt, 0.1) if orient == mavlink.MAV_SENSOR_ROTATION_PITCH_270 else hi
        d += noise * float(rng.uniform(-1.0, 1.0))
        cm = max(0, min(65535, round(100.0 * d)))
        return self._enc.distance_sensor_encode(
            self._t_ms(), round(100 * lo), round(100 * hi), cm, mavlink.MAV_DISTANCE_SENSOR_LASER, 0, orient, 0
        )

    def _msg_autopilot_version(self) -> Any:
        e = self._enc
        caps = (
            mavlink.MAV_PROTOCOL_CAPABILITY_MAVLINK2
            | mavlink.MAV_PROTOCOL_CAPABILITY_SET_POSITION_TARGET_LOCAL_NED
            | mavlink.MAV_PROTOCOL_CAPABILITY_COMMAND_INT
            | mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_FLOAT
            | mavlink.MAV_PROTOCOL_CAPABILITY_MISSION_INT
        )
        if self.PARAM_BYTEWISE:
            caps |= mavlink.MAV_PROTOCOL_CAPABILITY_PARAM_ENCODE_BYTEWISE
        sw = self.SOFTWARE_VERSION
        uid = 0x5349_4D00 + self.system_id
        return e.autopilot_version_encode(caps, sw, 0, 0, 0, [0] * 8, [0] * 8, [0] * 8, 0, 0, uid)

    @property
    def streamed_message_ids(self) -> frozenset[int]:
        """The message ids streamed now: the defaults and what was asked for, less what was stopped."""
        return frozenset(self._streams)

    def _set_interval(self, mid: int, interval_us: float) -> int:
        if mavlink.mavlink_map.get(mid) is None or mid in self.unsupported_messages:
            return mavlink.MAV_RESULT_UNSUPPORTED
        if interval_us < 0:
            self._streams.pop(mid, None)
            return mavlink.MAV_RESULT_ACCEPTED
        if interval_us == 0:
            hz = PX4_DEFAULT_STREAMS_HZ.get(mid, 1.0)
            interval = 1.0 / hz
        else:
            interval = max(interval_us * 1e-6, 0.002)
        if (
            mid != mavlink.MAVLINK_MSG_ID_HEARTBEAT
            and self.build_message(mid) is None
            and mid
            not in (
                mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT,
                mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED,
                mavlink.MAVLINK_MSG_ID_HOME_POSITION,
                mavlink.MAVLINK_MSG_ID_WINCH_STATUS,  # ArduPilot accepts it with or without a winch
                mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR,  # both accept it with or without a rangefinder
            )
        ):
            return mavlink.MAV_RESULT_UNSUPPORTED
        if mid == mavlink.MAVLINK_MSG_ID_HEARTBEAT:
            self._hb_period = interval
        else:
            self._streams[mid] = [interval, self.now]
        return mavlink.MAV_RESULT_ACCEPTED

    def _request_data_stream(self, stream_id: int, rate_hz: int, start: bool) -> None:
        groups = list(AP_STREAM_GROUPS) if stream_id == mavlink.MAV_DATA_STREAM_ALL else [stream_id]
        for g in groups:
            for mid in AP_STREAM_GROUPS.get(g, ()):
                if start and rate_hz > 0:
                    self._streams[mid] = [1.0 / rate_hz, self.now]
                else:
                    self._streams.pop(mid, None)


# message id -> its builder (MessageStreams.build_message)
_BUILDERS: dict[int, Callable[[MessageStreams], Any]] = {
    mavlink.MAVLINK_MSG_ID_ATTITUDE: MessageStreams._msg_attitude,
    mavlink.MAVLINK_MSG_ID_ATTITUDE_QUATERNION: MessageStreams._msg_attitude_quaternion,
    mavlink.MAVLINK_MSG_ID_HIGHRES_IMU: MessageStreams._msg_highres_imu,
    mavlink.MAVLINK_MSG_ID_RAW_IMU: MessageStreams._msg_raw_imu,
    mavlink.MAVLINK_MSG_ID_GLOBAL_POSITION_INT: MessageStreams._msg_global_position_int,
    mavlink.MAVLINK_MSG_ID_LOCAL_POSITION_NED: MessageStreams._msg_local_position_ned,
    mavlink.MAVLINK_MSG_ID_GPS_RAW_INT: MessageStreams._msg_gps_raw_int,
    mavlink.MAVLINK_MSG_ID_SYS_STATUS: MessageStreams._msg_sys_status,
    mavlink.MAVLINK_MSG_ID_EXTENDED_SYS_STATE: MessageStreams._msg_extended_sys_state,
    mavlink.MAVLINK_MSG_ID_BATTERY_STATUS: MessageStreams._msg_battery_status,
    mavlink.MAVLINK_MSG_ID_SYSTEM_TIME: MessageStreams._msg_system_time,
    mavlink.MAVLINK_MSG_ID_HOME_POSITION: MessageStreams._msg_home_position,
    mavlink.MAVLINK_MSG_ID_HIL_STATE_QUATERNION: MessageStreams._msg_hil_state_quaternion,
    mavlink.MAVLINK_MSG_ID_RC_CHANNELS: MessageStreams._msg_rc_channels,
    mavlink.MAVLINK_MSG_ID_WINCH_STATUS: MessageStreams._msg_winch_status,
    mavlink.MAVLINK_MSG_ID_DISTANCE_SENSOR: MessageStreams._msg_distance_sensor,
    mavlink.MAVLINK_MSG_ID_AUTOPILOT_VERSION: MessageStreams._msg_autopilot_version,
}

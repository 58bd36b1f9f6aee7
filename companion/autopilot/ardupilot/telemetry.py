"""ArduPilot's MAVLink decoded into :mod:`companion.autopilot.types` samples, stamped on the
shell's monotonic clock at receipt (on the reader thread) and handed to the event loop for
:attr:`~companion.autopilot.interface.Autopilot.telemetry`. COMMAND_ACK, PARAM_VALUE and
SYSTEM_TIME resolve the requests waiting for them."""

from __future__ import annotations

import logging
import math
import time
from typing import Any

from companion.autopilot.ardupilot.dialect import mavlink
from companion.autopilot.ardupilot.fence import MISSION_MESSAGES
from companion.autopilot.ardupilot.modes import COPTER_TO_FLIGHT_MODE, LANDED_STATES
from companion.autopilot.ardupilot.requests import ArduPilotRequests
from companion.autopilot.interface import (
    RcInput,
)
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
    Wind,
)
from companion.autopilot.winch import WinchStatus

log = logging.getLogger(__name__)

G = 9.80665


class ArduPilotTelemetry(ArduPilotRequests):
    """Vehicle state and telemetry samples from what the reader thread receives."""

    def _on_component_command(self, m: Any) -> None:
        """A COMMAND_LONG (:class:`~.component.ArduPilotComponent`)."""

    @property
    def mode(self) -> FlightMode:
        return COPTER_TO_FLIGHT_MODE.get(self.copter_mode, FlightMode.UNKNOWN)

    def _push(self, sample: TelemetrySample) -> None:
        self._post(self.telemetry.push, sample)

    def _status(self) -> VehicleStatus:
        healthy = self._prearm_ok if self._prearm_ok is not None else self._gps_fix >= 3
        return VehicleStatus(
            time.monotonic(),
            self._armed,
            self.mode,
            self._landed,
            bool(healthy),
            self._battery_pct if math.isfinite(self._battery_pct) else 100.0,
            self._payload_released,
        )

    def _push_status(self) -> None:
        self._push(self._status())

    def _on_message(self, m: Any) -> None:
        t = m.get_type()
        if t == "BAD_DATA":
            if getattr(m, "reason", "") == "Invalid signature":
                self.counters.signature_rejects += 1
                if self.counters.signature_rejects in (1, 100) or self.counters.signature_rejects % 1000 == 0:
                    log.warning(
                        "MAVLink signing: %d packets dropped (unsigned, or signed with another key)",
                        self.counters.signature_rejects,
                    )
                return
            self.counters.bad_data += 1
            self.counters.garbage_bytes += len(getattr(m, "data", b""))
            return
        src = m.get_srcSystem()
        now = time.monotonic()
        if t == "COMMAND_LONG":  # from the operator's GCS (any system), for the companion's component
            self._on_component_command(m)
            return
        if t == "HEARTBEAT":
            if m.autopilot == mavlink.MAV_AUTOPILOT_INVALID or m.type == mavlink.MAV_TYPE_GCS:
                return  # a GCS or another companion
            if self.target_system is None:
                self.target_system = src
            if src != self.target_system or m.get_srcComponent() != self.target_component:
                return
            self.counters.heartbeats += 1
            buf = m.get_msgbuf()
            self._vehicle_signs = len(buf) > 2 and buf[0] == 0xFD and bool(buf[2] & 0x01)  # MAVLINK_IFLAG_SIGNED
            if m.get_signed():
                self.counters.signed_heartbeats += 1
                self.counters.signed_from_vehicle += 1
            self._last_hb = now
            self._last_rx = now
            self.copter_mode = m.custom_mode
            self._armed = bool(m.base_mode & mavlink.MAV_MODE_FLAG_SAFETY_ARMED)
            if self._first_hb is not None and not self._first_hb.done():
                self._post(self._resolve_first_hb)
            self._push_status()
            if now - self._last_attitude > 3.0:
                self._check_streams(now)
            return
        if self.target_system is None or src != self.target_system:
            return
        self.counters.messages += 1
        self.counters.signed_from_vehicle += m.get_signed()
        self._last_rx = now
        if t == "ATTITUDE":
            self._last_attitude = now
            self._push(Attitude(now, m.roll, m.pitch, m.yaw, m.rollspeed, m.pitchspeed, m.yawspeed))
        elif t == "HIGHRES_IMU":
            self._have_highres = True
            self._push(Imu(now, m.xacc, m.yacc, m.zacc, m.xgyro, m.ygyro, m.zgyro))
        elif t == "RAW_IMU" and not self._have_highres:
            a = G / 1000.0
            self._push(Imu(now, m.xacc * a, m.yacc * a, m.zacc * a, m.xgyro / 1e3, m.ygyro / 1e3, m.zgyro / 1e3))
        elif t == "LOCAL_POSITION_NED":
            self._push(PositionNed(now, m.x, m.y, m.z, m.vx, m.vy, m.vz))
        elif t == "GLOBAL_POSITION_INT":
            self._push(GlobalPosition(now, m.lat / 1e7, m.lon / 1e7, m.alt / 1000.0, m.relative_alt / 1000.0))
        elif t == "GPS_RAW_INT":
            self._gps_fix = m.fix_type
            eph = m.eph / 100.0 if m.eph != 65535 else 99.99
            self._push(GpsRaw(now, m.lat / 1e7, m.lon / 1e7, m.alt / 1000.0, m.fix_type, m.satellites_visible, eph))
        elif t == "SYS_STATUS":
            prearm = mavlink.MAV_SYS_STATUS_PREARM_CHECK
            if m.onboard_control_sensors_present & prearm:
                self._prearm_ok = bool(m.onboard_control_sensors_health & prearm)
            if m.battery_remaining >= 0:
                self._battery_pct = float(m.battery_remaining)
            self._push_status()
        elif t == "BATTERY_STATUS":
            if m.battery_remaining >= 0:
                self._battery_pct = float(m.battery_remaining)
        elif t == "EXTENDED_SYS_STATE":
            self._landed = LANDED_STATES.get(m.landed_state, LandedState.UNKNOWN)
            self._push_status()
        elif t == "HOME_POSITION":
            self._push(HomePosition(now, m.latitude / 1e7, m.longitude / 1e7, m.altitude / 1000.0, m.x, m.y, m.z))
        elif t == "STATUSTEXT":
            text = m.text if isinstance(m.text, str) else bytes(m.text).decode(errors="replace")
            text = text.rstrip("\x00")
            self._last_text = text
            self._texts_seen += 1
            log.info("autopilot: %s", text)
            self._push(StatusText(now, m.severity, text))
        elif t == "COMMAND_ACK":
            if m.target_system in (0, self.source_system):
                self._post(self._resolve_ack, m.command, m.result)
        elif t == "WIND":  # direction: where the wind comes from (deg); the air moves the other way
            d = math.radians(m.direction)
            self._post(self.telemetry.push_wind, Wind(now, -m.speed * math.cos(d), -m.speed * math.sin(d)))
        elif t == "WINCH_STATUS":
            self._post(self.telemetry.push_winch, WinchStatus(now, float(m.line_length), float(m.speed), int(m.status)))
        elif t in MISSION_MESSAGES:  # the fence transfer (ardupilot.fence), when one is running
            handler = getattr(self, "_on_mission_message", None)
            if handler is not None and m.target_system in (0, self.source_system):
                self._post(handler, m)
        elif t == "SERVO_OUTPUT_RAW":
            if m.port == 0:
                outs = [getattr(m, f"servo{i}_raw", 0) for i in range(1, 17)]
                self.servo_outputs = tuple(outs)
                self._servo_outputs_time = now
        elif t == "PARAM_VALUE":
            pid = m.param_id if isinstance(m.param_id, str) else bytes(m.param_id).decode(errors="replace")
            pid = pid.rstrip("\x00")
            if math.isfinite(m.param_value):
                self.params[pid] = float(m.param_value)
                self._post(self._resolve_param, pid, float(m.param_value))
        elif t == "SYSTEM_TIME":
            self._system_time = (int(m.time_unix_usec), time.time())
            self._post(self._resolve_system_time, self._system_time)
        elif t == "RC_CHANNELS":
            self.rc_channels = tuple(getattr(m, f"chan{i}_raw") for i in range(1, m.chancount + 1))
            self._post(self.telemetry.push_rc, RcInput(now, self.rc_channels))

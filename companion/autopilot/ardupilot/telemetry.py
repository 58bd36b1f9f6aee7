"""ArduPilot's MAVLink decoded into :mod:`companion.autopilot.types` samples, stamped on the
shell's monotonic clock at receipt (on the reader thread) and handed to the event loop for
:attr:`~companion.autopilot.interface.Autopilot.telemetry`. COMMAND_ACK, PARAM_VALUE and
SYSTEM_TIME resolve the requests waiting for them."""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Callable
from typing import Any

from companion.autopilot.ardupilot.dialect import mavlink
from companion.autopilot.ardupilot.fence import MISSION_MESSAGES
from companion.autopilot.ardupilot.modes import COPTER_TO_FLIGHT_MODE, LANDED_STATES
from companion.autopilot.ardupilot.requests import ArduPilotRequests
from companion.autopilot.interface import (
    RcInput,
)
from companion.autopilot.timesync import TimesyncRejection, log_clock_offset
from companion.autopilot.types import (
    Attitude,
    FlightMode,
    GlobalPosition,
    GpsRaw,
    HomePosition,
    Imu,
    LandedState,
    PositionNed,
    RangefinderReading,
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

    def _on_odid_arm_status(self, m: Any, now: float) -> None:
        """An OPEN_DRONE_ID_ARM_STATUS from the transponder, any system (:class:`~.remote_id.ArduPilotRemoteId`)."""

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
        """One received message: link errors and the messages of any source first, then the
        vehicle's own (the target system's), each to its handler in ``_VEHICLE_HANDLERS``."""
        t = m.get_type()
        if t == "BAD_DATA":
            self._on_bad_data(m)
            return
        now = time.monotonic()
        if t == "OPEN_DRONE_ID_ARM_STATUS":  # the Remote ID transponder, forwarded by the autopilot
            self._on_odid_arm_status(m, now)
            return
        if t == "COMMAND_LONG":  # from the operator's GCS (any system), for the companion's component
            self._on_component_command(m)
            return
        if t == "HEARTBEAT":
            self._on_heartbeat(m, now)
            return
        if self.target_system is None or m.get_srcSystem() != self.target_system:
            return
        self.counters.messages += 1
        self.counters.signed_from_vehicle += m.get_signed()
        self._last_rx = now
        handler = _VEHICLE_HANDLERS.get(t)
        if handler is not None:
            handler(self, m, now)

    def _foreign_heartbeat(self, sysid: int, compid: int) -> None:
        """An autopilot's HEARTBEAT from another system or component than the vehicle's: counted,
        logged sampled (the first, the 10th, 100th, every 1000th)."""
        self.foreign_heartbeats += 1
        n = self.foreign_heartbeats
        if n in (1, 10, 100) or n % 1000 == 0:
            log.warning(
                "autopilot HEARTBEAT from %d/%d ignored (%d so far): the vehicle is %s/%d on this link",
                sysid,
                compid,
                n,
                self.target_system,
                self.target_component,
            )

    def _on_bad_data(self, m: Any) -> None:
        """Bytes that did not parse, or a packet whose signature did not check (counted, said
        at the first, the 100th and every 1000th)."""
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

    def _on_heartbeat(self, m: Any, now: float) -> None:
        """A HEARTBEAT: the first autopilot's picks the target system; the target's gives the
        mode, arming and whether the vehicle signs."""
        if m.autopilot == mavlink.MAV_AUTOPILOT_INVALID or m.type == mavlink.MAV_TYPE_GCS:
            return  # a GCS or another companion
        src = m.get_srcSystem()
        if self.target_system is None:
            self.target_system = src
        if src != self.target_system or m.get_srcComponent() != self.target_component:
            self._foreign_heartbeat(src, m.get_srcComponent())  # never the vehicle's mode or armed state
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

    # ------------------------------------------------------------------ the vehicle's messages
    def _sample_time_s(self, m: Any, now: float) -> float:
        """A sample's time: its receipt (``now``), or with ``sample_time = "autopilot"`` its
        ``time_boot_ms`` on our clock through the TIMESYNC offset (docs/clock.md) -- the receipt
        again before the offset is known, or when the mapped time is not within (receipt - 1 s,
        receipt + the offset's uncertainty, best RTT + 3 jitters] (a wrapped or bogus stamp, a clock
        jump not yet confirmed); a mapped time after the receipt is the receipt."""
        offset = self._sample_offset
        if offset is None:
            return now
        t = offset.to_companion_s(int(m.time_boot_ms) / 1e3)
        age_s = now - t
        if not -(offset.rtt_min_s + 3.0 * offset.jitter_s) <= age_s < 1.0:
            self.sample_times_refused += 1
            return now
        self._sample_ages_s.append(age_s)
        if len(self._sample_ages_s) == self._sample_ages_s.maxlen:
            ages = sorted(self._sample_ages_s)
            self._sample_ages_s.clear()
            log.info(
                "autopilot samples arrive %.1f ms after their time_boot_ms (median of %d; 10-90 %%: %.1f-%.1f ms)",
                1e3 * ages[len(ages) // 2],
                len(ages),
                1e3 * ages[len(ages) // 10],
                1e3 * ages[(9 * len(ages)) // 10],
            )
        return min(t, now)

    def _on_attitude(self, m: Any, now: float) -> None:
        self._last_attitude = now
        t = self._sample_time_s(m, now) if self.sample_time == "autopilot" else now
        self._push(Attitude(t, m.roll, m.pitch, m.yaw, m.rollspeed, m.pitchspeed, m.yawspeed))

    def _on_highres_imu(self, m: Any, now: float) -> None:
        self._have_highres = True
        self._push(Imu(now, m.xacc, m.yacc, m.zacc, m.xgyro, m.ygyro, m.zgyro))

    def _on_raw_imu(self, m: Any, now: float) -> None:
        if self._have_highres:
            return  # HIGHRES_IMU is streamed: RAW_IMU's milli-g and mrad/s would repeat it coarser
        a = G / 1000.0
        self._push(Imu(now, m.xacc * a, m.yacc * a, m.zacc * a, m.xgyro / 1e3, m.ygyro / 1e3, m.zgyro / 1e3))

    def _on_local_position(self, m: Any, now: float) -> None:
        t = self._sample_time_s(m, now) if self.sample_time == "autopilot" else now
        self._push(PositionNed(t, m.x, m.y, m.z, m.vx, m.vy, m.vz))

    def _on_global_position(self, m: Any, now: float) -> None:
        t = self._sample_time_s(m, now) if self.sample_time == "autopilot" else now
        self._push(GlobalPosition(t, m.lat / 1e7, m.lon / 1e7, m.alt / 1000.0, m.relative_alt / 1000.0))

    def _on_gps_raw(self, m: Any, now: float) -> None:
        self._gps_fix = m.fix_type
        eph = m.eph / 100.0 if m.eph != 65535 else 99.99
        self._push(GpsRaw(now, m.lat / 1e7, m.lon / 1e7, m.alt / 1000.0, m.fix_type, m.satellites_visible, eph))

    def _on_sys_status(self, m: Any, now: float) -> None:
        prearm = mavlink.MAV_SYS_STATUS_PREARM_CHECK
        if m.onboard_control_sensors_present & prearm:
            self._prearm_ok = bool(m.onboard_control_sensors_health & prearm)
        if m.battery_remaining >= 0:
            self._battery_pct = float(m.battery_remaining)
        self._push_status()

    def _on_battery_status(self, m: Any, now: float) -> None:
        if m.battery_remaining >= 0:
            self._battery_pct = float(m.battery_remaining)

    def _on_extended_sys_state(self, m: Any, now: float) -> None:
        self._landed = LANDED_STATES.get(m.landed_state, LandedState.UNKNOWN)
        self._push_status()

    def _on_home_position(self, m: Any, now: float) -> None:
        self._push(HomePosition(now, m.latitude / 1e7, m.longitude / 1e7, m.altitude / 1000.0, m.x, m.y, m.z))

    def _on_statustext(self, m: Any, now: float) -> None:
        text = m.text if isinstance(m.text, str) else bytes(m.text).decode(errors="replace")
        text = text.rstrip("\x00")
        self._last_text = text
        self._texts_seen += 1
        log.info("autopilot: %s", text)
        self._push(StatusText(now, m.severity, text))

    def _on_command_ack(self, m: Any, now: float) -> None:
        if m.target_system in (0, self.source_system):
            self._post(self._resolve_ack, m.command, m.result)

    def _on_wind(self, m: Any, now: float) -> None:
        # direction: where the wind comes from (deg); the air moves the other way
        d = math.radians(m.direction)
        self._post(self.telemetry.push_wind, Wind(now, -m.speed * math.cos(d), -m.speed * math.sin(d)))

    def _on_distance_sensor(self, m: Any, now: float) -> None:
        # centimetres; signal_quality 0: not known (ArduPilot sends 0 when its backend has none)
        q = int(m.signal_quality)
        reading = RangefinderReading(
            now,
            m.current_distance / 100.0,
            m.min_distance / 100.0,
            m.max_distance / 100.0,
            int(m.orientation),
            q if q > 0 else None,
        )
        self._post(self.telemetry.push_rangefinder, reading)

    def _on_winch_status(self, m: Any, now: float) -> None:
        status = WinchStatus(now, float(m.line_length), float(m.speed), int(m.status), float(m.tension))
        self._post(self.telemetry.push_winch, status)

    def _on_mission(self, m: Any, now: float) -> None:
        """The fence transfer's messages (ardupilot.fence), when one is running."""
        handler = getattr(self, "_on_mission_message", None)
        if handler is not None and m.target_system in (0, self.source_system):
            self._post(handler, m)

    def _on_servo_output_raw(self, m: Any, now: float) -> None:
        if m.port == 0:
            outs = [getattr(m, f"servo{i}_raw", 0) for i in range(1, 17)]
            self.servo_outputs = tuple(outs)
            self._servo_outputs_time = now

    def _on_param_value(self, m: Any, now: float) -> None:
        pid = m.param_id if isinstance(m.param_id, str) else bytes(m.param_id).decode(errors="replace")
        pid = pid.rstrip("\x00")
        if math.isfinite(m.param_value):
            self.params[pid] = float(m.param_value)
            self._post(self._resolve_param, pid, float(m.param_value))

    def _on_system_time(self, m: Any, now: float) -> None:
        self._system_time = (int(m.time_unix_usec), time.time())
        self._post(self._resolve_system_time, self._system_time)

    def _on_timesync(self, m: Any, now: float) -> None:
        """An autopilot's TIMESYNC answer to ours (docs/clock.md), stamped at receipt in ns; its own
        requests (tc1 = 0) and other components' answers are not ours to take."""
        est = self.timesync
        if est is None or m.get_srcComponent() != self.target_component or int(m.tc1) == 0:
            return
        with self._timesync_lock:
            outcome = est.on_timesync(int(m.tc1), int(m.ts1), time.monotonic_ns())
            offset = est.estimate
            accepted = est.accepted
        self._sample_offset = offset  # the samples' mapping (sample_time = "autopilot"), same thread
        if isinstance(outcome, TimesyncRejection):
            n = est.rejected[outcome]
            if n in (1, 10) or n % 100 == 0:
                log.warning("TIMESYNC answer tc1=%d ts1=%d rejected: %s (%d so far)", m.tc1, m.ts1, outcome.value, n)
            return
        if offset is not None and (self._timesync_logged < 0 or accepted - self._timesync_logged >= 60):
            self._timesync_logged = accepted
            log_clock_offset(log, offset)

    def _on_rc_channels(self, m: Any, now: float) -> None:
        self.rc_channels = tuple(getattr(m, f"chan{i}_raw") for i in range(1, m.chancount + 1))
        self._post(self.telemetry.push_rc, RcInput(now, self.rc_channels))


# the target system's messages, each to its handler (the fence transfer's to the one for all of them)
_VEHICLE_HANDLERS: dict[str, Callable[[ArduPilotTelemetry, Any, float], None]] = {
    "ATTITUDE": ArduPilotTelemetry._on_attitude,
    "HIGHRES_IMU": ArduPilotTelemetry._on_highres_imu,
    "RAW_IMU": ArduPilotTelemetry._on_raw_imu,
    "LOCAL_POSITION_NED": ArduPilotTelemetry._on_local_position,
    "GLOBAL_POSITION_INT": ArduPilotTelemetry._on_global_position,
    "GPS_RAW_INT": ArduPilotTelemetry._on_gps_raw,
    "SYS_STATUS": ArduPilotTelemetry._on_sys_status,
    "BATTERY_STATUS": ArduPilotTelemetry._on_battery_status,
    "EXTENDED_SYS_STATE": ArduPilotTelemetry._on_extended_sys_state,
    "HOME_POSITION": ArduPilotTelemetry._on_home_position,
    "STATUSTEXT": ArduPilotTelemetry._on_statustext,
    "COMMAND_ACK": ArduPilotTelemetry._on_command_ack,
    "WIND": ArduPilotTelemetry._on_wind,
    "WINCH_STATUS": ArduPilotTelemetry._on_winch_status,
    "DISTANCE_SENSOR": ArduPilotTelemetry._on_distance_sensor,
    **dict.fromkeys(MISSION_MESSAGES, ArduPilotTelemetry._on_mission),
    "SERVO_OUTPUT_RAW": ArduPilotTelemetry._on_servo_output_raw,
    "PARAM_VALUE": ArduPilotTelemetry._on_param_value,
    "SYSTEM_TIME": ArduPilotTelemetry._on_system_time,
    "RC_CHANNELS": ArduPilotTelemetry._on_rc_channels,
    "TIMESYNC": ArduPilotTelemetry._on_timesync,
}

"""PX4 telemetry through MAVSDK's async streams, one task per stream (cancelled, and so
unsubscribed, on close), stamped on the shell's clock; HEARTBEAT, HOME_POSITION and RC_CHANNELS
come whole through MavlinkDirect. With ``setpoint_transport="offboard"`` a guard stops MAVSDK's
offboard re-send once the shell stops refreshing the setpoint."""

from __future__ import annotations

import asyncio
import contextlib
import json
import logging
import math
import time
from collections.abc import AsyncIterator, Callable
from typing import Any

from companion.autopilot.interface import (
    RcInput,
)
from companion.autopilot.px4.link import Px4Link
from companion.autopilot.timesync import TimesyncRejection, log_clock_offset
from companion.autopilot.types import (
    MAV_SENSOR_ROTATION_PITCH_270,
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
    VehicleStatus,
    Wind,
)

log = logging.getLogger(__name__)

STREAM_RESUBSCRIBE_S = 1.0  # a MAVSDK stream that ended or raised is subscribed again after this
MAV_MODE_FLAG_SAFETY_ARMED = 128
MAV_AUTOPILOT_INVALID = 8
MAV_TYPE_GCS = 6
RANGEFINDER_RATE_HZ = 10.0
MAV_SENSOR_ROTATION_OTHER = 100  # MAV_SENSOR_ROTATION_CUSTOM: what is not downward here

_FLIGHT_MODES = {
    "UNKNOWN": FlightMode.UNKNOWN,
    "READY": FlightMode.HOLD,
    "TAKEOFF": FlightMode.TAKEOFF,
    "HOLD": FlightMode.HOLD,
    "MISSION": FlightMode.MISSION,
    "RETURN_TO_LAUNCH": FlightMode.RTL,
    "LAND": FlightMode.LAND,
    "OFFBOARD": FlightMode.OFFBOARD,
    "FOLLOW_ME": FlightMode.MISSION,
    "MANUAL": FlightMode.MANUAL,
    "ALTCTL": FlightMode.MANUAL,
    "POSCTL": FlightMode.POSITION,
    "ACRO": FlightMode.MANUAL,
    "STABILIZED": FlightMode.MANUAL,
    "RATTITUDE": FlightMode.MANUAL,
}
_LANDED = {
    "UNKNOWN": LandedState.UNKNOWN,
    "ON_GROUND": LandedState.ON_GROUND,
    "IN_AIR": LandedState.IN_AIR,
    "TAKING_OFF": LandedState.TAKING_OFF,
    "LANDING": LandedState.LANDING,
}
_SEVERITY = {"EMERGENCY": 0, "ALERT": 1, "CRITICAL": 2, "ERROR": 3, "WARNING": 4, "NOTICE": 5, "INFO": 6, "DEBUG": 7}


_PX4_AUTO_SUB = {
    1: FlightMode.HOLD,  # AUTO.READY
    2: FlightMode.TAKEOFF,
    3: FlightMode.HOLD,  # AUTO.LOITER
    4: FlightMode.MISSION,
    5: FlightMode.RTL,
    6: FlightMode.LAND,
    8: FlightMode.MISSION,  # follow target
    9: FlightMode.LAND,  # precision land
}
_PX4_MAIN = {
    1: FlightMode.MANUAL,
    2: FlightMode.MANUAL,  # ALTCTL
    3: FlightMode.POSITION,  # POSCTL
    5: FlightMode.MANUAL,  # ACRO
    6: FlightMode.OFFBOARD,
    7: FlightMode.MANUAL,  # STABILIZED
    8: FlightMode.MANUAL,  # RATTITUDE
}


def px4_flight_mode(custom_mode: int) -> FlightMode:
    """PX4 HEARTBEAT custom_mode (main mode << 16 | sub mode << 24) -> :class:`FlightMode`."""
    main, sub = (custom_mode >> 16) & 0xFF, (custom_mode >> 24) & 0xFF
    if main == 4:  # AUTO
        return _PX4_AUTO_SUB.get(sub, FlightMode.UNKNOWN)
    return _PX4_MAIN.get(main, FlightMode.UNKNOWN)


def flight_mode_from_mavsdk(mode: Any) -> FlightMode:
    return _FLIGHT_MODES.get(getattr(mode, "name", str(mode)), FlightMode.UNKNOWN)


# a MAVSDK stream: its subscribe call and the handler of its items
_Stream = tuple[Callable[[], AsyncIterator[Any]], Callable[[Any], None]]


class Px4Telemetry(Px4Link):
    """The telemetry streams, the connection watch and the stale-setpoint guard."""

    want_wind = False  # subscribe to the wind estimate ([go_no_go] wind_limit_m_s)
    want_rangefinder = False  # subscribe to DISTANCE_SENSOR ([mission.rangefinder] enabled)
    # [runtime] autopilot_attitude_rate_hz / autopilot_position_rate_hz (None: PX4's own rates)
    attitude_rate_hz: float | None = None
    position_rate_hz: float | None = None

    async def _set_stream_rates(self) -> None:
        """Ask PX4 for the configured rates (MAVSDK's set_rate_*: SET_MESSAGE_INTERVAL). A rate
        refused is a warning: the stream goes on at PX4's own rate."""
        tel = self._tel
        asks = [
            ("attitude", tel.set_rate_attitude_euler, self.attitude_rate_hz),
            # ATTITUDE_QUATERNION (onboard mode: 50 Hz) feeds MAVSDK's angular velocity stream too
            ("attitude quaternion", tel.set_rate_attitude_quaternion, self.attitude_rate_hz),
            ("IMU", tel.set_rate_imu, self.attitude_rate_hz),
            ("local position", tel.set_rate_position_velocity_ned, self.position_rate_hz),
            ("global position", tel.set_rate_position, self.position_rate_hz),
        ]
        for what, set_rate, hz in asks:
            if hz is None:
                continue
            try:
                await set_rate(hz)
            except Exception as err:  # MAVSDK's TelemetryError, or the link gone meanwhile
                log.warning("PX4 did not take %s at %g Hz (%s): it streams at its own rate", what, hz, err)
            else:
                log.info("PX4 streams %s at %g Hz", what, hz)

    def _start_streams(self) -> None:
        """One task per MAVSDK stream and per MavlinkDirect message, the connection watch, the
        stream rates asked for and (offboard transport) the stale-setpoint guard."""
        loop = asyncio.get_running_loop()

        def now() -> float:
            return loop.time()

        streams = self._motion_streams(now) + self._state_streams(now)
        if self.want_wind:
            tel = self._tel

            def on_wind(w: Any) -> None:  # MAVSDK's Wind: PX4's WIND_COV, where the air moves, NED
                self.telemetry.push_wind(Wind(now(), w.wind_x_ned_m_s, w.wind_y_ned_m_s))

            streams.append((tel.subscribe_wind, on_wind))
        if self.want_rangefinder:
            streams.append((self._tel.subscribe_distance_sensor, self._rangefinder_handler(now)))
            self._tasks.append(loop.create_task(self._rangefinder_rate(), name="px4-rangefinder-rate"))
        for sub, fn in streams:
            self._tasks.append(loop.create_task(self._consume(sub, fn), name=f"px4-{fn.__name__}"))
        for message, fn in self._direct_streams(now):
            self._tasks.append(loop.create_task(self._consume(self._direct_subscription(message), fn)))
        self._tasks.append(loop.create_task(self._watch_connection(), name="px4-connection"))
        if self.timesync is not None:  # docs/clock.md
            on_ts = self._on_timesync
            self._tasks.append(loop.create_task(self._consume(self._direct_subscription("TIMESYNC"), on_ts)))
            self._tasks.append(loop.create_task(self._timesync_requests(), name="px4-timesync"))
        if self.attitude_rate_hz is not None or self.position_rate_hz is not None:
            self._tasks.append(loop.create_task(self._set_stream_rates(), name="px4-stream-rates"))
        if self.setpoint_transport == "offboard":
            self._tasks.append(loop.create_task(self._stale_guard(), name="px4-stale-guard"))

    def _rangefinder_handler(self, now: Callable[[], float]) -> Callable[[Any], None]:
        """MAVSDK's DistanceSensor (DISTANCE_SENSOR in metres, its orientation as Euler angles in
        degrees: PX4 SIH's MAV_SENSOR_ROTATION_PITCH_270 comes as pitch 270 or -90) as a reading;
        MAVSDK passes no signal quality."""

        def on_distance_sensor(d: Any) -> None:
            o = d.orientation
            down = abs(o.roll_deg) < 1.0 and abs((o.pitch_deg % 360.0) - 270.0) < 1.0
            orientation = MAV_SENSOR_ROTATION_PITCH_270 if down else MAV_SENSOR_ROTATION_OTHER
            r = RangefinderReading(now(), d.current_distance_m, d.minimum_distance_m, d.maximum_distance_m, orientation)
            self.telemetry.push_rangefinder(r)

        return on_distance_sensor

    async def _rangefinder_rate(self) -> None:
        """DISTANCE_SENSOR at RANGEFINDER_RATE_HZ (PX4 SIH's onboard link streams it at 10 Hz anyway)."""
        try:
            await self._tel.set_rate_distance_sensor(RANGEFINDER_RATE_HZ)
        except Exception as err:  # MAVSDK's TelemetryError, or the link gone meanwhile
            log.warning("PX4 did not take DISTANCE_SENSOR at %g Hz (%s)", RANGEFINDER_RATE_HZ, err)

    async def _timesync_requests(self) -> None:
        """TIMESYNC(tc1 = 0, ts1 = our monotonic clock, ns) through MavlinkDirect every
        ``timesync_period_s``: PX4 answers with its boot time (docs/clock.md)."""
        from mavsdk.plugins.mavlink_direct import MavlinkMessage

        assert self.timesync is not None
        while True:
            _, ts1 = self.timesync.request(time.monotonic_ns())
            fields = f'{{"tc1":0,"ts1":{ts1},"target_system":{self.system_id},"target_component":1}}'
            try:
                self._direct_sync.send_message(MavlinkMessage("TIMESYNC", 0, 0, self.system_id, 1, fields))
            except Exception as err:  # a link down: the next request goes out on time
                log.debug("TIMESYNC request not sent: %s", err)
            await asyncio.sleep(self.timesync_period_s)

    def _on_timesync(self, m: Any) -> None:
        """PX4's TIMESYNC, stamped as MavlinkDirect hands it over (after MAVSDK's own hop: the RTT,
        and the offset's error bound RTT / 2, include it). MAVSDK's own exchanges with PX4 come
        through too: their ts1 are not ours (rejected as unknown, not said)."""
        est = self.timesync
        if est is None or m.system_id != self.system_id or m.component_id != 1:
            return
        now_ns = time.monotonic_ns()
        f = json.loads(m.fields_json)
        tc1, ts1 = int(f["tc1"]), int(f["ts1"])
        if tc1 == 0:
            return  # a request (PX4's own, which MAVSDK answers)
        outcome = est.on_timesync(tc1, ts1, now_ns)
        if isinstance(outcome, TimesyncRejection):
            n = est.rejected[outcome]
            if outcome is not TimesyncRejection.UNKNOWN_REQUEST and (n in (1, 10) or n % 100 == 0):
                log.warning("TIMESYNC answer tc1=%d ts1=%d rejected: %s (%d so far)", tc1, ts1, outcome.value, n)
            return
        offset = est.estimate
        if offset is not None and (self._timesync_logged < 0 or est.accepted - self._timesync_logged >= 60):
            self._timesync_logged = est.accepted
            log_clock_offset(log, offset)

    def _direct_subscription(self, message: str) -> Callable[[], AsyncIterator[Any]]:
        """MavlinkDirect's stream of one message by name, subscribed anew at each call."""
        return lambda: self._direct.subscribe_message(message)

    def _motion_streams(self, now: Callable[[], float]) -> list[_Stream]:
        """The streams of where the vehicle is and how it moves: position, attitude, IMU, GPS."""
        tel = self._tel

        def on_pv(pv: Any) -> None:
            p, v = pv.position, pv.velocity
            self._push(PositionNed(now(), p.north_m, p.east_m, p.down_m, v.north_m_s, v.east_m_s, v.down_m_s))

        def on_pos(p: Any) -> None:
            self._push(
                GlobalPosition(now(), p.latitude_deg, p.longitude_deg, p.absolute_altitude_m, p.relative_altitude_m)
            )

        def on_att(e: Any) -> None:
            r = math.radians
            self._push(Attitude(now(), r(e.roll_deg), r(e.pitch_deg), r(e.yaw_deg), *self._rates))

        def on_rates(w: Any) -> None:
            self._rates = (w.roll_rad_s, w.pitch_rad_s, w.yaw_rad_s)

        def on_imu(i: Any) -> None:
            a, g = i.acceleration_frd, i.angular_velocity_frd
            self._push(
                Imu(now(), a.forward_m_s2, a.right_m_s2, a.down_m_s2, g.forward_rad_s, g.right_rad_s, g.down_rad_s)
            )

        def on_gps_info(gi: Any) -> None:
            self._gps_fix = int(getattr(gi.fix_type, "value", gi.fix_type))
            self._gps_sats = int(gi.num_satellites)

        def on_raw_gps(g: Any) -> None:
            eph = g.horizontal_uncertainty_m if math.isfinite(g.horizontal_uncertainty_m) else g.hdop
            eph = eph if math.isfinite(eph) else 99.99
            self._push(
                GpsRaw(
                    now(), g.latitude_deg, g.longitude_deg, g.absolute_altitude_m, self._gps_fix, self._gps_sats, eph
                )
            )

        return [
            (tel.subscribe_position_velocity_ned, on_pv),
            (tel.subscribe_position, on_pos),
            (tel.subscribe_attitude_euler, on_att),
            (tel.subscribe_attitude_angular_velocity_body, on_rates),
            (tel.subscribe_imu, on_imu),
            (tel.subscribe_gps_info, on_gps_info),
            (tel.subscribe_raw_gps, on_raw_gps),
        ]

    def _state_streams(self, now: Callable[[], float]) -> list[_Stream]:
        """The streams of the vehicle's state: mode, arming, landed state, battery, health,
        status texts, home."""
        tel = self._tel

        def on_mode(m: Any) -> None:
            self._mode = flight_mode_from_mavsdk(m)
            self._push_status()

        def on_armed(a: bool) -> None:
            self._armed = bool(a)
            self._push_status()

        def on_landed(s: Any) -> None:
            self._landed = _LANDED.get(getattr(s, "name", ""), LandedState.UNKNOWN)
            self._push_status()

        def on_battery(b: Any) -> None:
            pct = b.remaining_percent
            if math.isfinite(pct):
                self._battery_pct = pct * 100.0 if pct <= 1.0 else pct

        def on_health(h: Any) -> None:
            self._health = h
            self._healthy = bool(h.is_armable and h.is_global_position_ok and h.is_home_position_ok)
            self._push_status()

        def on_text(st: Any) -> None:
            text = str(st.text)
            self._last_text = text
            self._texts_seen += 1
            log.info("autopilot: %s", text)
            self._push(StatusText(now(), _SEVERITY.get(getattr(st.type, "name", ""), 6), text))

        def on_home(h: Any) -> None:
            pass  # MAVSDK's home stream keeps HOME_POSITION coming; on_home_position reads it whole

        return [
            (tel.subscribe_flight_mode, on_mode),
            (tel.subscribe_armed, on_armed),
            (tel.subscribe_landed_state, on_landed),
            (tel.subscribe_battery, on_battery),
            (tel.subscribe_health, on_health),
            (tel.subscribe_status_text, on_text),
            (tel.subscribe_home, on_home),
        ]

    def _direct_streams(self, now: Callable[[], float]) -> list[tuple[str, Callable[[Any], None]]]:
        """The messages MavlinkDirect brings whole (message name, handler): HEARTBEAT,
        HOME_POSITION and RC_CHANNELS, the vehicle's only."""

        def on_heartbeat(m: Any) -> None:
            try:
                hb = json.loads(m.fields_json)
            except ValueError:
                self.decode_errors += 1
                return
            if m.system_id != self.system_id or m.component_id != 1:
                # a GCS's or a companion's is not an autopilot's; any other never sets mode or armed
                if int(hb.get("autopilot", 0)) != MAV_AUTOPILOT_INVALID and int(hb.get("type", 0)) != MAV_TYPE_GCS:
                    self._foreign_heartbeat(int(m.system_id), int(m.component_id))
                return
            self._last_hb = time.monotonic()
            self._armed = bool(int(hb.get("base_mode", 0)) & MAV_MODE_FLAG_SAFETY_ARMED)
            self._mode = px4_flight_mode(int(hb.get("custom_mode", 0)))
            self._push_status()

        def on_home_position(m: Any) -> None:  # with x/y/z: home in PX4's local frame
            if m.system_id != self.system_id:
                return
            try:
                f = json.loads(m.fields_json)
                home = HomePosition(
                    now(),
                    int(f["latitude"]) / 1e7,
                    int(f["longitude"]) / 1e7,
                    int(f["altitude"]) / 1000.0,
                    float(f.get("x", 0.0)),
                    float(f.get("y", 0.0)),
                    float(f.get("z", 0.0)),
                )
            except (ValueError, TypeError, KeyError, OverflowError) as err:
                self.decode_errors += 1
                log.warning("HOME_POSITION not understood (%s): %s", err, m.fields_json)
                return
            self._push(home)

        def on_rc_channels(m: Any) -> None:  # the receiver's raw channels (Dart: pilot sticks, switch)
            if m.system_id != self.system_id:
                return
            try:
                f = json.loads(m.fields_json)
                n = max(0, min(18, int(f.get("chancount", 18))))
                chans = tuple(int(f.get(f"chan{i}_raw", 0)) for i in range(1, n + 1))
            except (ValueError, TypeError):
                self.decode_errors += 1
                return
            self.telemetry.push_rc(RcInput(now(), chans))

        return [("HEARTBEAT", on_heartbeat), ("HOME_POSITION", on_home_position), ("RC_CHANNELS", on_rc_channels)]

    async def _consume(self, subscribe: Callable[[], AsyncIterator[Any]], fn: Callable[[Any], None]) -> None:
        """One MAVSDK stream into ``fn``, for as long as the task runs. A stream that ends or
        raises is said once and subscribed again after ``STREAM_RESUBSCRIBE_S`` (counted in
        ``streams_restarted``): a stream lost silently would freeze that part of the telemetry
        (a landed state that never changes again leaves a landing that never ends)."""
        name = fn.__name__
        while True:
            gen = subscribe()
            why = "ended"
            try:
                async for item in gen:
                    self._last_rx = time.monotonic()
                    try:
                        fn(item)
                    except Exception:
                        self.decode_errors += 1  # the item is dropped; the stream goes on
                        if self.decode_errors in (1, 100) or self.decode_errors % 10000 == 0:
                            log.exception("error decoding %s (%d so far)", name, self.decode_errors)
            except Exception as err:  # (a cancellation is not one: it ends the task)
                why = f"failed ({type(err).__name__}: {err})"
            finally:
                with contextlib.suppress(Exception):
                    await gen.aclose()  # type: ignore[attr-defined]
            self.streams_restarted += 1
            log.warning("MAVSDK stream %s %s: subscribing again in %.1f s", name, why, STREAM_RESUBSCRIBE_S)
            await asyncio.sleep(STREAM_RESUBSCRIBE_S)

    async def _watch_connection(self) -> None:
        gen = self._system.is_connected_state()
        try:
            async for connected in gen:
                if connected != self._connected:
                    log.warning("PX4 link %s", "restored" if connected else "lost (no heartbeat for 3 s)")
                self._connected = bool(connected)
        finally:
            with contextlib.suppress(Exception):
                await gen.aclose()

    async def _stale_guard(self) -> None:
        """Offboard-plugin transport: stop MAVSDK's 20 Hz re-send once the shell stops refreshing."""
        while True:
            await asyncio.sleep(0.1)
            if self._plugin_streaming and time.monotonic() - self._last_sp_call > self.setpoint_stale_s:
                self._plugin_streaming = False
                if self._mode is FlightMode.OFFBOARD:
                    log.error("setpoints stale: stopping MAVSDK's offboard re-send (PX4 switches to HOLD)")
                    with contextlib.suppress(Exception):
                        await self._offboard.stop()

    def _foreign_heartbeat(self, sysid: int, compid: int) -> None:
        """An autopilot's HEARTBEAT from another system or component than the vehicle's: counted,
        logged sampled (the first, the 10th, 100th, every 1000th)."""
        self.foreign_heartbeats += 1
        n = self.foreign_heartbeats
        if n in (1, 10, 100) or n % 1000 == 0:
            log.warning(
                "autopilot HEARTBEAT from %d/%d ignored (%d so far): the vehicle is %d/1 on this link",
                sysid,
                compid,
                n,
                self.system_id,
            )

    def _push(self, sample: Any) -> None:
        self.telemetry.push(sample)

    def _push_status(self) -> None:
        self._push(
            VehicleStatus(
                time.monotonic(),
                self._armed,
                self._mode,
                self._landed,
                self._healthy,
                self._battery_pct,
                self._payload_released,
            )
        )

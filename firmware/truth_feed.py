"""Ground truth from a running autopilot simulation, for rendering the landing sensors.

PX4's SIH (and our MAVLink sim vehicle) stream the simulated vehicle's true state as
HIL_STATE_QUATERNION when asked with SET_MESSAGE_INTERVAL. :class:`MavlinkTruth` listens on its
own MAVLink link (for PX4 SITL the GCS link, ``udpin:127.0.0.1:14550``; for the sim vehicle a
``udpout`` to its port), asks for that message and exposes the truth the way the simulated camera
and UWB read a :class:`~companion_sitl.vehicle.SimVehicle` (``pn``/``pe``/``pd`` metres NED from
an origin, ``roll``/``pitch``/``yaw`` radians, ``step_to``), so
:func:`companion_sitl.landing_sensors.sim_landing_kit` renders real images of a pad whose true position is
displaced from the configured one (SIH cannot bias GPS; displacing the pad tests the same thing).

ArduPilot's SITL offers the same as SIM_STATE (message 108, ``message="SIM_STATE"``): its
physics' true attitude quaternion, latitude/longitude (``lat_int``/``lon_int``, degE7) and
altitude (m AMSL), sent on any link that asks with SET_MESSAGE_INTERVAL (its float
``lat``/``lon`` fields carry degE7 too on ArduCopter 4.7, so the integer ones are preferred).
SIMSTATE (164) carries no altitude and is not used.

Both messages carry latitude and longitude as degE7 integers that the firmware truncates (C's
``(int32_t)(deg * 1e7)``, toward zero: ArduPilot's ``SIM::sim_state_send``, PX4's
HIL_STATE_QUATERNION stream): a 1.11 cm step in latitude and 0.91 cm in longitude at CMAC. Read as
they are, the truth jumps on that grid: the simulated camera and UWB then see the vehicle standing
still and leaping a centimetre, and the touchdown is scored to the centimetre.
:class:`DegE7Dequantiser` recovers the position inside the step from the message's own
velocity (float m/s in SIM_STATE, cm/s in HIL_STATE_QUATERNION), holding it inside the step the
integer allows.

The reader is a thread; the newest sample is swapped in as one tuple, so readers on the event loop
never see a torn state.
"""

from __future__ import annotations

import logging
import math
import os
import threading
import time
from typing import Any

os.environ.setdefault("MAVLINK20", "1")
from pymavlink import mavutil

from companion.geometry.earth import GeoPoint, LocalTangentPlane, radii_of_curvature
from companion.geometry.rotations import quat_to_euler

log = logging.getLogger(__name__)

MSG_ID_HIL_STATE_QUATERNION = 115
MSG_ID_SIM_STATE = 108
TRUTH_MESSAGES = {"HIL_STATE_QUATERNION": MSG_ID_HIL_STATE_QUATERNION, "SIM_STATE": MSG_ID_SIM_STATE}
MAV_CMD_SET_MESSAGE_INTERVAL = 511
SERIAL_CONTROL_DEV_SHELL = 10
SERIAL_CONTROL_FLAG_RESPOND = 2
SERIAL_CONTROL_FLAG_EXCLUSIVE = 4


DEG_E7_PER_RAD = 1e7 * 180.0 / math.pi
MAX_INTEGRATION_GAP_S = 0.5  # a longer gap between samples starts the dequantiser afresh


class DegE7Dequantiser:
    """The true value behind a degE7 integer ``q`` that the firmware truncated toward zero (C's
    ``(int32_t)(deg * 1e7)``): the value lies in [q, q + 1) for q > 0, (q - 1, q] for q < 0 and
    (-1, 1) for q = 0 (units of 1e-7 deg).

    Each update moves the previous value by what the velocity says the vehicle moved (``step``,
    degE7) and clamps it into the step ``q`` allows: a moving vehicle crossing a step edge pins the
    value to that edge, so it stays within a fraction of a step of the truth (set membership; no
    tuning); a vehicle at rest keeps its value inside the step. The first update, and one whose
    ``step`` is not finite (the samples were too far apart to integrate), take the middle of the
    step."""

    def __init__(self) -> None:
        self.value: float | None = None

    @staticmethod
    def bounds(q: int) -> tuple[float, float]:
        if q > 0:
            return float(q), float(q + 1)
        if q < 0:
            return float(q - 1), float(q)
        return -1.0, 1.0

    def update(self, q: int, step: float) -> float:
        lo, hi = self.bounds(q)
        x = 0.5 * (lo + hi) if self.value is None or not math.isfinite(step) else self.value + step
        self.value = min(max(x, lo), hi)
        return self.value


def _mid_cm_s(c: int) -> float:
    """The middle of the 1 cm/s step an integer truncated toward zero stands for, in m/s."""
    return (c + 0.5 * (c > 0) - 0.5 * (c < 0)) * 0.01


class TruthUnavailable(RuntimeError):
    """No ground truth arrived (the reason says from where and for how long)."""


class MavlinkTruth:
    """HIL_STATE_QUATERNION (PX4 SIH, our sim vehicle) or SIM_STATE (ArduPilot SITL) ground truth
    over MAVLink (see the module doc).

    ``origin``: the NED origin (the true home); None takes the first sample's position, which is
    home when the feed starts with the vehicle on the ground.
    """

    def __init__(
        self,
        url: str,
        origin: GeoPoint | None = None,
        rate_hz: float = 50.0,
        source_system: int = 246,
        message: str = "HIL_STATE_QUATERNION",
        watch: tuple[str, ...] = (),
    ):
        if not (math.isfinite(rate_hz) and 0.5 <= rate_hz <= 1000.0):
            raise ValueError(f"truth rate {rate_hz!r} Hz: expected 0.5..1000")
        if message not in TRUTH_MESSAGES:
            raise ValueError(f"truth message {message!r}: expected one of {sorted(TRUTH_MESSAGES)}")
        self.message = message
        self.url = url
        self.rate_hz = rate_hz
        self.source_system = source_system
        self._ltp = LocalTangentPlane(origin) if origin is not None else None
        self._state: tuple[float, ...] | None = None  # t, n, e, d, r, p, y, vn, ve, vd
        self._conn: Any = None
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.samples = 0
        self.rejected = 0
        self._target: tuple[int, int] | None = None
        self._last_request = -math.inf
        self._lat = DegE7Dequantiser()
        self._lon = DegE7Dequantiser()
        self._last_fix: tuple[float, float, float] | None = None  # sample time s, vn, ve (m/s)
        self.params: dict[str, float] = {}  # PARAM_VALUE answers seen on this link
        self.acks: dict[int, int] = {}  # command id -> MAV_RESULT of its last COMMAND_ACK
        self.shell_out = bytearray()  # PX4's shell output over SERIAL_CONTROL (:meth:`shell`)
        # the autopilot's (component 1) messages of the ``watch`` types, kept with their arrival
        # time (monotonic s): HEARTBEAT, EXTENDED_SYS_STATE, SERVO_OUTPUT_RAW for a test to follow
        self.watch = frozenset(watch)
        self.watched: list[tuple[float, Any]] = []
        self._watch_lock = threading.Lock()

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> MavlinkTruth:
        try:
            self._conn = mavutil.mavlink_connection(self.url, source_system=self.source_system, source_component=0)
        except OSError as err:
            raise TruthUnavailable(f"ground truth link {self.url!r} cannot be opened: {err}") from err
        self._thread = threading.Thread(target=self._run, name="truth-feed", daemon=True)
        self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._conn is not None:
            self._conn.close()
            self._conn = None

    def __enter__(self) -> MavlinkTruth:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def wait(self, timeout_s: float = 10.0) -> None:
        """Block until the first truth sample (raises :class:`TruthUnavailable` after ``timeout_s``)."""
        t_end = time.monotonic() + timeout_s
        while self._state is None:
            if time.monotonic() > t_end:
                raise TruthUnavailable(
                    f"no {self.message} on {self.url!r} within {timeout_s} s "
                    f"(heartbeat seen: {self._target is not None})"
                )
            time.sleep(0.02)

    # ------------------------------------------------------------------ reader thread
    def _run(self) -> None:
        conn = self._conn
        while not self._stop.is_set():
            if self._target is None or time.monotonic() - self._last_request > 2.0:
                self._request(conn)
            try:
                msg = conn.recv_match(blocking=True, timeout=0.1)
            except Exception as err:  # malformed bytes: pymavlink raises on some; count and go on
                self.rejected += 1
                log.debug("truth feed: bad packet dropped: %s", err)
                continue
            if msg is None:
                continue
            kind = msg.get_type()
            if kind in self.watch and msg.get_srcComponent() == 1:
                with self._watch_lock:
                    self.watched.append((time.monotonic(), msg))
            if kind == "HEARTBEAT" and self._target is None and msg.get_srcComponent() == 1:
                self._target = (msg.get_srcSystem(), msg.get_srcComponent())
                self._last_request = -math.inf
            elif kind == "PARAM_VALUE":
                self.params[str(msg.param_id)] = float(msg.param_value)
            elif kind == "COMMAND_ACK":
                self.acks[int(msg.command)] = int(msg.result)
            elif kind == "SERIAL_CONTROL" and msg.device == SERIAL_CONTROL_DEV_SHELL:
                self.shell_out += bytes(msg.data[: msg.count])
            elif kind == "HIL_STATE_QUATERNION" == self.message:
                self._on_truth(msg)
            elif kind == "SIM_STATE" == self.message:
                self._on_sim_state(msg)

    def _until_answered(self, what: str, send: Any, answer: Any, timeout_s: float) -> Any:
        """Call ``send(mav)`` every 0.5 s until ``answer()`` is not None (read by the reader
        thread); raises TimeoutError after ``timeout_s``."""
        if self._target is None or self._conn is None:
            raise TruthUnavailable(f"no autopilot heartbeat on {self.url!r}: cannot send {what}")
        t_end = time.monotonic() + timeout_s
        while time.monotonic() < t_end:
            send(self._conn.mav)
            t_next = min(t_end, time.monotonic() + 0.5)
            while time.monotonic() < t_next:
                got = answer()
                if got is not None:
                    return got
                time.sleep(0.02)
        raise TimeoutError(f"{what}: no answer from the autopilot within {timeout_s} s")

    def set_param(self, name: str, value: float, timeout_s: float = 5.0) -> None:
        """PARAM_SET on this link (a simulator setting such as ArduPilot's SIM_WIND_SPD), resent
        every 0.5 s until the autopilot echoes the value; raises TimeoutError otherwise."""
        ts, tc = self._target or (0, 0)
        self.params.pop(name, None)

        def echoed() -> bool | None:
            got = self.params.get(name)
            return True if got is not None and abs(got - value) <= 1e-4 * max(1.0, abs(value)) else None

        self._until_answered(
            f"{name} = {value}",
            lambda mav: mav.param_set_send(ts, tc, name.encode(), float(value), mavutil.mavlink.MAV_PARAM_TYPE_REAL32),
            echoed,
            timeout_s,
        )

    def get_param(self, name: str, timeout_s: float = 5.0) -> float:
        """PARAM_REQUEST_READ on this link, resent every 0.5 s until the autopilot answers; the
        value, or TimeoutError."""
        ts, tc = self._target or (0, 0)
        self.params.pop(name, None)
        value: float = self._until_answered(
            f"read {name}",
            lambda mav: mav.param_request_read_send(ts, tc, name.encode(), -1),
            lambda: self.params.get(name),
            timeout_s,
        )
        return value

    def send_param(self, name: str, value: float) -> None:
        """PARAM_SET on this link without waiting for the echo (a simulator setting driven several
        times a second, such as the weather of lab/real_weather.py)."""
        ts, tc = self._target or (0, 0)
        self._conn.mav.param_set_send(ts, tc, name.encode(), float(value), mavutil.mavlink.MAV_PARAM_TYPE_REAL32)

    def command(self, command: int, *params: float, timeout_s: float = 5.0) -> int:
        """COMMAND_LONG on this link (a test harness acting as a ground station, e.g.
        MAV_CMD_DO_SET_HOME between campaign landings), resent every 0.5 s until acknowledged;
        returns the MAV_RESULT, raises TimeoutError without an answer."""
        ts, tc = self._target or (0, 0)
        p = [float(x) for x in params] + [0.0] * (7 - len(params))
        self.acks.pop(command, None)
        result: int = self._until_answered(
            f"command {command}",
            lambda mav: mav.command_long_send(ts, tc, command, 0, *p),
            lambda: self.acks.get(command),
            timeout_s,
        )
        return result

    def shell(self, command: str, timeout_s: float = 3.0) -> str:
        """One line to PX4's shell over SERIAL_CONTROL (a SITL-only harness action, e.g.
        ``sensor_gps_sim stop``: SIH v1.16 ignores MAV_CMD_INJECT_FAILURE for GPS); the output up
        to the next prompt, or TimeoutError."""
        line = (command.rstrip("\n") + "\n").encode()
        if len(line) > 70:
            raise ValueError(f"shell command of {len(line)} bytes: SERIAL_CONTROL carries 70")
        self.shell_out.clear()
        data = list(line.ljust(70, b"\0"))
        flags = SERIAL_CONTROL_FLAG_RESPOND | SERIAL_CONTROL_FLAG_EXCLUSIVE
        prompt = b"pxh> "

        def answered() -> str | None:
            out = bytes(self.shell_out)
            return out.decode(errors="replace") if out.count(prompt) and out.rstrip().endswith(b">") else None

        sent: list[bool] = []

        def send(mav: Any) -> None:
            if not sent:  # once: a shell line resent would run twice
                mav.serial_control_send(SERIAL_CONTROL_DEV_SHELL, flags, 0, 0, len(line), data)
                sent.append(True)

        answer: str = self._until_answered(f"shell {command!r}", send, answered, timeout_s)
        return answer

    def watched_messages(self, kind: str, since: float = -math.inf) -> list[tuple[float, Any]]:
        """The watched messages of type ``kind`` that arrived at or after ``since`` (monotonic s)."""
        with self._watch_lock:
            return [(t, m) for t, m in self.watched if t >= since and m.get_type() == kind]

    def _request(self, conn: Any) -> None:
        """SET_MESSAGE_INTERVAL for the truth message; repeated every 2 s until it flows (a
        first heartbeat also tells a ``udpout`` peer where we are)."""
        self._last_request = time.monotonic()
        try:
            conn.mav.heartbeat_send(6, 8, 0, 0, 0)  # MAV_TYPE_GCS, MAV_AUTOPILOT_INVALID
            if self._target is not None and (self._state is None or time.monotonic() - self._state[0] > 1.0):
                ts, tc = self._target
                interval_us = 1e6 / self.rate_hz
                conn.mav.command_long_send(
                    ts, tc, MAV_CMD_SET_MESSAGE_INTERVAL, 0, TRUTH_MESSAGES[self.message], interval_us, 0, 0, 0, 0, 0
                )
        except OSError as err:
            log.debug("truth feed: request not sent: %s", err)

    def _on_truth(self, m: Any) -> None:
        # cm/s, NED, truncated toward zero like the position (PX4: int16 of lpos.v * 1e2f): the
        # middle of each step
        v = (_mid_cm_s(m.vx), _mid_cm_s(m.vy), _mid_cm_s(m.vz))
        # PX4 leaves time_usec at 0 in this stream (its msg{} is never stamped): timed on arrival
        t = m.time_usec * 1e-6 if getattr(m, "time_usec", 0) else time.monotonic()
        self.store_sample(list(m.attitude_quaternion), (int(m.lat), int(m.lon), m.alt * 1e-3), v, t)

    def _on_sim_state(self, m: Any) -> None:
        """ArduPilot SITL's SIM_STATE: degE7 in lat_int/lon_int (MAVLink 2 extensions); without
        them the float fields, which ArduPilot fills with degE7 as well (float32: ~1 m steps, not
        dequantised). It has no timestamp: samples are timed as they arrive."""
        lat_i, lon_i = getattr(m, "lat_int", 0), getattr(m, "lon_int", 0)
        geo: tuple[float, float, float]
        if lat_i or lon_i:
            geo = (int(lat_i), int(lon_i), m.alt)
        else:
            lat, lon = m.lat, m.lon
            if abs(lat) > 90.0 or abs(lon) > 180.0:
                lat, lon = lat * 1e-7, lon * 1e-7
            geo = (float(lat), float(lon), m.alt)
        self.store_sample([m.q1, m.q2, m.q3, m.q4], geo, (m.vn, m.ve, m.vd), time.monotonic())

    def _dequantise(
        self, lat_e7: int, lon_e7: int, alt_m: float, vel: tuple[float, float, float], t: float
    ) -> GeoPoint:
        """The position inside the degE7 step (:class:`DegE7Dequantiser`): the horizontal motion
        since the last sample from the mean of the two velocities (trapezoid)."""
        last = self._last_fix
        step_lat = step_lon = math.nan
        if last is not None and 0.0 <= t - last[0] <= MAX_INTEGRATION_GAP_S:
            dt = t - last[0]
            lat_deg = lat_e7 * 1e-7
            r_m, r_n = radii_of_curvature(lat_deg)
            step_lat = 0.5 * (last[1] + vel[0]) * dt / (r_m + alt_m) * DEG_E7_PER_RAD
            east_m_per_rad = (r_n + alt_m) * math.cos(math.radians(lat_deg))
            step_lon = 0.5 * (last[2] + vel[1]) * dt / east_m_per_rad * DEG_E7_PER_RAD
        self._last_fix = (t, vel[0], vel[1])
        lat_d = self._lat.update(lat_e7, step_lat) * 1e-7
        lon_d = self._lon.update(lon_e7, step_lon) * 1e-7
        return GeoPoint(lat_d, lon_d, alt_m)

    def store_sample(
        self,
        q: list[float],
        geo: tuple[float, float, float],
        vel: tuple[float, float, float],
        t: float,
    ) -> None:
        """One truth sample, as both message handlers decode it (public: a test feeds samples
        without a link). ``q``: attitude quaternion (w, x, y, z); ``geo``: latitude and longitude
        as degE7 ints (dequantised here) or as degrees, altitude AMSL in m; ``vel``: NED m/s;
        ``t``: its time in s."""
        if not all(math.isfinite(v) for v in (*q, *geo, *vel)) or abs(sum(v * v for v in q) - 1.0) > 0.1:
            self.rejected += 1
            return
        if isinstance(geo[0], int) and isinstance(geo[1], int):
            p = self._dequantise(geo[0], geo[1], geo[2], vel, t)
        else:
            p = GeoPoint(*geo)
        if self._ltp is None:
            self._ltp = LocalTangentPlane(p)
            log.info("truth origin taken from the first sample: %.7f %.7f %.2f m", p.lat_deg, p.lon_deg, p.alt_amsl_m)
        n, e, d = self._ltp.to_ned(p)
        r, pi, y = quat_to_euler(q)
        self._state = (time.monotonic(), n, e, d, float(r), float(pi), float(y), *(float(v) for v in vel))
        self.samples += 1

    # ------------------------------------------------------------------ SimVehicle-like view
    def step_to(self, t_s: float) -> None:
        """Truth advances by itself (the autopilot's simulation runs on its own clock)."""

    def _get(self, i: int) -> float:
        s = self._state
        if s is None:
            raise TruthUnavailable(f"no ground truth from {self.url!r} yet")
        return s[i]

    @property
    def origin(self) -> GeoPoint | None:
        """The NED origin (given, or the first sample's position once one arrived)."""
        return self._ltp.origin if self._ltp is not None else None

    @property
    def age_s(self) -> float:
        s = self._state
        return math.inf if s is None else time.monotonic() - s[0]

    @property
    def pn(self) -> float:
        return self._get(1)

    @property
    def pe(self) -> float:
        return self._get(2)

    @property
    def pd(self) -> float:
        return self._get(3)

    @property
    def roll(self) -> float:
        return self._get(4)

    @property
    def pitch(self) -> float:
        return self._get(5)

    @property
    def yaw(self) -> float:
        return self._get(6)

    @property
    def vn(self) -> float:
        return self._get(7)

    @property
    def ve(self) -> float:
        return self._get(8)

    @property
    def vd(self) -> float:
        return self._get(9)

"""The Dart experiment over real MAVLink: an ArduCopter-like sim vehicle flown on RC sticks and a
forward camera plugin rendering the wall marker from its ground truth.

:class:`StickSimVehicle` is the embedded :class:`SimVehicle` plus ArduCopter's pilot attitude
modes. While armed in STABILIZE or ALT_HOLD (handed in by the MAVLink vehicle every tick with
channels 1-4, RCMAP roll, pitch, throttle, yaw) it flies the attitude-setpoint path of
companion_sitl.dart_sim (dart sec. 3.1): roll / pitch stick -> angle setpoint (full stick =
``max_tilt_deg``, companion.dart.mixer.attitude_setpoint), yaw stick -> yaw rate, throttle ->
climb rate (ALT_HOLD) or thrust (STABILIZE, mid stick = hover), first-order attitude response,
the inner loop's residual attitude disturbance, linear drag against wind and gusts. In OFFBOARD
(PX4 dialect) it flies the SET_ATTITUDE_TARGETs it receives the same way while they are fresh
(thrust as in STABILIZE). Every other mode (GUIDED, LOITER, HOLD, LAND, ...) is the base
vehicle's. The IMU it reports (HIGHRES_IMU) has
the Dart IMU's white noise and a constant bias per axis; the frame vibration of the lock-step
simulator is left out here: an autopilot low-pass filters its IMU before it streams it.

:class:`DartLinkCamera` is a camera plugin (companion.plugin_api, api_version 1): a thread
exposes at ``vision_hz`` on the shell's monotonic clock, snapshots the vehicle's truth under the
MAVLink vehicle's lock at that instant, renders the nested wall marker (SimulatedCamera, real
images), applies the gimbal (none, 2-DOF: level, heading with the body; 3-DOF: level, heading
held), motion blur (fixed camera) and pixel noise, and publishes the frame stamped at exposure
once the capture latency has passed.

:class:`DartLinkSim` puts them together: the marker on a wall (marker centre ``marker_height_m``
above home, facing south), the vehicle airborne at the mission's start point in ALT_HOLD
(ArduPilot dialect) or POSCTL (PX4 dialect) -- the paper's pilot has flown it there --, the
pilot's transmitter (sticks on channels 1-4, mirrored on the runtime's ``pilot_channels``, the
cyber-pilot switch) and truth in the marker frame. :func:`fly_dart_link` flies the Dart shell
(companion.dart.shell) through the ArduPilot or PX4 backend against it, with a pilot script.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import threading
import time
from collections import deque
from collections.abc import Callable, Coroutine, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, ClassVar, cast

import numpy as np

from companion.autopilot.ardupilot import ArduPilotAutopilot
from companion.autopilot.px4 import Px4Autopilot
from companion.autopilot.types import FlightMode, Imu, LandedState
from companion.dart.estimators import GimbalKind, camera_mount, wall_marker
from companion.dart.mission import DartPhase
from companion.dart.mixer import AttitudeMapConfig, RcMixerConfig, attitude_setpoint
from companion.dart.params import DartFlightParams
from companion.dart.shell import DART_STREAM_RATES_HZ, DartRunSummary, DartShell
from companion.geometry import Transform, euler_to_rotmat, rot_z, wrap_angle
from companion.plugin_api import Frame
from companion.scheduling import RateLoop
from companion.vision.camera import CameraModel, load_camera, load_default_camera
from companion_sitl.params import SimConfig, VehicleSimConfig

from .camera import SimCameraConfig, SimulatedCamera
from .dart_sim import (
    ESTIMATOR_GIMBAL,
    NEUTRAL_US,
    SWITCH_OFF_US,
    SWITCH_ON_US,
    BlockNoise,
    DartParams,
    DartSimConfig,
    attitude_response,
    motion_blur,
    thrust_per_mass,
)
from .mavlink.factory import mavlink_sim_vehicle
from .mavlink.link import LinkStats, free_udp_port
from .mavlink.messages import PX4_DEFAULT_STREAMS_HZ
from .mavlink.vehicle import MavlinkSimVehicle
from .vehicle import G, SimVehicle, TruthSample

log = logging.getLogger(__name__)

#: ArduCopter pilot attitude modes flown on the sticks, and what the throttle stick means there
STICK_MODES = {"STABILIZE": "thrust", "ALT_HOLD": "climb_rate"}
#: a PWM inside ALT_HOLD's band of the flight-mode switch (channel 5, FLTMODE2)
ALT_HOLD_PWM = 1295
#: the PX4 dialect's streams raised for the Dart estimator (message id -> Hz); PX4 itself needs
#: MAV_x_RATE / SET_MESSAGE_INTERVAL for that (its onboard link streams HIGHRES_IMU at 50 Hz)
PX4_DART_STREAMS_HZ = {105: 200.0, 30: 100.0, 65: 50.0}


class StickSimVehicle(SimVehicle):
    """SimVehicle plus ArduCopter's STABILIZE / ALT_HOLD on RC sticks (see the module doc)."""

    def __init__(self, cfg: SimConfig, dart: DartSimConfig | None = None) -> None:
        super().__init__(cfg)
        self.dart = d = dart or DartSimConfig()
        self.attitude_map: AttitudeMapConfig = d  # [sim] is an attitude map (param_kinds.AttitudeMapTable)
        self.rcmap = RcMixerConfig()  # roll 1, pitch 2, throttle 3, yaw 4 (ArduPilot RCMAP)
        self.copter_mode = ""
        self.sticks_us: tuple[float, float, float, float] = (NEUTRAL_US, NEUTRAL_US, NEUTRAL_US, NEUTRAL_US)
        self.stick_steps = 0
        rng = np.random.default_rng(np.random.SeedSequence([cfg.seed, 0xDA27]))
        self._n = BlockNoise(rng)
        self._gyro_bias = [d.gyro_bias_rad_s * self._n() for _ in range(3)]
        self._accel_bias = [d.accel_bias_m_s2 * self._n() for _ in range(3)]
        self._in_stick = False
        self._roll_c = self._pitch_c = self._yaw_c = 0.0
        self._yaw_rate = 0.0
        self._dist = [0.0, 0.0, 0.0]  # residual attitude error of the inner loop, smoothed
        self._dist_gm = [0.0, 0.0, 0.0]  # its Gauss-Markov driver
        self._att_target: tuple[float, float, float, float] | None = None
        self._att_target_t = -math.inf

    # ------------------------------------------------------------------ inputs
    def set_rc_input(self, copter_mode: str, sticks_us: Sequence[int | float]) -> None:
        """The autopilot's mode name and RC channels 1-4 (what it flies on), every tick."""
        self.copter_mode = copter_mode
        r, p, t, y = (float(v) for v in sticks_us[:4])
        self.sticks_us = (r, p, t, y)

    def set_attitude_target(self, roll_rad: float, pitch_rad: float, yaw_rate_rad_s: float, thrust: float) -> None:
        """PX4 offboard attitude (SET_ATTITUDE_TARGET): flown in OFFBOARD while fresh (newer than
        COM_OF_LOSS_T), with thrust as in STABILIZE; it also counts as a setpoint stream for the
        switch to OFFBOARD."""
        vals = (roll_rad, pitch_rad, yaw_rate_rad_s, thrust)
        if not all(math.isfinite(v) for v in vals):
            self._text(f"attitude setpoint rejected: not finite {vals}")
            return
        self._att_target = (roll_rad, pitch_rad, yaw_rate_rad_s, min(1.0, max(0.0, thrust)))
        self._att_target_t = self.time_s
        self._sp_times.append(self.time_s)
        if len(self._sp_times) > 50:
            del self._sp_times[:-50]

    def start_in_air(self, north_m: float, east_m: float, down_m: float, yaw_rad: float = 0.0) -> None:
        """Armed and hovering at a point (home and the local origin stay on the ground below)."""
        if self._home_reported is None:
            self._set_home()
        self.pn, self.pe, self.pd = north_m, east_m, down_m
        self.vn = self.ve = self.vd = 0.0
        self.roll = self.pitch = 0.0
        self.yaw = self._yaw_sp = wrap_angle(yaw_rad)
        self.armed = True
        self.landed = LandedState.IN_AIR
        self._airborne = True
        self._ground_since = self._landed_since = None
        self._hold_target = self._estimate()

    # ------------------------------------------------------------------ physics
    def _attitude_offboard(self) -> bool:
        fresh = self.time_s - self._att_target_t <= self.cfg.vehicle.offboard_loss_timeout_s
        return self.mode is FlightMode.OFFBOARD and self._att_target is not None and fresh

    def _step(self, dt: float) -> None:
        offboard = self._attitude_offboard()
        throttle_mode = "thrust" if offboard else STICK_MODES.get(self.copter_mode)
        if throttle_mode is None or not self.armed:
            if self._in_stick:  # back to the autopilot's own loops, from where the vehicle is
                self._in_stick = False
                self._int = [0.0, 0.0, 0.0]
                self._yaw_sp = self.yaw
                self._hold_target = self._estimate()
            super()._step(dt)
            return
        if not self._in_stick:
            self._in_stick = True
            self._roll_c, self._pitch_c, self._yaw_c = self.roll, self.pitch, self.yaw
            self._yaw_rate = 0.0
            self._dist = [0.0, 0.0, 0.0]
        self._stick_step(dt, throttle_mode, self._att_target if offboard else None)

    def _stick_step(
        self, dt: float, throttle_mode: str, target: tuple[float, float, float, float] | None = None
    ) -> None:
        d, n = self.dart, self._n
        self.time_s += dt
        t = self.time_s
        # the base vehicle's environment and bookkeeping: home, wind, GPS wander, payload
        if self._home_reported is None and self.healthy:
            self._set_home()
        rn = self._rng_wind.standard_normal(3)
        for i in range(3):
            self._wind[i] = self._wind_mean[i] + self._gust[i].step(dt, float(rn[i]))
        rg = self._rng_gps.standard_normal(3)
        for i in range(3):
            self._walk[i].step(dt, float(rg[i]))
        if self._release_at is not None and t >= self._release_at:
            self.payload_released = True
            self._release_at = None
            self._text("payload released")
        # sticks -> attitude setpoint (companion_sitl.dart_sim's low level)
        chans = [NEUTRAL_US] * 8
        for ch, v in zip(self.rcmap.channels, self.sticks_us, strict=True):
            chans[ch - 1] = v
        sp = attitude_setpoint(chans, None, self.rcmap, self.attitude_map)
        if target is not None:  # offboard attitude setpoint (PX4)
            roll_sp, pitch_sp, yaw_rate_sp, thrust = target
        elif sp is None:  # invalid sticks: level, no yaw rate, hold altitude / hover thrust
            roll_sp = pitch_sp = yaw_rate_sp = 0.0
            thrust = d.hover_throttle if throttle_mode == "thrust" else 0.5
        else:
            roll_sp, pitch_sp, yaw_rate_sp, thrust = sp.roll_rad, sp.pitch_rad, sp.yaw_rate_rad_s, sp.thrust
        (r_roll, r_pitch, r_yaw), d_rate, self._yaw_rate = attitude_response(
            d,
            dt,
            (self._roll_c, self._pitch_c, self._yaw_rate),
            (roll_sp, pitch_sp, yaw_rate_sp),
            self._dist,
            self._dist_gm,
            n,
        )
        self._roll_c += r_roll * dt
        self._pitch_c += r_pitch * dt
        self._yaw_c = wrap_angle(self._yaw_c + r_yaw * dt)
        self.roll = self._roll_c + self._dist[0]
        self.pitch = self._pitch_c + self._dist[1]
        self.yaw = wrap_angle(self._yaw_c + self._dist[2])
        # body rates from the ZYX Euler rates (what the gyro and ATTITUDE report)
        er = (r_roll + d_rate[0], r_pitch + d_rate[1], r_yaw + d_rate[2])
        sr, cr = math.sin(self.roll), math.cos(self.roll)
        sp_, cp = math.sin(self.pitch), math.cos(self.pitch)
        self._rates = (er[0] - sp_ * er[2], cr * er[1] + sr * cp * er[2], -sr * er[1] + cr * cp * er[2])
        # translation: thrust along body -z, gravity, drag against the air
        cy, sy = math.cos(self.yaw), math.sin(self.yaw)
        f_t = thrust_per_mass(d, throttle_mode, thrust, self.vd, cr * cp)
        bz = (cy * sp_ * cr + sy * sr, sy * sp_ * cr - cy * sr, cp * cr)
        vel = (self.vn, self.ve, self.vd)
        acc = [-f_t * bz[i] - d.drag_per_s * (vel[i] - self._wind[i]) + (G if i == 2 else 0.0) for i in range(3)]
        if self.pd >= -1e-6 and acc[2] >= 0.0:  # resting on the ground
            self.vn = self.ve = self.vd = 0.0
            self.pd = 0.0
            acc = [0.0, 0.0, 0.0]
        else:
            self.vn += acc[0] * dt
            self.ve += acc[1] * dt
            self.vd += acc[2] * dt
            self.pn += self.vn * dt
            self.pe += self.ve * dt
            self.pd += self.vd * dt
            if self.pd > 0.0:
                self.pd = self.vd = 0.0
        self._accel = (acc[0], acc[1], acc[2])
        self.stick_steps += 1
        self._land_detector(t)
        if self.armed:
            self.battery_pct = max(0.0, self.battery_pct - 100.0 * dt / self.cfg.vehicle.battery_endurance_s)
        if t >= self._truth_next:
            self._truth_next = t + 0.1
            self.truth_log.append(TruthSample(t, self.pn, self.pe, self.pd, self.vn, self.ve, self.vd))

    def imu(self) -> Imu:
        """The base vehicle's IMU (specific force, body rates, white noise) plus a constant bias."""
        i = super().imu()
        a, g = self._accel_bias, self._gyro_bias
        return Imu(
            i.time_s,
            i.accel_x_m_s2 + a[0],
            i.accel_y_m_s2 + a[1],
            i.accel_z_m_s2 + a[2],
            i.gyro_x_rad_s + g[0],
            i.gyro_y_rad_s + g[1],
            i.gyro_z_rad_s + g[2],
        )


class DartLinkCamera:
    """Forward camera plugin (api_version 1) rendering the wall marker from the vehicle's truth.

    ``clock`` must be the shell's clock (the asyncio loop's ``time()``: ``time.monotonic``).
    """

    api_version: ClassVar[int] = 1

    def __init__(
        self,
        link: MavlinkSimVehicle,
        dart: DartSimConfig,
        T_world_marker: Transform,
        *,
        gimbal: GimbalKind = GimbalKind.THREE_DOF,
        gimbal_heading_rad: float = 0.0,
        camera: CameraModel | None = None,
        rate_hz: float = 30.0,
        seed: int = 0,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 0.0):
            raise ValueError(f"rate_hz = {rate_hz!r}: must be > 0")
        self.link = link
        self.dart = dart
        self.gimbal = gimbal
        self.gimbal_heading_rad = gimbal_heading_rad
        self.rate_hz = rate_hz
        self._clock = clock
        cam = camera
        if cam is None:
            cam = load_camera(dart.camera_file) if dart.camera_file else load_default_camera()
            if dart.camera_scale != 1.0:
                cam = cam.scaled(dart.camera_scale)
        self.camera_model = cam
        self._R_bc = np.array(camera_mount(), dtype=float)
        self._t_bc = np.array(dart.lens_offset_m, dtype=float)
        ss = np.random.SeedSequence([seed, 0xCA3])
        s_render, s_noise = ss.spawn(2)
        self.renderer = SimulatedCamera(
            cam,
            dart.layout,
            SimCameraConfig(
                latency_s=dart.camera_latency_s,
                noise_std=0.0,
                ground_size_m=dart.wall_size_m,
                clutter=dart.wall_clutter,
                clutter_radius_m=0.45 * dart.wall_size_m,
            ),
            T_body_camera=Transform(self._R_bc, self._t_bc),
            T_world_pad=T_world_marker,
            seed=int(s_render.generate_state(1)[0]),
        )
        self._rng = np.random.default_rng(s_noise)
        w, h = cam.size
        self._noise_img = (self._rng.standard_normal((h + 64, w + 64)) * dart.image_noise_std).astype(np.float32)
        self._f_px = 0.5 * (cam.fx + cam.fy)
        self._lock = threading.Lock()
        self._pending: deque[tuple[float, Frame]] = deque(maxlen=16)  # (readable from, frame)
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self.frames = 0
        self.frames_read = 0
        self.render_errors = 0

    def start(self) -> None:
        if self._thread is not None:
            return
        self._stop.clear()
        self._thread = threading.Thread(target=self._run, name="dart-link-camera", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def read(self) -> Frame | None:
        """The newest frame whose capture latency has passed and that was not read before (older
        ones are dropped: keep-newest); None when there is nothing new. Never blocks."""
        now = self._clock()
        newest: Frame | None = None
        with self._lock:
            while self._pending and self._pending[0][0] <= now:
                newest = self._pending.popleft()[1]
        if newest is not None:
            self.frames_read += 1
        return newest

    # ------------------------------------------------------------------ the camera thread
    def _truth(self) -> tuple[Transform, tuple[float, float, float]]:
        link = self.link
        with link.lock:
            v = link.vehicle
            if link.running:
                v.step_to(link.now)
            R_wb = euler_to_rotmat(v.roll, v.pitch, v.yaw)
            a = v.attitude()
            return Transform(R_wb, np.array([v.pn, v.pe, v.pd])), (
                a.rollspeed_rad_s,
                a.pitchspeed_rad_s,
                a.yawspeed_rad_s,
            )

    def T_world_camera(self, T_world_body: Transform) -> Transform:
        """The camera's pose for a body pose: rigid, or held by the gimbal (plus its 0.02 deg)."""
        R_wb = np.asarray(T_world_body.R, dtype=float)
        t_wc = np.asarray(T_world_body.t, dtype=float) + R_wb @ self._t_bc
        if self.gimbal is GimbalKind.NONE:
            return Transform(R_wb @ self._R_bc, t_wc)
        e = np.radians(self.dart.gimbal_noise_deg) * self._rng.standard_normal(3)
        if self.gimbal is GimbalKind.TWO_DOF:
            yaw = math.atan2(float(R_wb[1, 0]), float(R_wb[0, 0]))
            R = euler_to_rotmat(float(e[0]), float(e[1]), yaw)
        else:
            R = rot_z(self.gimbal_heading_rad) @ euler_to_rotmat(float(e[0]), float(e[1]), float(e[2]))
        return Transform(R @ self._R_bc, t_wc)

    def _expose(self, t_exp: float) -> Frame:
        c = self.dart
        T_wb, rates = self._truth()
        frame = self.renderer.capture_camera(self.T_world_camera(T_wb), t_exp)
        img = frame.image
        if self.gimbal is GimbalKind.NONE:  # the fixed camera turns with the body during the exposure
            wc = self._R_bc.T @ np.array(rates)
            du = self._f_px * float(wc[1]) * c.exposure_s
            dv = -self._f_px * float(wc[0]) * c.exposure_s
            if math.hypot(du, dv) >= 0.5:
                img = motion_blur(img, du, dv)
        if c.image_noise_std > 0.0:
            h, w = img.shape
            oy, ox = (int(v) for v in self._rng.integers(0, 64, 2))
            noisy = img.astype(np.float32) + self._noise_img[oy : oy + h, ox : ox + w]
            img = np.clip(noisy, 0, 255).astype(np.uint8)
        self.frames += 1
        return Frame(t_exp, img, self.frames)

    def _run(self) -> None:
        period = 1.0 / self.rate_hz
        next_t = self._clock()
        while not self._stop.is_set():
            delay = next_t - self._clock()
            if delay > 0.0 and self._stop.wait(delay):
                break
            t_exp = self._clock()
            next_t = max(next_t + period, t_exp)
            try:
                frame = self._expose(t_exp)
            except Exception:  # a rendering bug must show up, not kill the camera silently
                self.render_errors += 1
                log.exception("dart link camera: frame at %.3f s not rendered", t_exp)
                continue
            with self._lock:
                self._pending.append((t_exp + self.dart.camera_latency_s, frame))


class DartLinkSim:
    """The Dart scene over MAVLink on loopback UDP; see the module doc.

    ``dialect="ardupilot"``: ALT_HOLD on the sticks, the cyber-pilot overrides RC channels.
    ``dialect="px4"``: the vehicle holds position (POSCTL) until the cyber-pilot streams offboard
    attitude setpoints and switches to OFFBOARD; RC_CHANNELS is the raw receiver, so the runtime
    reads the pilot on the stick channels themselves. ``port``: where the companion listens.
    Use as a context manager or :meth:`start` / :meth:`stop`; the camera is started and stopped
    by its user (the shell).
    """

    def __init__(
        self,
        params: DartParams | None = None,
        *,
        port: int,
        dialect: str = "ardupilot",
        estimator: str | None = None,
        gimbal: GimbalKind | None = None,
        seed: int = 0,
        marker_height_m: float = 2.0,
        physics_hz: float = 400.0,
        rc_override_timeout_s: float = 3.0,
        camera: CameraModel | None = None,
    ) -> None:
        if dialect not in ("ardupilot", "px4"):
            raise ValueError(f"dialect {dialect!r}: must be 'ardupilot' or 'px4'")
        p = params or DartParams()
        if dialect == "px4":  # PX4 reports the receiver's raw channels: the pilot is read there
            p = replace(p, runtime=p.runtime.replaced(pilot_channels=p.runtime.stick_channels))
        self.params = p
        self.dialect = dialect
        d = p.sim
        name = (estimator or p.runtime.estimator).strip().upper().replace("_", "-")
        if name not in ESTIMATOR_GIMBAL:
            raise ValueError(f"unknown Dart estimator {estimator!r}; choose one of {list(ESTIMATOR_GIMBAL)}")
        self.gimbal = gimbal if gimbal is not None else ESTIMATOR_GIMBAL[name]
        self.seed = seed
        wn, we, _ = d.wind_ned_m_s
        speed = math.hypot(wn, we)
        wind_from = math.degrees(math.atan2(-we, -wn)) % 360.0 if speed > 0.0 else 0.0
        self.sim_config = SimConfig(
            seed=seed,
            ready_delay_s=0.0,
            wind_speed_m_s=speed,
            wind_from_deg=wind_from,
            gust_std_m_s=d.gust_std_m_s,
            gust_time_constant_s=d.gust_tau_s,
            gyro_noise_rad_s=d.gyro_noise_rad_s,
            accel_noise_m_s2=d.accel_noise_m_s2,
            imu_rate_hz=min(1000.0, physics_hz),
            attitude_rate_hz=min(500.0, physics_hz),
            vehicle=VehicleSimConfig(physics_rate_hz=physics_hz, max_tilt_deg=d.max_tilt_deg),
        )
        # the wall marker: centre above home, facing south (a drone facing it heads north)
        self.heading_rad = math.radians(p.runtime.marker_heading_deg)
        self.R_world_marker = np.array(wall_marker(self.heading_rad), dtype=float)
        self.p_world_marker = np.array([0.0, 0.0, -marker_height_m])
        self.vehicle = StickSimVehicle(self.sim_config, d)
        m = p.mission
        start = np.array([m.x_m, m.y_m, m.start_distance_m]) + np.array(d.start_offset_m)
        p0 = self.p_world_marker + self.R_world_marker @ start
        self.vehicle.start_in_air(float(p0[0]), float(p0[1]), float(p0[2]), self.heading_rad)
        streams = None
        if dialect == "px4":
            self.vehicle.mode = FlightMode.POSITION  # the pilot hovers in POSCTL
            streams = {**PX4_DEFAULT_STREAMS_HZ, **PX4_DART_STREAMS_HZ}
        self.link = mavlink_sim_vehicle(
            self.sim_config,
            dialect,  # type: ignore[arg-type]
            remote=("127.0.0.1", port),
            vehicle=self.vehicle,
            rc_override_timeout_s=rc_override_timeout_s,
            stream_rates_hz=streams,
        )
        self.camera = DartLinkCamera(
            self.link,
            d,
            Transform(self.R_world_marker, self.p_world_marker),
            gimbal=self.gimbal,
            gimbal_heading_rad=self.heading_rad,
            camera=camera,
            rate_hz=p.runtime.vision_hz,
            seed=seed,
        )
        self.sticks: tuple[float, float, float, float] = (NEUTRAL_US, NEUTRAL_US, NEUTRAL_US, NEUTRAL_US)
        self.switch_us = SWITCH_OFF_US
        self.set_pilot(switch_on=False)  # ALT_HOLD, sticks centred, cyber-pilot off

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> DartLinkSim:
        self.link.start()
        return self

    def stop(self) -> None:
        self.camera.stop()
        self.link.stop()

    def __enter__(self) -> DartLinkSim:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # ------------------------------------------------------------------ the pilot
    def set_pilot(
        self,
        *,
        roll_us: float | None = None,
        pitch_us: float | None = None,
        throttle_us: float | None = None,
        yaw_us: float | None = None,
        switch_on: bool | None = None,
        mode_pwm: int = ALT_HOLD_PWM,
    ) -> None:
        """The pilot's transmitter: sticks (channels 1-4, mirrored on the runtime's
        ``pilot_channels``), the flight-mode switch (channel 5) and the cyber-pilot switch."""
        r, p, t, y = self.sticks
        self.sticks = (
            r if roll_us is None else roll_us,
            p if pitch_us is None else pitch_us,
            t if throttle_us is None else throttle_us,
            y if yaw_us is None else yaw_us,
        )
        if switch_on is not None:
            self.switch_us = SWITCH_ON_US if switch_on else SWITCH_OFF_US
        rt = self.params.runtime
        chans: dict[int, int] = {5: mode_pwm, rt.switch_channel: round(self.switch_us)}
        for ch, mirror, v in zip(rt.stick_channels, rt.pilot_channels, self.sticks, strict=True):
            chans[ch] = round(v)
            chans[mirror] = round(v)
        self.link.pilot_set_rc(chans)

    # ------------------------------------------------------------------ truth
    def truth_marker(self) -> tuple[float, float, float]:
        """The vehicle's centre of thrust in the marker frame (x right, y up, z out of the wall)."""
        with self.link.lock:
            v = self.vehicle
            if self.link.running:
                v.step_to(self.link.now)
            p = np.array([v.pn, v.pe, v.pd])
        q = self.R_world_marker.T @ (p - self.p_world_marker)
        return float(q[0]), float(q[1]), float(q[2])

    @property
    def copter_mode(self) -> int:
        return int(cast(Any, self.link).copter_mode)


# ------------------------------------------------------------------------------ a whole flight
PilotScript = Callable[["DartLinkSim", "DartShell"], Coroutine[Any, Any, None]]


@dataclass
class DartLinkResult:
    """A Dart flight over MAVLink: the shell's summary and what really happened."""

    summary: DartRunSummary
    truth: list[tuple[float, DartPhase, float, float, float]]  # (shell time, phase, x, y, z) marker frame
    link: LinkStats
    modes: set[int | str]  # ArduCopter mode numbers, or the PX4 vehicle's FlightMode values
    rc_overrides_end: list[int | None]
    shell: DartShell
    autopilot: ArduPilotAutopilot | Px4Autopilot
    sim: DartLinkSim

    def truth_in(self, phase: DartPhase, after_s: float = 0.0) -> np.ndarray:
        """(N, 3) true positions in ``phase`` from ``after_s`` after the phase began."""
        starts = [t for t, ph in self.summary.transitions if ph is phase]
        if not starts:
            return np.zeros((0, 3))
        t0 = starts[-1] + after_s
        return np.array([r[2:] for r in self.truth if r[1] is phase and r[0] >= t0], dtype=float).reshape(-1, 3)


async def fly_dart_link(
    params: DartParams | None = None,
    *,
    duration_s: float,
    seed: int = 0,
    dialect: str = "ardupilot",
    estimator: str | None = None,
    pilot: PilotScript | None = None,
    truth_hz: float = 20.0,
    log_path: str | Path | None = None,
) -> DartLinkResult:
    """Fly the Dart mission against the MAVLink stick vehicle: through the ArduPilot backend (RC
    overrides, ``dialect="ardupilot"``) or the PX4 backend (offboard attitude, ``"px4"``).

    The pilot's script (default: the switch on at once, sticks centred) runs beside the shell.
    The companion is given the simulated camera's calibration and the marker's true size.
    """
    p = params or DartParams()
    name = (estimator or p.runtime.estimator).strip().upper().replace("_", "-")
    port = free_udp_port()
    sim = DartLinkSim(p, port=port, dialect=dialect, seed=seed, estimator=name)
    modes: set[int | str] = set()
    truth: list[tuple[float, DartPhase, float, float, float]] = []
    with sim:
        ap: ArduPilotAutopilot | Px4Autopilot
        if dialect == "px4":
            ap = Px4Autopilot(f"udpin://127.0.0.1:{port}")
        else:
            ap = ArduPilotAutopilot(f"udpin:127.0.0.1:{port}", stream_rates_hz=DART_STREAM_RATES_HZ)
        await ap.connect(timeout_s=10.0)
        rt = sim.params.runtime.replaced(estimator=name)
        shell = DartShell(
            ap,
            sim.camera,
            DartFlightParams(control=p.control, mission=p.mission, runtime=rt, estimator=p.estimator),
            output="attitude" if dialect == "px4" else "rc_override",
            camera_model=sim.camera.camera_model,
            layout=p.sim.layout,
            log_path=log_path,
        )

        async def watch() -> None:
            rate = RateLoop(shell.clock, truth_hz)
            while True:
                t = await rate.tick()
                modes.add(sim.copter_mode if dialect == "ardupilot" else sim.vehicle.mode.value)
                truth.append((t, shell.mission.phase, *sim.truth_marker()))

        async def default_pilot(s: DartLinkSim, _shell: DartShell) -> None:
            s.set_pilot(switch_on=True)

        loop = asyncio.get_running_loop()
        side = [loop.create_task(watch()), loop.create_task((pilot or default_pilot)(sim, shell))]
        try:
            summary = await shell.run(duration_s)
        finally:
            for task in side:
                task.cancel()
            for task in side:
                with contextlib.suppress(asyncio.CancelledError):
                    await task
            await ap.close()
        for task in side:  # a failing pilot script fails the flight
            if not task.cancelled() and task.exception() is not None:
                raise task.exception()  # type: ignore[misc]
        # the release went out on the shell's exit; the sim's receive thread may not have read it
        # yet: wait (bounded) until it has counted every override the shell sent (PX4: none)
        sent = shell.stats.overrides_sent + shell.stats.releases_sent
        deadline = time.monotonic() + 2.0
        while sim.link.stats.by_type_in["RC_CHANNELS_OVERRIDE"] < sent and time.monotonic() < deadline:
            await asyncio.sleep(0.01)
        overrides = sim.link.rc_overrides
    return DartLinkResult(summary, truth, sim.link.stats, modes, overrides, shell, ap, sim)


__all__ = [
    "ALT_HOLD_PWM",
    "STICK_MODES",
    "DartLinkCamera",
    "DartLinkResult",
    "DartLinkSim",
    "StickSimVehicle",
    "fly_dart_link",
]

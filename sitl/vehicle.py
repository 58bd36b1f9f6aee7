"""Embedded multicopter: translational rigid-body dynamics with PX4-like inner loops.

Synchronous and deterministic by seed. The model is what a PX4 SIH quad looks like to a
companion computer: an attitude-limited velocity loop (P + I, accel and tilt limits, first-order
tilt response), modes (HOLD, TAKEOFF, LAND, OFFBOARD with its setpoint rules and loss failsafe),
a land detector, and the autopilot's own GPS-based estimate (truth + wander + bias), which is
what it reports and what its own position loops use.

:class:`SimVehicle` holds the truth (position, velocity, attitude) and the autopilot's status
(armed, mode, landed, battery, the payload released), steps the physics and answers the commands
and the telemetry; its parts, each in its own module, are

* ``wind_model`` (:class:`~companion_sitl.wind.SimWind`): the wind, mean and gusts;
* ``gps_error`` (:class:`~companion_sitl.gps_error.GpsError`): the GPS error and the part of it
  the estimate has taken;
* ``estimator_error`` (:class:`~companion_sitl.estimator_error.EstimatorError`): the velocity
  estimate's error and the estimator state of the flight (attitude offset, velocity bias);
* ``modes`` (:class:`~companion_sitl.modes.FlightModes`): arming, the modes, the offboard rules
  and failsafe, each mode's velocity setpoint;
* ``control`` (:class:`~companion_sitl.velocity_control.VelocityController`, and
  :func:`~companion_sitl.velocity_control.attitude_step`): the inner loops;
* ``dynamics`` (:class:`~companion_sitl.dynamics.TranslationalDynamics`): thrust, gravity, drag
  and the ground move the truth;
* ``land_detector`` (:class:`~companion_sitl.land_detector.LandDetector`): landed, touchdowns,
  the auto-disarm;
* ``payload`` (:class:`~companion_sitl.payload.SimPayload`): the release, the winch and its parcel.

Its random draws come from generators spawned off ``[sim] seed`` in a fixed order (wind, GPS, IMU,
misc, then the estimator errors' own): the order of the draws is what makes a flight reproducible.

Frames: world NED at the (true) home position, metres; ground is flat at down = 0.
Plain floats in the hot path: numpy on 3-vectors costs more than the arithmetic.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from companion.autopilot.types import (
    Attitude,
    FlightMode,
    GlobalPosition,
    GpsRaw,
    HomePosition,
    Imu,
    LandedState,
    PositionNed,
    VehicleStatus,
)
from companion.autopilot.winch import WinchCommand
from companion.geometry.earth import GeoPoint, LocalTangentPlane
from companion.geometry.rotations import wrap_angle
from companion.guidance.setpoint import VelocitySetpoint
from companion_sitl.dynamics import TranslationalDynamics
from companion_sitl.estimator_error import EstimatorError
from companion_sitl.gauss_markov import GaussMarkov
from companion_sitl.gnss_loss import SimGnss
from companion_sitl.gps_error import GPS_FIX_PERIOD_S, GpsError
from companion_sitl.land_detector import AUTO_DISARM_AFTER_LAND_S, LandDetector, Touchdown
from companion_sitl.modes import (
    HOLD_MAX_H_SPEED,
    HOLD_MAX_V_SPEED,
    OFFBOARD_MIN_SETPOINT_RATE_HZ,
    PLD_BTOUT_S,
    PLD_HACC_RAD_M,
    FlightModes,
    SimCommandError,
)
from companion_sitl.modes import sqrt_controller_2d as _sqrt_controller_2d
from companion_sitl.pad_motion import PadTrack
from companion_sitl.params import SimConfig
from companion_sitl.payload import PARCEL_STEP_HZ, SimPayload
from companion_sitl.profiles import EstimatorState, apply_profile, get_profile
from companion_sitl.velocity_control import YAW_RATE_MAX, G, VelocityController, attitude_step
from companion_sitl.winch import ParcelOnLine, SimWinch
from companion_sitl.wind import SimWind

__all__ = [
    "AUTO_DISARM_AFTER_LAND_S",
    "GPS_FIX_PERIOD_S",
    "HOLD_MAX_H_SPEED",
    "HOLD_MAX_V_SPEED",
    "OFFBOARD_MIN_SETPOINT_RATE_HZ",
    "PARCEL_STEP_HZ",
    "PLD_BTOUT_S",
    "PLD_HACC_RAD_M",
    "YAW_RATE_MAX",
    "G",
    "GaussMarkov",
    "SimCommandError",
    "SimVehicle",
    "Touchdown",
    "TruthSample",
    "_GaussMarkov",
    "_sqrt_controller_2d",
]

log = logging.getLogger(__name__)

_GaussMarkov = GaussMarkov  # its former name here (tests/sitl/test_sim_sensors_fast_paths.py)


@dataclass
class TruthSample:
    time_s: float
    north_m: float
    east_m: float
    down_m: float
    north_m_s: float
    east_m_s: float
    down_m_s: float


class _Alias:
    """An attribute of one of SimVehicle's parts under the name it had on SimVehicle itself
    (its subclass in dart_link.py and the tests read and set them)."""

    def __init__(self, part: str, name: str) -> None:
        self.part, self.name = part, name

    def __get__(self, obj: object, owner: type | None = None) -> Any:
        return self if obj is None else getattr(getattr(obj, self.part), self.name)

    def __set__(self, obj: object, value: Any) -> None:
        setattr(getattr(obj, self.part), self.name, value)


@dataclass
class SimVehicle:
    """The embedded multicopter (see the module doc): its truth and status here, the rest in its parts."""

    cfg: SimConfig
    time_s: float = 0.0
    # truth
    pn: float = 0.0
    pe: float = 0.0
    pd: float = 0.0
    vn: float = 0.0
    ve: float = 0.0
    vd: float = 0.0
    roll: float = 0.0
    pitch: float = 0.0
    yaw: float = 0.0
    # autopilot state
    armed: bool = False
    mode: FlightMode = FlightMode.HOLD
    landed: LandedState = LandedState.ON_GROUND
    payload_released: bool = False
    battery_pct: float = 100.0
    truth_log: list[TruthSample] = field(default_factory=list)
    touchdowns: list[Touchdown] = field(default_factory=list)
    status_texts: list[tuple[float, str]] = field(default_factory=list)
    # the winch and its parcel (sitl/winch.py): set in __post_init__ when sim.winch.fitted
    winch: SimWinch | None = None
    parcel: ParcelOnLine | None = None

    # the parts' state under its former names (dart_link.StickSimVehicle, lab/gps_step_probe;
    # tests read the parts themselves: estimator_error, gps_error, modes, dynamics)
    _wind = _Alias("wind_model", "now")
    _wind_mean = _Alias("wind_model", "mean")
    _gust = _Alias("wind_model", "gusts")
    _rng_wind = _Alias("wind_model", "rng")
    _walk = _Alias("gps_error", "walk")
    _gps_in_est = _Alias("gps_error", "in_est")
    _verr = _Alias("estimator_error", "verr")
    _att_bias = _Alias("estimator_error", "att_bias")
    _pos_bias = _Alias("estimator_error", "pos_bias")
    _bias_descent_t0 = _Alias("estimator_error", "descent_t0")
    _bias_drift_m_s2 = _Alias("estimator_error", "drift_m_s2")
    _hold_target = _Alias("modes", "hold_target")
    _yaw_sp = _Alias("modes", "yaw_sp")
    _sp_times = _Alias("modes", "sp_times")
    _guided = _Alias("modes", "guided")
    _int = _Alias("control", "integ")
    _airborne = _Alias("land_detector", "airborne")
    _ground_since = _Alias("land_detector", "ground_since")
    _landed_since = _Alias("land_detector", "landed_since")
    _release_at = _Alias("payload", "release_at")
    _accel = _Alias("dynamics", "accel")

    def __post_init__(self) -> None:
        self._pad_track: PadTrack | None = None  # [sim.pad_motion]: the deck it may rest on
        self._init_profile()
        ss, rng_wind = self._init_generators()
        # the estimator errors first, the GPS's after: the order the draws have always had
        self.estimator_error = EstimatorError(self.profile, ss, self._rng_misc, self.pd)
        self._init_autopilot()
        self.wind_model = SimWind(self.cfg, rng_wind, self.profile.wind_ramp_height_m)
        self.gps_error = GpsError(self.cfg, self.profile, self._rng_gps, self._dt)
        self._init_home()
        self._init_loops()

    def _init_profile(self) -> None:
        """The autopilot profile fixes what the firmware decides (sitl/profiles.py); the payload."""
        self.profile = get_profile(self.cfg.profile)
        self.cfg = apply_profile(self.cfg)
        self.payload = SimPayload(self.cfg.winch, (self.pn, self.pe, self.pd))
        if self.payload.winch is not None:
            self.winch, self.parcel = self.payload.winch, self.payload.parcel

    def _init_generators(self) -> tuple[np.random.SeedSequence, np.random.Generator]:
        """The generators of the wind, the GPS, the IMU and the rest, spawned off the seed: the
        sequence (the estimator errors spawn theirs from it after them) and the wind's."""
        ss = np.random.SeedSequence(self.cfg.seed)
        rng_wind, self._rng_gps, self._rng_imu, self._rng_misc = (np.random.default_rng(s) for s in ss.spawn(4))
        return ss, rng_wind

    def _init_autopilot(self) -> None:
        """The firmware's settings the vehicle's own logic reads, and the physics step."""
        # the mode the autopilot's offboard-loss failsafe switches to (PX4: COM_OBL_RC_ACT; the
        # PX4-dialect MAVLink vehicle sets POSITION, measured on PX4 v1.16 SIH)
        self.offboard_loss_mode = FlightMode.HOLD
        self._dt = 1.0 / self.cfg.vehicle.physics_rate_hz

    def _init_home(self) -> None:
        """The true home and its tangent plane; the reported home is set at the first good fix."""
        c = self.cfg
        self._home_true = GeoPoint(c.home.lat_deg, c.home.lon_deg, c.home.alt_amsl_m)
        self._ltp = LocalTangentPlane(self._home_true)
        self._home_reported: GeoPoint | None = None
        self._home_offset = (0.0, 0.0, 0.0)  # the local origin in the estimate's frame (set with home)

    def _init_loops(self) -> None:
        """The commander, the inner loops, the dynamics, the land detector and the step's bookkeeping."""
        self.modes = FlightModes(self)
        self.control = VelocityController()
        self.dynamics = TranslationalDynamics()
        self.land_detector = LandDetector(self.profile.land_detect_s)
        self.landing_targets_received = 0
        self.gnss = SimGnss(self.profile.name)  # GNSS lost and external navigation (gnss_loss.py)
        self._gnss_was_above = False  # above [sim] gnss_lost_below_m once
        self._armed_s = 0.0  # when it was last armed (height_estimate_drift_m_s)
        self._rates = (0.0, 0.0, 0.0)
        self._truth_next = 0.0

    # ------------------------------------------------------------------ commands (sitl/modes.py)
    @property
    def healthy(self) -> bool:
        return self.time_s >= self.cfg.ready_delay_s

    def arm(self) -> None:
        self.modes.arm()

    def disarm(self) -> None:
        self.modes.disarm()

    def takeoff(self, alt_rel_m: float) -> None:
        self.modes.takeoff(alt_rel_m)

    def set_velocity(self, sp: VelocitySetpoint) -> None:
        self.modes.set_velocity(sp)

    def setpoint_fresh(self) -> bool:
        """Offboard setpoints arrived within the offboard-loss timeout."""
        return self.modes.setpoint_fresh()

    def start_offboard(self) -> None:
        self.modes.start_offboard()

    def hold(self) -> None:
        self.modes.hold()

    def land(self) -> None:
        self.modes.land()

    def precision_land(self) -> None:
        """LAND steered by LANDING_TARGET (like PX4 AUTO.PRECLAND): approach the target at height
        until within PLD_HACC_RAD, descend over it; with no target for PLD_BTOUT, plain LAND."""
        self.land()
        self.modes.precland = True
        self._text("precision landing")

    def set_landing_target(self, north_m: float, east_m: float) -> None:
        """A LANDING_TARGET position in the autopilot's local NED frame (its origin at home)."""
        self.modes.set_landing_target(north_m, east_m)

    def pilot_set_mode(self, mode: FlightMode) -> None:
        """The pilot flips the RC mode switch (tests and the RC mixer use this)."""
        self.modes.pilot_set_mode(mode)

    def release_payload(self) -> None:
        self.payload.command_release(self.time_s, self.cfg.vehicle.release_delay_s, self.payload_released)

    def winch_command(self, cmd: WinchCommand) -> None:
        """DO_WINCH as ArduCopter answers it: FAILED without a winch (WINCH_TYPE = 0)."""
        if self.winch is None:
            raise SimCommandError("no winch fitted (ArduCopter: WINCH_TYPE = 0 answers DO_WINCH with FAILED)")
        self.winch.command(cmd)
        self._text(f"winch: action {int(cmd.action)}, {cmd.length_m:+.2f} m")

    # ------------------------------------------------------------------ physics
    def step_to(self, t_s: float) -> None:
        while self.time_s + self._dt <= t_s + 1e-9:
            self._step(self._dt)

    def _step(self, dt: float) -> None:
        """One physics tick: the disturbances, the autopilot (mode logic, velocity loop, attitude)
        on its estimate, then the true vehicle's motion, land detector, battery, winch, truth log."""
        self.time_s += dt
        t = self.time_s
        if self._home_reported is None and self.healthy:
            self._set_home()  # EKF origin and home at the first good GPS fix
        self.wind_model.step(dt, self.pd)
        self.gps_error.step(t, dt, self.cfg.gps_noise_m)
        self.estimator_error.step(t, dt, self.pd)
        if self.cfg.gnss_lost_below_m > 0.0 and not self.gnss.lost:
            self._lose_gnss_when_low()
        if self.gnss.step(t):
            self._ekf_failsafe()
        if self.payload.release_due(t):
            self.payload_released = True
            self._text("payload released")
        vc = self.cfg.vehicle
        thrust_on = self.armed
        sp = self.modes.setpoint(t, dt)
        on_ground = self.dynamics.grounded if vc.soft_ground else self.pd >= -1e-6
        # the velocity loop on the autopilot's velocity estimate (_velocity_estimate), then the attitude
        ve, ff = self._velocity_estimate(), self.modes.feed_forward()
        a_sp = self.control.acceleration(vc, sp, ve, ff, thrust_on and not on_ground, dt)
        yaw_sp = self.modes.yaw_sp if self.armed else None
        att = (self.roll, self.pitch, self.yaw)
        bias = self.estimator_error.att_bias
        (self.roll, self.pitch, self.yaw), self._rates, thrust = attitude_step(
            vc, att, a_sp, self.estimated_yaw(), bias, yaw_sp, dt
        )
        self.dynamics.step(self, thrust, thrust_on, on_ground, dt)
        if self._pad_track is not None:
            self._ride_on_the_deck(t, dt)
        self.land_detector.update(self, t)
        if self.armed and not on_ground:
            self.battery_pct = max(0.0, self.battery_pct - 100.0 * dt / vc.battery_endurance_s)
        if self.winch is not None:
            pos, vel = (self.pn, self.pe, self.pd), (self.vn, self.ve, self.vd)
            w = self.wind_model.now
            self.payload.step_winch(t, dt, pos, vel, (w[0], w[1], w[2]), self.payload_released)
        if t >= self._truth_next:
            self._truth_next = t + 0.1
            self.truth_log.append(TruthSample(t, self.pn, self.pe, self.pd, self.vn, self.ve, self.vd))

    def _land_detector(self, t: float) -> None:
        """The land detector's step (dart_link.StickSimVehicle's own physics calls it)."""
        self.land_detector.update(self, t)

    # ------------------------------------------------------------------ the autopilot's estimate
    def _estimate(self) -> tuple[float, float, float]:
        """The autopilot's own local position estimate (truth + GPS wander, or the part of it the
        estimate has taken where the profile moves the vehicle with it; the height off by the
        profile's scale error, ``height_estimate_scale_error``). GNSS lost (gnss_loss.py): the
        external pose it navigates on, else the error it had when the GPS went."""
        if self.gnss.lost:
            return self._estimate_without_gnss()
        return self._estimate_with_gnss()

    def _estimate_without_gnss(self) -> tuple[float, float, float]:
        gn = self.gnss
        d = self._estimate_with_gnss()[2]  # the barometer's height
        pose = gn.pose_local
        if gn.external_fresh(self.time_s) and pose is not None:
            off = self._home_offset
            return (pose[1] + off[0], pose[2] + off[1], d)
        err = gn.error_at_loss or (0.0, 0.0)
        return (self.pn + err[0], self.pe + err[1], d)

    def lose_gnss(self) -> None:
        """The GPS goes off now (ArduCopter's SIM_GPS1_ENABLE = 0): see gnss_loss.py."""
        est = self._estimate_with_gnss()
        self.gnss.lose(self.time_s, (est[0] - self.pn, est[1] - self.pe))
        self._text("GPS 1: lost")

    def _lose_gnss_when_low(self) -> None:
        """[sim] gnss_lost_below_m: the GPS off coming down through it near the true pad."""
        h, below = -self.pd, self.cfg.gnss_lost_below_m
        self._gnss_was_above = getattr(self, "_gnss_was_above", False) or h > below + 0.5
        pn, pe = self.pad_true_ned
        if (
            self._gnss_was_above
            and h <= below
            and math.hypot(self.pn - pn, self.pe - pe) <= self.cfg.gnss_lost_within_m
        ):
            self.lose_gnss()

    def _ekf_failsafe(self) -> None:
        """The failsafe without a position source, with the firmware's texts: ArduCopter's EKF
        failsafe with FS_EKF_ACTION = 1 lands where it is; PX4 out of OFFBOARD goes to ALTCTL (the
        height held: MANUAL here, zero velocity) and from other modes lands (gnss_loss.py)."""
        m = self.gnss.model
        texts = m.failsafe_texts if m is not None else ("EKF variance",)
        self._text(texts[0])
        if not self.armed or self.mode is FlightMode.LAND:
            return
        if m is not None and not m.failsafe_lands and self.mode is FlightMode.OFFBOARD:
            self.mode = FlightMode.MANUAL
            return
        self.modes.land()
        for text in texts[1:]:
            self._text(text)

    def _estimate_with_gnss(self) -> tuple[float, float, float]:
        g = self.gps_error
        w = g.walk
        d = self.pd * (1.0 + self.cfg.height_estimate_scale_error) + w[2].x
        if self.cfg.height_estimate_drift_m_s and self.armed:  # reads higher by rate x time armed
            d -= self.cfg.height_estimate_drift_m_s * (self.time_s - self._armed_s)
        if self.profile.gps_error_estimate_tau_s > 0.0:
            # the horizontal error is the part the estimate has taken (gps_error_estimate_*)
            return (self.pn + g.in_est[0], self.pe + g.in_est[1], d)
        if self.estimator_error.state is not None:
            pb = self.estimator_error.pos_bias
            return (self.pn + w[0].x + pb[0], self.pe + w[1].x + pb[1], d)
        return (self.pn + w[0].x, self.pe + w[1].x, d)

    def _velocity_bias(self) -> tuple[float, float]:
        """The estimator state's horizontal velocity bias (N, E) now (EstimatorError.velocity_bias)."""
        return self.estimator_error.velocity_bias(self.time_s, self.pd)

    def _velocity_estimate_h(self) -> tuple[float, float]:
        """The horizontal velocity the autopilot's velocity loop closes on: truth + the rate at
        which its estimate takes the GPS error (gps_error_estimate_*), with a PX4 profile's
        velocity error where it flies on it (velocity_loop_on_estimate)."""
        vn, ve = self.vn, self.ve
        if self.profile.gps_error_estimate_tau_s > 0.0:
            k = self.profile.gps_error_velocity_share
            vn += k * self.gps_error.in_est_rate[0]
            ve += k * self.gps_error.in_est_rate[1]
        verr = self.estimator_error.verr
        if verr and self.profile.velocity_loop_on_estimate:
            vn += verr[0].x
            ve += verr[1].x
        return vn, ve

    def _velocity_estimate(self) -> tuple[float, float, float]:
        """The velocity the velocity loop runs on (N, E, D): truth + the profile's error (PX4 SIH
        drifts on it; ArduCopter holds a position target, so its error does not drive the
        vehicle: profiles.py)."""
        ee = self.estimator_error
        ve_n, ve_e = self._velocity_estimate_h()
        ve_d = self.vd
        if ee.verr and self.profile.velocity_loop_on_estimate:
            ve_n += ee.verr[0].x
            ve_e += ee.verr[1].x
            ve_d += ee.verr[2].x
        if ee.state is not None and self.profile.velocity_loop_on_estimate:
            bn, be = self._velocity_bias()
            ve_n += bn
            ve_e += be
        return (ve_n, ve_e, ve_d)

    # read-only views of the autopilot's estimate for tests and tools (the private methods stay
    # what the vehicle's own parts call; these only read them, nothing is drawn)
    @property
    def velocity_bias_ne_m_s(self) -> tuple[float, float]:
        """The estimator state's horizontal velocity bias now (N, E; m/s; zero without a state)."""
        return self._velocity_bias()

    @property
    def estimate_ned_m(self) -> tuple[float, float, float]:
        """The autopilot's position estimate in its own frame (N, E, D; m), before home is taken off."""
        return self._estimate()

    @property
    def local_estimate_ned_m(self) -> tuple[float, float, float]:
        """The autopilot's position estimate from home (N, E, D; m): what position_ned reports
        before its report noise."""
        return self._local()

    @property
    def home_offset_ned_m(self) -> tuple[float, float, float]:
        """The local origin in the estimate's frame (N, E, D; m): the estimate when home was set."""
        return self._home_offset

    @property
    def estimator_state(self) -> EstimatorState | None:
        """The estimator state drawn for this flight (profiles.EstimatorState; None without)."""
        return self.estimator_error.state

    def estimated_yaw(self) -> float:
        """The autopilot's yaw estimate: the true yaw plus its estimator state's offset (the truth
        itself without a state)."""
        if self.estimator_error.state is None:
            return self.yaw
        return wrap_angle(self.yaw + self.estimator_error.att_bias[2])

    def _set_home(self) -> None:
        # The home the autopilot reports is its GPS position at arming: the bias lives in it.
        est = self._estimate()
        b = self.gps_error.bias
        self._home_reported = self._ltp.to_geo(est[0] + b[0], est[1] + b[1], est[2] + b[2])
        self._home_offset = est  # local origin at home (estimate at arming)

    def _text(self, msg: str) -> None:
        log.debug("sim vehicle t=%.2f: %s", self.time_s, msg)
        self.status_texts.append((self.time_s, msg))

    # ------------------------------------------------------------------ telemetry
    def _local(self) -> tuple[float, float, float]:
        est = self._estimate()
        off = self._home_offset
        return (est[0] - off[0], est[1] - off[1], est[2] - off[2])

    def position_ned(self) -> PositionNed:
        n, e, d = self._local()
        r = [x * 0.03 for x in self._rng_misc.standard_normal(3).tolist()]
        vn, ve, vd = self.vn, self.ve, self.vd
        verr = self.estimator_error.verr
        if verr:  # the reported velocity is the estimate the velocity loop flies on
            vn += verr[0].x
            ve += verr[1].x
            vd += verr[2].x
        if self.estimator_error.state is not None:
            bn, be = self._velocity_bias()
            vn += bn
            ve += be
        return PositionNed(self.time_s, n, e, d, vn + r[0], ve + r[1], vd + r[2])

    def global_position(self) -> GlobalPosition:
        est = self._estimate()
        b = self.gps_error.bias
        g = self._ltp.to_geo(est[0] + b[0], est[1] + b[1], est[2] + b[2])
        home_alt = self._home_reported.alt_amsl_m if self._home_reported else self._home_true.alt_amsl_m
        return GlobalPosition(self.time_s, g.lat_deg, g.lon_deg, g.alt_amsl_m, g.alt_amsl_m - home_alt)

    def gps_raw(self) -> GpsRaw:
        est = self._estimate()
        b = self.gps_error.bias
        r = [x * self.cfg.gps_noise_m for x in self._rng_gps.standard_normal(3).tolist()]
        g = self._ltp.to_geo(est[0] + b[0] + r[0], est[1] + b[1] + r[1], est[2] + b[2] + r[2])
        m = self.gnss.model
        if self.gnss.lost and m is not None:
            return GpsRaw(self.time_s, g.lat_deg, g.lon_deg, g.alt_amsl_m, m.lost_fix_type, m.lost_satellites, 0.8)
        return GpsRaw(self.time_s, g.lat_deg, g.lon_deg, g.alt_amsl_m, 3 if self.healthy else 1, 14, 0.8)

    def attitude(self) -> Attitude:
        p, q, r = self._rates
        if self.estimator_error.state is None:
            return Attitude(self.time_s, self.roll, self.pitch, self.yaw, p, q, r)
        b = self.estimator_error.att_bias  # what the estimator reports is off the truth by its state's offset
        return Attitude(self.time_s, self.roll + b[0], self.pitch + b[1], wrap_angle(self.yaw + b[2]), p, q, r)

    def imu(self) -> Imu:
        """Specific force and body rates in FRD, with white noise."""
        a_n, a_e, a_d = self.dynamics.accel
        f = (a_n, a_e, a_d - G)
        cr, sr = math.cos(self.roll), math.sin(self.roll)
        cp, sp = math.cos(self.pitch), math.sin(self.pitch)
        cy, sy = math.cos(self.yaw), math.sin(self.yaw)
        # R^T (world->body) rows are R's columns
        R = (
            (cy * cp, sy * cp, -sp),
            (cy * sp * sr - sy * cr, sy * sp * sr + cy * cr, cp * sr),
            (cy * sp * cr + sy * sr, sy * sp * cr - cy * sr, cp * cr),
        )
        fb = [R[i][0] * f[0] + R[i][1] * f[1] + R[i][2] * f[2] for i in range(3)]
        na = self._rng_imu.standard_normal(6).tolist()
        sa, sg = self.cfg.accel_noise_m_s2, self.cfg.gyro_noise_rad_s
        p, q, r = self._rates
        return Imu(
            self.time_s,
            fb[0] + sa * na[0],
            fb[1] + sa * na[1],
            fb[2] + sa * na[2],
            p + sg * na[3],
            q + sg * na[4],
            r + sg * na[5],
        )

    def wind_ned(self) -> tuple[float, float]:
        """The wind at the vehicle now (mean and gust; where the air moves, N and E, m/s): what the
        autopilot's estimate converges to, reported as it by the simulated autopilots."""
        return self.wind_model.now[0], self.wind_model.now[1]

    def set_wind(self, speed_m_s: float, from_deg: float) -> None:
        """Change the mean wind (a test's weather change); the gusts go on around it."""
        self.wind_model.set_mean(speed_m_s, from_deg)

    def status(self) -> VehicleStatus:
        return VehicleStatus(
            self.time_s, self.armed, self.mode, self.landed, self.healthy, self.battery_pct, self.payload_released
        )

    def home(self) -> HomePosition | None:
        h = self._home_reported
        if h is None:
            return None
        return HomePosition(self.time_s, h.lat_deg, h.lon_deg, h.alt_amsl_m)

    # ------------------------------------------------------------------ truth
    @property
    def pad_true_ned(self) -> tuple[float, float]:
        """Not known by the vehicle: filled in by the scenario (configured pad + displacement)."""
        return getattr(self, "_pad_true", (math.nan, math.nan))

    def set_pad_truth(self, north_m: float, east_m: float) -> None:
        self._pad_true = (north_m, east_m)

    def set_pad_track(self, track: PadTrack | None) -> None:
        """The pad moves ([sim.pad_motion]): resting on its deck the vehicle rides along."""
        self._pad_track = track

    def _ride_on_the_deck(self, t: float, dt: float) -> None:
        """Resting on the moving pad's deck (``deck_size_m``, a square turned with the pad), the
        vehicle is carried by it: its offset from the pad kept in the pad's frame, its heading
        turned with it, its velocity the deck's (the GPS reports the van's speed)."""
        track = self._pad_track
        assert track is not None
        if self.pd < -1e-6 or self.vd < 0.0:
            return
        n0, e0, yaw0, _, _ = track.state(t - dt)
        dn, de = self.pn - n0, self.pe - e0
        c, s = math.cos(yaw0), math.sin(yaw0)  # the offset in the pad's axes (its up edge along yaw)
        if max(abs(c * dn + s * de), abs(-s * dn + c * de)) > 0.5 * track.config.deck_size_m:
            return  # on the ground beside the deck
        n1, e1, yaw1, vn, ve = track.state(t)
        dy = yaw1 - yaw0
        cd, sd = math.cos(dy), math.sin(dy)
        self.pn, self.pe = n1 + cd * dn - sd * de, e1 + sd * dn + cd * de
        self.yaw = wrap_angle(self.yaw + dy)
        self.vn, self.ve = vn, ve

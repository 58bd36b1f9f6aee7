"""Embedded multicopter: translational rigid-body dynamics with PX4-like inner loops.

Synchronous and deterministic by seed. The model is what a PX4 SIH quad looks like to a
companion computer: an attitude-limited velocity loop (P + I, accel and tilt limits, first-order
tilt response), modes (HOLD, TAKEOFF, LAND, OFFBOARD with its setpoint rules and loss failsafe),
a land detector, and the autopilot's own GPS-based estimate (truth + wander + bias), which is
what it reports and what its own position loops use.

Frames: world NED at the (true) home position, metres; ground is flat at down = 0.
Plain floats in the hot path: numpy on 3-vectors costs more than the arithmetic.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, field

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
from companion_sitl.params import SimConfig
from companion_sitl.profiles import (
    VELOCITY_BIAS_DESCENT_SPEED_M_S,
    VELOCITY_BIAS_DESCENT_START_M,
    VELOCITY_BIAS_DRIFT_MAX_M_S,
    VELOCITY_BIAS_DRIFT_RATE_M_S2,
    VELOCITY_BIAS_HEIGHTS_M,
    EstimatorState,
    apply_profile,
    get_profile,
)
from companion_sitl.winch import ParcelOnLine, SimWinch

log = logging.getLogger(__name__)

G = 9.80665
HOLD_MAX_H_SPEED = 5.0
HOLD_MAX_V_SPEED = 1.5
OFFBOARD_MIN_SETPOINT_RATE_HZ = 2.0
AUTO_DISARM_AFTER_LAND_S = 2.0
PLD_HACC_RAD_M = 0.2  # PX4 precision landing: horizontal acceptance radius before descending
PLD_BTOUT_S = 5.0  # PX4 precision landing: target lost after this long -> plain landing
YAW_RATE_MAX = math.radians(60.0)
GPS_FIX_PERIOD_S = 0.2  # a GPS receiver's 5 Hz fixes (ArduPilot SITL's default SIM_GPS1_HZ)


PARCEL_STEP_HZ = 1000.0  # the parcel pendulum's least integration rate (sitl/winch.py)

# the modes that hold a position target (no setpoint of their own in the sim)
_POSITION_HOLD_MODES = (
    FlightMode.HOLD,
    FlightMode.POSITION,
    FlightMode.MANUAL,
    FlightMode.RTL,
    FlightMode.MISSION,
    FlightMode.UNKNOWN,
)


def _sqrt_controller_2d(en: float, ee: float, p: float, second_ord_lim: float, dt: float) -> tuple[float, float]:
    """ArduPilot's sqrt_controller on a 2-D error: p x error up to the distance where the
    correction's rate would reach ``second_ord_lim``, a square root beyond it, never more than
    the error closed in one ``dt``."""
    e = math.hypot(en, ee)
    if e == 0.0:
        return 0.0, 0.0
    linear = second_ord_lim / (p * p)
    c = math.sqrt(2.0 * second_ord_lim * (e - 0.5 * linear)) if e > linear else p * e
    c = min(c, e / dt)
    return en * c / e, ee * c / e


class SimCommandError(RuntimeError):
    """The simulated autopilot refused a command (as PX4 would, with its reason)."""


@dataclass
class Touchdown:
    time_s: float
    north_m: float
    east_m: float
    payload_released: bool
    yaw_rad: float = math.nan  # true heading at touchdown (NED)


@dataclass
class TruthSample:
    time_s: float
    north_m: float
    east_m: float
    down_m: float
    north_m_s: float
    east_m_s: float
    down_m_s: float


@dataclass
class _GaussMarkov:
    """First-order Gauss-Markov process x' = -x/tau + w, stationary std ``sigma``."""

    sigma: float
    tau: float
    x: float = 0.0
    # (dt, sigma, tau) -> (a, sigma * sqrt(1 - a^2)) of the last step: the physics steps at one dt
    _coef: tuple[float, float, float, float, float] | None = field(default=None, repr=False, compare=False)

    def step(self, dt: float, n: float) -> float:
        c = self._coef
        if c is None or c[0] != dt or c[1] != self.sigma or c[2] != self.tau:
            a = math.exp(-dt / self.tau)
            c = self._coef = (dt, self.sigma, self.tau, a, self.sigma * math.sqrt(1.0 - a * a))
        self.x = c[3] * self.x + c[4] * n
        return self.x


GaussMarkov = _GaussMarkov  # the same process where a harness drives a real SITL (lab/real_weather.py)


@dataclass
class SimVehicle:
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

    def __post_init__(self) -> None:
        # the autopilot profile fixes what the firmware decides (sitl/profiles.py)
        self.profile = get_profile(self.cfg.profile)
        self.cfg = apply_profile(self.cfg)
        wc = self.cfg.winch
        if wc.fitted:
            self.winch = SimWinch(wc.rate_max_m_s, wc.pos_p, stuck=wc.stuck)
            self.parcel = ParcelOnLine(wc.parcel_drag_1_s)
            self._winch_prev = (self.pn, self.pe, self.pd)
        c = self.cfg
        ss = np.random.SeedSequence(c.seed)
        self._rng_wind, self._rng_gps, self._rng_imu, self._rng_misc = (np.random.default_rng(s) for s in ss.spawn(4))
        # the autopilot's velocity-estimate error (profile; none for ideal: no draw, no cost)
        self._verr: list[_GaussMarkov] = []
        if self.profile.velocity_error_m_s > 0.0:
            self._rng_verr = np.random.default_rng(ss.spawn(1)[0])
            pr = self.profile
            self._verr = [
                _GaussMarkov(pr.velocity_error_m_s, pr.velocity_error_tau_s),
                _GaussMarkov(pr.velocity_error_m_s, pr.velocity_error_tau_s),
                _GaussMarkov(pr.velocity_error_down_m_s, pr.velocity_error_tau_s),
            ]
            for w in self._verr:
                w.x = w.sigma * float(self._rng_verr.standard_normal())
        # the estimator's state for this flight (profiles.EstimatorState; drawn after the error's
        # start so a profile without states draws exactly as before)
        self.estimator_state: EstimatorState | None = None
        self._att_bias = (0.0, 0.0, 0.0)  # reported - true roll, pitch, yaw (rad)
        self._pos_bias = [0.0, 0.0]  # the position estimate's share of the velocity bias (N, E; m)
        # when the descent passed VELOCITY_BIAS_DESCENT_START_M (None: not in such a descent)
        self._above_bias_start = False
        self._bias_descent_t0: float | None = None
        self._bias_drift_m_s2: tuple[float, ...] = (0.0, 0.0)  # N, E: the drift past the traced window
        if self.profile.estimator_states:
            u = float(self._rng_verr.uniform()) if self._verr else float(self._rng_misc.uniform())
            acc = 0.0
            for es in self.profile.estimator_states:
                acc += es.probability
                self.estimator_state = es
                if u < acc:
                    break
            assert self.estimator_state is not None
            roll_b, pitch_b, yaw_b = self.estimator_state.attitude_bias_deg
            self._att_bias = (math.radians(roll_b), math.radians(pitch_b), math.radians(yaw_b))
            # the position estimate's share of the bias, from its steady state on the ground
            tau_p = self.estimator_state.position_follows_bias_tau_s
            b0 = self._velocity_bias()
            self._pos_bias = [b0[0] * tau_p, b0[1] * tau_p]
            # the drift's rates from a stream of their own: every other draw stays as it was
            rng = np.random.default_rng(ss.spawn(1)[0])
            self._bias_drift_m_s2 = tuple(VELOCITY_BIAS_DRIFT_RATE_M_S2 * x for x in rng.standard_normal(2).tolist())
        self._land_detect_s = self.profile.land_detect_s
        # the mode the autopilot's offboard-loss failsafe switches to (PX4: COM_OBL_RC_ACT; the
        # PX4-dialect MAVLink vehicle sets POSITION, measured on PX4 v1.16 SIH)
        self.offboard_loss_mode = FlightMode.HOLD
        self._dt = 1.0 / c.vehicle.physics_rate_hz
        # wind: mean from "wind_from", gusts as Gauss-Markov per axis
        wf = math.radians(c.wind_from_deg)
        self._wind_mean = (-c.wind_speed_m_s * math.cos(wf), -c.wind_speed_m_s * math.sin(wf), 0.0)
        gs = c.gust_std_effective_m_s
        tau = c.gust_time_constant_s
        self._gust = [_GaussMarkov(gs, tau), _GaussMarkov(gs, tau), _GaussMarkov(0.3 * gs, tau)]
        self._wind = list(self._wind_mean)
        # autopilot estimate error: slow wander (horizontal/vertical) + constant bias
        self._walk = [
            _GaussMarkov(c.gps_walk_m, c.gps_walk_time_constant_s),
            _GaussMarkov(c.gps_walk_m, c.gps_walk_time_constant_s),
            _GaussMarkov(1.5 * c.gps_walk_m, c.gps_walk_time_constant_s),
        ]
        for w in self._walk:  # start from the stationary distribution
            w.x = w.sigma * float(self._rng_gps.standard_normal())
        # the part of the horizontal GPS error the estimate has taken (profiles.gps_error_estimate_*;
        # N, E, m) and its rate (m/s: the velocity estimate's error, and the second-order state)
        self._gps_in_est = [self._walk[0].x, self._walk[1].x]
        self._gps_in_est_rate = [0.0, 0.0]
        # the GPS fix's white noise (gps_noise_m) at the receiver's 5 Hz, which the estimate takes
        # too; its own generator, so the other draws stay as they were
        self._rng_fix = np.random.default_rng([c.seed, 0x6F1C])
        self._fix_noise = (0.0, 0.0)
        self._fix_next_s = 0.0
        # the estimate's response per physics step (computed once: _step runs at one dt): the
        # first-order step coefficient, and the second-order x'' = w^2 (err - x) - 2 zeta w x' as
        # (w^2, 2 zeta w), (0, 0) for first order
        pr = self.profile
        tau_e = pr.gps_error_estimate_tau_s
        self._gps_lag_a = 1.0 - math.exp(-self._dt / tau_e) if tau_e > 0.0 else 1.0
        w_e = 1.0 / tau_e if tau_e > 0.0 else 0.0
        self._gps_est_2nd = (w_e * w_e, 2.0 * pr.gps_error_estimate_damping * w_e)
        # GUIDED's shaped setpoint (profiles.guided_*): the position target, desired velocity and
        # acceleration (N, E); None outside OFFBOARD (set from the estimate on entering it)
        self._guided: tuple[list[float], list[float], list[float]] | None = None
        self._bias = tuple(c.gps_bias_m)
        self._home_true = GeoPoint(c.home.lat_deg, c.home.lon_deg, c.home.alt_amsl_m)
        self._ltp = LocalTangentPlane(self._home_true)
        self._home_reported: GeoPoint | None = None
        # velocity loop
        self._int = [0.0, 0.0, 0.0]
        self._hold_target: tuple[float, float, float] | None = None
        self._takeoff_target_d = 0.0
        self._yaw_sp = 0.0
        self._sp: VelocitySetpoint | None = None
        self._precland = False
        self._pl_target: tuple[float, float] | None = None
        self._pl_seen_s = -math.inf
        self.landing_targets_received = 0
        self._sp_times: list[float] = []
        self._ground_since: float | None = 0.0
        self._armed_s = 0.0  # when it was last armed (height_estimate_drift_m_s)
        self._landed_since: float | None = 0.0
        self._release_at: float | None = None
        self._rates = (0.0, 0.0, 0.0)
        self._accel = (0.0, 0.0, 0.0)
        self._airborne = False
        self._grounded = True  # resting on the ground (soft_ground: where it was caught)
        self._truth_next = 0.0

    # ------------------------------------------------------------------ commands
    @property
    def healthy(self) -> bool:
        return self.time_s >= self.cfg.ready_delay_s

    def arm(self) -> None:
        if self.armed:
            return
        if not self.healthy:
            raise SimCommandError("arming denied: estimator/GPS not ready")
        if self.landed is not LandedState.ON_GROUND:
            raise SimCommandError("arming denied: not landed")
        if self.battery_pct < 10.0:
            raise SimCommandError(f"arming denied: battery {self.battery_pct:.0f} %")
        self.armed = True
        self._armed_s = self.time_s  # the height estimate's drift counts from here (height_estimate_drift_m_s)
        self.mode = FlightMode.HOLD
        self._int = [0.0, 0.0, 0.0]
        self._yaw_sp = self.estimated_yaw()
        self._hold_target = None
        self._text("armed")

    def disarm(self) -> None:
        if not self.armed:
            return
        if self.landed is not LandedState.ON_GROUND:
            raise SimCommandError("disarming denied: not landed")
        self.armed = False
        self._text("disarmed")

    def takeoff(self, alt_rel_m: float) -> None:
        if not self.armed:
            raise SimCommandError("takeoff denied: not armed")
        if not (math.isfinite(alt_rel_m) and 0.5 <= alt_rel_m <= 100.0):
            raise SimCommandError(f"takeoff denied: altitude {alt_rel_m} m out of range")
        est = self._estimate()
        self._takeoff_target_d = est[2] - alt_rel_m
        self._hold_target = (est[0], est[1], self._takeoff_target_d)
        self.mode = FlightMode.TAKEOFF
        self._yaw_sp = self.estimated_yaw()

    def set_velocity(self, sp: VelocitySetpoint) -> None:
        vals = (sp.north_m_s, sp.east_m_s, sp.down_m_s, sp.yaw_rad, *(sp.accel_ne_m_s2 or ()))
        if not all(math.isfinite(v) for v in vals):
            self._text(f"offboard setpoint rejected: not finite {vals}")
            return
        self._sp = sp
        self._sp_times.append(self.time_s)
        if len(self._sp_times) > 50:
            del self._sp_times[:-50]

    def setpoint_fresh(self) -> bool:
        """Offboard setpoints arrived within the offboard-loss timeout."""
        return bool(self._sp_times) and self.time_s - self._sp_times[-1] <= self.cfg.vehicle.offboard_loss_timeout_s

    def start_offboard(self) -> None:
        if not self.armed:
            raise SimCommandError("offboard denied: not armed")
        recent = [t for t in self._sp_times if self.time_s - t <= 1.0]
        if len(recent) < OFFBOARD_MIN_SETPOINT_RATE_HZ + 1 or self.time_s - recent[-1] > 0.5:
            raise SimCommandError("offboard denied: no setpoints streamed (need > 2 Hz before switching)")
        self.mode = FlightMode.OFFBOARD

    def hold(self) -> None:
        est = self._estimate()
        self._hold_target = est
        self.mode = FlightMode.HOLD

    def land(self) -> None:
        if not self.armed:
            raise SimCommandError("land denied: not armed")
        est = self._estimate()
        self._hold_target = est
        self._precland = False
        self.mode = FlightMode.LAND

    def precision_land(self) -> None:
        """LAND steered by LANDING_TARGET (like PX4 AUTO.PRECLAND): approach the target at height
        until within PLD_HACC_RAD, descend over it; with no target for PLD_BTOUT, plain LAND."""
        self.land()
        self._precland = True
        self._text("precision landing")

    def set_landing_target(self, north_m: float, east_m: float) -> None:
        """A LANDING_TARGET position in the autopilot's local NED frame (its origin at home)."""
        if not (math.isfinite(north_m) and math.isfinite(east_m)):
            self._text(f"landing target rejected: not finite {(north_m, east_m)}")
            return
        off = getattr(self, "_home_offset", (0.0, 0.0, 0.0))
        self._pl_target = (north_m + off[0], east_m + off[1])  # into the estimate frame the controller uses
        self._pl_seen_s = self.time_s
        self.landing_targets_received += 1

    def release_payload(self) -> None:
        if self._release_at is None and not self.payload_released:
            self._release_at = self.time_s + self.cfg.vehicle.release_delay_s

    # ------------------------------------------------------------------ winch (sitl/winch.py)
    winch: SimWinch | None = None  # set in __post_init__ when sim.winch.fitted
    parcel: ParcelOnLine | None = None

    def winch_command(self, cmd: WinchCommand) -> None:
        """DO_WINCH as ArduCopter answers it: FAILED without a winch (WINCH_TYPE = 0)."""
        if self.winch is None:
            raise SimCommandError("no winch fitted (ArduCopter: WINCH_TYPE = 0 answers DO_WINCH with FAILED)")
        self.winch.command(cmd)
        self._text(f"winch: action {int(cmd.action)}, {cmd.length_m:+.2f} m")

    def _step_winch(self, t: float, dt: float) -> None:
        w, par = self.winch, self.parcel
        assert w is not None and par is not None
        l0 = w.length_m
        w.step(dt)
        l1 = w.length_m
        if self.payload_released and not par.released:
            par.release()
        # the pendulum at >= 1 kHz: its numerical damping is then below 1 % of the swing per period
        n = max(1, math.ceil(dt * PARCEL_STEP_HZ - 1e-9))
        h = dt / n
        a0 = self._winch_prev
        a1 = (self.pn, self.pe, self.pd)
        va = (self.vn, self.ve, self.vd)
        wind = (self._wind[0], self._wind[1], self._wind[2])
        for k in range(1, n + 1):
            f = k / n
            a = (a0[0] + f * (a1[0] - a0[0]), a0[1] + f * (a1[1] - a0[1]), a0[2] + f * (a1[2] - a0[2]))
            par.step(t - dt + k * h, h, a, va, l0 + f * (l1 - l0), wind)
        self._winch_prev = a1

    def pilot_set_mode(self, mode: FlightMode) -> None:
        """The pilot flips the RC mode switch (tests and the RC mixer use this)."""
        if mode in (FlightMode.POSITION, FlightMode.HOLD, FlightMode.LAND):
            self._hold_target = self._estimate()
        self.mode = mode
        self._text(f"pilot switched to {mode.value}")

    # ------------------------------------------------------------------ physics
    def step_to(self, t_s: float) -> None:
        while self.time_s + self._dt <= t_s + 1e-9:
            self._step(self._dt)

    def _estimate(self) -> tuple[float, float, float]:
        """The autopilot's own local position estimate (truth + GPS wander, or the part of it the
        estimate has taken where the profile moves the vehicle with it; the height off by the
        profile's scale error, ``height_estimate_scale_error``)."""
        w = self._walk
        d = self.pd * (1.0 + self.cfg.height_estimate_scale_error) + w[2].x
        if self.cfg.height_estimate_drift_m_s and self.armed:  # reads higher by rate x time armed
            d -= self.cfg.height_estimate_drift_m_s * (self.time_s - self._armed_s)
        if self.profile.gps_error_estimate_tau_s > 0.0:
            # the horizontal error is the part the estimate has taken (gps_error_estimate_*)
            return (self.pn + self._gps_in_est[0], self.pe + self._gps_in_est[1], d)
        if self.estimator_state is not None:
            pb = self._pos_bias
            return (self.pn + w[0].x + pb[0], self.pe + w[1].x + pb[1], d)
        return (self.pn + w[0].x, self.pe + w[1].x, d)

    def _velocity_bias(self) -> tuple[float, float]:
        """The estimator state's horizontal velocity bias (N, E): linear between the heights it
        was measured at, constant outside them. In a descent from above the traced descent's start,
        at the height that descent had reached after the time since passing it (the estimate
        wanders with time in calm flight, so a slower descent or a hover lands on more of it);
        elsewhere at the true height above ground."""
        es = self.estimator_state
        if es is None:
            return (0.0, 0.0)
        hs, vs = VELOCITY_BIAS_HEIGHTS_M, es.velocity_bias_m_s
        if self._bias_descent_t0 is not None:
            h = VELOCITY_BIAS_DESCENT_START_M - VELOCITY_BIAS_DESCENT_SPEED_M_S * (self.time_s - self._bias_descent_t0)
            if h < hs[0]:  # past the traced window: drifting on
                late_s = (hs[0] - h) / VELOCITY_BIAS_DESCENT_SPEED_M_S
                cap = VELOCITY_BIAS_DRIFT_MAX_M_S
                dn, de = (max(-cap, min(cap, r * late_s)) for r in self._bias_drift_m_s2)
                return (vs[0][0] + dn, vs[0][1] + de)
        else:
            h = -self.pd
        if h <= hs[0]:
            return vs[0]
        for i in range(1, len(hs)):
            if h <= hs[i]:
                k = (h - hs[i - 1]) / (hs[i] - hs[i - 1])
                a, b = vs[i - 1], vs[i]
                return (a[0] + k * (b[0] - a[0]), a[1] + k * (b[1] - a[1]))
        return vs[-1]

    def _step(self, dt: float) -> None:
        """One physics tick: the disturbances, the autopilot (mode logic, velocity loop, attitude)
        on its estimate, then the true vehicle's motion, land detector, battery, winch, truth log."""
        self.time_s += dt
        t = self.time_s
        if self._home_reported is None and self.healthy:
            self._set_home()  # EKF origin and home at the first good GPS fix
        self._step_wind(dt)
        self._step_gps_error(t, dt)
        if self._verr:
            rv = self._rng_verr.standard_normal(3).tolist()
            for i in range(3):
                self._verr[i].step(dt, rv[i])
        if self.estimator_state is not None:
            self._step_estimator_bias(t, dt)
        if self._release_at is not None and t >= self._release_at:
            self.payload_released = True
            self._release_at = None
            self._text("payload released")
        vc = self.cfg.vehicle
        thrust_on = self.armed
        sp = self._mode_setpoint(t, dt)
        on_ground = self._grounded if vc.soft_ground else self.pd >= -1e-6
        a_sp = self._velocity_loop(sp, thrust_on and not on_ground, dt)
        thrust = self._attitude_step(a_sp, dt)
        self._move(thrust, thrust_on, on_ground, dt)
        self._land_detector(t)
        if self.armed and not on_ground:
            self.battery_pct = max(0.0, self.battery_pct - 100.0 * dt / vc.battery_endurance_s)
        if self.winch is not None:
            self._step_winch(t, dt)
        if t >= self._truth_next:
            self._truth_next = t + 0.1
            self.truth_log.append(TruthSample(t, self.pn, self.pe, self.pd, self.vn, self.ve, self.vd))

    def _step_wind(self, dt: float) -> None:
        """The wind: mean + gusts, faded towards the ground by the profile's ramp."""
        rn = self._rng_wind.standard_normal(3).tolist()  # Python floats: the same values, no numpy scalars
        for i in range(3):
            self._wind[i] = self._wind_mean[i] + self._gust[i].step(dt, rn[i])
        ramp = self.profile.wind_ramp_height_m
        if ramp > 0.0 and -self.pd < ramp:  # the SITL's wind fades towards the ground (profiles.py)
            k = math.sqrt(max(0.0, -self.pd) / ramp)
            for i in range(3):
                self._wind[i] *= k

    def _step_gps_error(self, t: float, dt: float) -> None:
        """The GPS error's random walk, and the part of it the autopilot's estimate has taken
        where the profile has one (gps_error_estimate_*)."""
        c = self.cfg
        rg = self._rng_gps.standard_normal(3).tolist()
        for i in range(3):
            self._walk[i].step(dt, rg[i])
        if self.profile.gps_error_estimate_tau_s <= 0.0:
            return
        if t >= self._fix_next_s:
            self._fix_next_s = t + GPS_FIX_PERIOD_S
            r = self._rng_fix.standard_normal(2).tolist()
            self._fix_noise = (c.gps_noise_m * r[0], c.gps_noise_m * r[1])
        # the estimate takes the error (first or second order, gps_error_estimate_*); a vehicle
        # held on the estimate then moves against it (GUIDED's position target, _mode_setpoint)
        a = self._gps_lag_a
        w2, c2 = self._gps_est_2nd
        for i in range(2):
            err = self._walk[i].x + self._fix_noise[i]
            if c2 > 0.0:  # second order, semi-implicit Euler (w dt <= 0.03 here)
                rate = self._gps_in_est_rate[i]
                rate += dt * (w2 * (err - self._gps_in_est[i]) - c2 * rate)
                self._gps_in_est_rate[i] = rate
                self._gps_in_est[i] += dt * rate
            else:  # first order, exact for the error held over dt
                d = a * (err - self._gps_in_est[i])
                self._gps_in_est[i] += d
                self._gps_in_est_rate[i] = d / dt

    def _step_estimator_bias(self, t: float, dt: float) -> None:
        """The estimator state's position bias: it drifts with the velocity bias, GPS pulls it
        back (EstimatorState); and the time the traced descent's start was passed on the way down."""
        es = self.estimator_state
        assert es is not None
        if -self.pd > VELOCITY_BIAS_DESCENT_START_M:
            self._above_bias_start, self._bias_descent_t0 = True, None
        elif self._above_bias_start:  # passing the traced descent's start on the way down
            self._above_bias_start, self._bias_descent_t0 = False, t
        # exact step of de/dt = b - e / tau for b constant over dt
        bn, be = self._velocity_bias()
        tau_p = es.position_follows_bias_tau_s
        a = math.exp(-dt / tau_p)
        self._pos_bias[0] = a * self._pos_bias[0] + (1.0 - a) * tau_p * bn
        self._pos_bias[1] = a * self._pos_bias[1] + (1.0 - a) * tau_p * be

    def _mode_setpoint(self, t: float, dt: float) -> tuple[float, float, float]:
        """The mode logic (autopilot side, on its estimate): the velocity setpoint (N, E, D).
        A mode that hands over (OFFBOARD's failsafe, TAKEOFF done) lets the next one set it in
        the same tick."""
        est = self._estimate()
        sp = (0.0, 0.0, 0.0)
        if self.armed:
            if self.mode is FlightMode.OFFBOARD:
                sp = self._offboard_setpoint(t, dt, est)
            if self.mode is FlightMode.TAKEOFF:
                assert self._hold_target is not None
                sp_n, sp_e, _ = self._pos_ctrl(est, self._hold_target)
                sp = (sp_n, sp_e, -self.cfg.vehicle.takeoff_speed_m_s)
                # done within the altitude acceptance radius: HOLD then climbs on to the height
                if est[2] <= self._takeoff_target_d + self.cfg.vehicle.takeoff_altitude_acceptance_m:
                    self.mode = FlightMode.HOLD
            if self.mode in _POSITION_HOLD_MODES:
                if self._hold_target is None:
                    self._hold_target = est
                sp = self._pos_ctrl(est, self._hold_target)
            if self.mode is FlightMode.LAND:
                sp = self._land_setpoint(t, est)
        if not self.armed or self.mode is not FlightMode.OFFBOARD:
            self._guided = None
        return sp

    def _offboard_setpoint(self, t: float, dt: float, est: tuple[float, float, float]) -> tuple[float, float, float]:
        """OFFBOARD: the companion's setpoint, cut to the autopilot's limits; a setpoint stream
        that stopped is the failsafe (its mode then holds position)."""
        vc = self.cfg.vehicle
        if self._sp is None or t - self._sp_times[-1] > vc.offboard_loss_timeout_s:
            self._text(f"offboard lost: failsafe {self.offboard_loss_mode.value}")
            self.hold()
            self.mode = self.offboard_loss_mode  # holds position in either
            return (0.0, 0.0, 0.0)
        sp_n, sp_e, sp_d = self._sp.north_m_s, self._sp.east_m_s, self._sp.down_m_s
        self._yaw_sp = self._sp.yaw_rad
        # the autopilot cuts each axis on its own (PX4's position control: horizontal
        # norm to MPC_XY_VEL_MAX, down / up to MPC_Z_VEL_MAX_DN / _UP)
        h = math.hypot(sp_n, sp_e)
        if h > vc.offboard_max_horizontal_m_s:
            k_h = vc.offboard_max_horizontal_m_s / h
            sp_n, sp_e = sp_n * k_h, sp_e * k_h
        sp_d = min(max(sp_d, -vc.offboard_max_up_m_s), vc.offboard_max_down_m_s)
        if self.profile.guided_jerk_max_m_s3 > 0.0:
            sp_n, sp_e = self._guided_velocity(sp_n, sp_e, est, dt)
        return (sp_n, sp_e, sp_d)

    def _land_setpoint(self, t: float, est: tuple[float, float, float]) -> tuple[float, float, float]:
        """LAND: descend at the land speed, on the precision-landing target while it is seen
        (horizontal approach first, as PX4's precision landing does)."""
        assert self._hold_target is not None
        sp_d = self.cfg.vehicle.land_speed_m_s
        pl = self._pl_target if self._precland and t - self._pl_seen_s <= PLD_BTOUT_S else None
        if pl is not None:
            self._hold_target = (pl[0], pl[1], self._hold_target[2])
            if math.hypot(pl[0] - est[0], pl[1] - est[1]) > PLD_HACC_RAD_M and self.landed is not LandedState.ON_GROUND:
                sp_d = 0.0
        sp_n, sp_e, _ = self._pos_ctrl(est, self._hold_target)
        return (sp_n, sp_e, sp_d)

    def _velocity_loop(self, sp: tuple[float, float, float], integrate: bool, dt: float) -> tuple[float, float, float]:
        """The velocity loop (P + I, conditional integration while ``integrate``) -> the
        acceleration setpoint (N, E, D), within the limits. It runs on the autopilot's velocity
        estimate (truth + the profile's error: PX4 SIH drifts on it; ArduCopter holds a position
        target, so its error does not drive the vehicle: profiles.py)."""
        vc = self.cfg.vehicle
        sp_n, sp_e, sp_d = sp
        ve_n, ve_e = self._velocity_estimate_h()
        ve_d = self.vd
        if self._verr and self.profile.velocity_loop_on_estimate:
            ve_n += self._verr[0].x
            ve_e += self._verr[1].x
            ve_d += self._verr[2].x
        if self.estimator_state is not None and self.profile.velocity_loop_on_estimate:
            bn, be = self._velocity_bias()
            ve_n += bn
            ve_e += be
        kp, ki = vc.velocity_p_gain, vc.velocity_i_gain
        kp_z = kp if vc.vertical_velocity_p_gain is None else vc.vertical_velocity_p_gain
        ki_z = ki if vc.vertical_velocity_i_gain is None else vc.vertical_velocity_i_gain
        en, ee, ed = sp_n - ve_n, sp_e - ve_e, sp_d - ve_d
        # GUIDED's desired acceleration, fed forward (updated this tick; None outside OFFBOARD), and
        # the setpoint's own (PX4 adds it to its velocity loop's output; ArduCopter's GUIDED takes it)
        ff = self._guided[2] if self._guided is not None else (0.0, 0.0)
        if self.mode is FlightMode.OFFBOARD and self._sp is not None and self._sp.accel_ne_m_s2 is not None:
            ff = (ff[0] + self._sp.accel_ne_m_s2[0], ff[1] + self._sp.accel_ne_m_s2[1])
        an = kp * en + ki * self._int[0] + ff[0]
        ae = kp * ee + ki * self._int[1] + ff[1]
        ad = kp_z * ed + ki_z * self._int[2]
        a_h_max = min(vc.max_horizontal_accel_m_s2, G * math.tan(math.radians(vc.max_tilt_deg)))
        ah = math.hypot(an, ae)
        sat_h = ah > a_h_max
        if sat_h:
            an, ae = an * a_h_max / ah, ae * a_h_max / ah
        sat_v = not (-vc.max_up_accel_m_s2 <= ad <= vc.max_down_accel_m_s2)
        ad = min(max(ad, -vc.max_up_accel_m_s2), vc.max_down_accel_m_s2)
        if integrate:
            if not sat_h:  # conditional integration (anti-windup)
                self._int[0] += en * dt
                self._int[1] += ee * dt
            if not sat_v:
                self._int[2] += ed * dt
        return (an, ae, ad)

    def _attitude_step(self, a_sp: tuple[float, float, float], dt: float) -> float:
        """Tilt the thrust towards f_sp = a_sp - g with first-order lag, turn the yaw towards its
        setpoint; returns the thrust's magnitude. The autopilot makes its attitude setpoint with its
        own yaw and drives its attitude *estimate* to it (PX4: the thrust vector and yaw setpoint
        become q_sp in the estimator's frame), so with an estimator state's offset the true tilt is
        the setpoint - the offset and the true thrust is f_sp turned by -yaw offset: the velocity
        loop's own response turns with the yaw error."""
        vc = self.cfg.vehicle
        fn, fe, fd = a_sp[0], a_sp[1], a_sp[2] - G
        T = math.sqrt(fn * fn + fe * fe + fd * fd)
        yaw_ctrl = self.estimated_yaw()
        cy, sy = math.cos(yaw_ctrl), math.sin(yaw_ctrl)
        fx = cy * fn + sy * fe
        fy = -sy * fn + cy * fe
        roll_d = math.asin(max(-1.0, min(1.0, fy / T))) - self._att_bias[0]
        pitch_d = math.atan2(-fx, -fd) - self._att_bias[1]
        k = min(1.0, dt / vc.attitude_time_constant_s)
        d_roll = (roll_d - self.roll) * k
        d_pitch = (pitch_d - self.pitch) * k
        self.roll += d_roll
        self.pitch += d_pitch
        # the yaw controller closes on the autopilot's yaw estimate (its heading setpoint is in the
        # estimator's frame: with a state's yaw offset the true heading is the setpoint - offset)
        dyaw = wrap_angle(self._yaw_sp - self.estimated_yaw()) if self.armed else 0.0
        dyaw = max(-YAW_RATE_MAX * dt, min(YAW_RATE_MAX * dt, dyaw))
        self.yaw = wrap_angle(self.yaw + dyaw)
        self._rates = (d_roll / dt, d_pitch / dt, dyaw / dt)
        return T

    def _move(self, T: float, thrust_on: bool, on_ground: bool, dt: float) -> None:
        """Translational dynamics: a = f(actual attitude) + g - drag(v - wind), on the ground the
        ground's reaction (hard ground, or PX4 SIH's soft one)."""
        vc = self.cfg.vehicle
        if thrust_on:
            cr, sr = math.cos(self.roll), math.sin(self.roll)
            cp, sp_ = math.cos(self.pitch), math.sin(self.pitch)
            cy, sy = math.cos(self.yaw), math.sin(self.yaw)
            f_n = -T * (cy * sp_ * cr + sy * sr)
            f_e = -T * (sy * sp_ * cr - cy * sr)
            f_d = -T * (cp * cr)
        else:
            f_n = f_e = f_d = 0.0
        kd = vc.drag_coefficient_1_s
        a_n = f_n - kd * (self.vn - self._wind[0])
        a_e = f_e - kd * (self.ve - self._wind[1])
        a_d = f_d + G - kd * (self.vd - self._wind[2])
        if vc.soft_ground:
            # PX4 SIH's fake ground (sih.cpp, Sih::equations_of_motion): below the take-off level
            # it cancels the forces and stops the vehicle only while their sum points down. A
            # steady descent (thrust = weight - drag) is not caught: it sinks on until the thrust
            # drops, and the vehicle rests where it was caught (see docs/simulation.md).
            caught = self.pd >= -1e-6 and a_d > 0.0
            if caught:
                self._rest(thrust_on)
                a_n = a_e = a_d = 0.0
            else:
                self._integrate(a_n, a_e, a_d, dt)
            self._grounded = caught
        elif on_ground and a_d >= 0.0:
            # resting on the ground: the ground carries the weight, friction stops sliding
            self._rest(thrust_on)
            self.pd = 0.0
            a_n = a_e = a_d = 0.0
        else:
            self._integrate(a_n, a_e, a_d, dt)
            if self.pd > 0.0:  # touching down this step
                self.pd = 0.0
                self.vd = 0.0
        self._accel = (a_n, a_e, a_d)

    def _rest(self, thrust_on: bool) -> None:
        """On the ground: it carries the weight, friction stops sliding."""
        self.vn = self.ve = self.vd = 0.0
        self._int = [0.0, 0.0, self._int[2] if thrust_on else 0.0]

    def _integrate(self, a_n: float, a_e: float, a_d: float, dt: float) -> None:
        self.vn += a_n * dt
        self.ve += a_e * dt
        self.vd += a_d * dt
        self.pn += self.vn * dt
        self.pe += self.ve * dt
        self.pd += self.vd * dt

    def _velocity_estimate_h(self) -> tuple[float, float]:
        """The horizontal velocity the autopilot's velocity loop closes on: truth + the rate at
        which its estimate takes the GPS error (gps_error_estimate_*), with a PX4 profile's
        velocity error where it flies on it (velocity_loop_on_estimate)."""
        vn, ve = self.vn, self.ve
        if self.profile.gps_error_estimate_tau_s > 0.0:
            k = self.profile.gps_error_velocity_share
            vn += k * self._gps_in_est_rate[0]
            ve += k * self._gps_in_est_rate[1]
        if self._verr and self.profile.velocity_loop_on_estimate:
            vn += self._verr[0].x
            ve += self._verr[1].x
        return vn, ve

    def _guided_velocity(
        self, sp_n: float, sp_e: float, est: tuple[float, float, float], dt: float
    ) -> tuple[float, float]:
        """ArduCopter GUIDED's answer to a velocity setpoint (profiles.guided_*): the velocity the
        velocity loop is asked for (the desired acceleration it feeds forward stays in _guided).

        AC_PosControl::input_vel_accel_xy advances the desired state (position target += v dt +
        a dt^2 / 2, v += a dt), then shapes the acceleration towards the setpoint
        (shape_vel_accel_xy: sqrt_controller on the velocity error with k = jerk / accel, the
        correction limited to accel, the change of acceleration to jerk dt);
        update_xy_controller asks for v + PSC_POSXY_P x (target - estimate)."""
        pr = self.profile
        if self._guided is None:  # init_xy_controller: the target from the estimate, at rest
            vn0, ve0 = self._velocity_estimate_h()
            self._guided = ([est[0], est[1]], [vn0, ve0], [0.0, 0.0])
        pos, vel, acc = self._guided
        for i in range(2):
            pos[i] += vel[i] * dt + 0.5 * acc[i] * dt * dt
            vel[i] += acc[i] * dt
        j_max, a_max = pr.guided_jerk_max_m_s3, pr.guided_accel_max_m_s2
        cn, ce = _sqrt_controller_2d(sp_n - vel[0], sp_e - vel[1], j_max / a_max, j_max, dt)
        c = math.hypot(cn, ce)
        if c > a_max:
            cn, ce = cn * a_max / c, ce * a_max / c
        dn, de = cn - acc[0], ce - acc[1]  # shape_accel_xy: the jerk limit
        d = math.hypot(dn, de)
        if d > j_max * dt:
            dn, de = dn * j_max * dt / d, de * j_max * dt / d
        acc[0] += dn
        acc[1] += de
        kp = pr.guided_position_p_1_s
        return vel[0] + kp * (pos[0] - est[0]), vel[1] + kp * (pos[1] - est[1])

    def _pos_ctrl(
        self, est: tuple[float, float, float], target: tuple[float, float, float]
    ) -> tuple[float, float, float]:
        kp = self.cfg.vehicle.position_p_gain
        vn = kp * (target[0] - est[0])
        ve = kp * (target[1] - est[1])
        vd = kp * (target[2] - est[2])
        h = math.hypot(vn, ve)
        if h > HOLD_MAX_H_SPEED:
            vn, ve = vn * HOLD_MAX_H_SPEED / h, ve * HOLD_MAX_H_SPEED / h
        vd = max(-HOLD_MAX_V_SPEED, min(HOLD_MAX_V_SPEED, vd))
        return vn, ve, vd

    def _land_detector(self, t: float) -> None:
        on_ground = self.pd >= -0.01 and abs(self.vd) < 0.05
        if on_ground:
            if self._ground_since is None:
                self._ground_since = t
            if t - self._ground_since >= self._land_detect_s and self.landed is not LandedState.ON_GROUND:
                self.landed = LandedState.ON_GROUND
                self._landed_since = t
                if self._airborne:
                    self._airborne = False
                    self.touchdowns.append(Touchdown(t, self.pn, self.pe, self.payload_released, self.yaw))
                    self._text(f"landed at N {self.pn:.2f} E {self.pe:.2f}")
            if (
                self.armed
                and self.mode is FlightMode.LAND
                and self.landed is LandedState.ON_GROUND
                and self._landed_since is not None
                and t - self._landed_since >= AUTO_DISARM_AFTER_LAND_S
            ):
                self.armed = False
                self._text("auto-disarmed after landing")
        else:
            self._ground_since = None
            self._landed_since = None
            if self.pd < -0.3:
                self._airborne = True
                self.landed = LandedState.IN_AIR

    def _set_home(self) -> None:
        # The home the autopilot reports is its GPS position at arming: the bias lives in it.
        est = self._estimate()
        b = self._bias
        self._home_reported = self._ltp.to_geo(est[0] + b[0], est[1] + b[1], est[2] + b[2])
        self._home_offset = est  # local origin at home (estimate at arming)

    def _text(self, msg: str) -> None:
        log.debug("sim vehicle t=%.2f: %s", self.time_s, msg)
        self.status_texts.append((self.time_s, msg))

    # ------------------------------------------------------------------ telemetry
    def _local(self) -> tuple[float, float, float]:
        est = self._estimate()
        off = getattr(self, "_home_offset", (0.0, 0.0, 0.0))
        return (est[0] - off[0], est[1] - off[1], est[2] - off[2])

    def position_ned(self) -> PositionNed:
        n, e, d = self._local()
        r = [x * 0.03 for x in self._rng_misc.standard_normal(3).tolist()]
        vn, ve, vd = self.vn, self.ve, self.vd
        if self._verr:  # the reported velocity is the estimate the velocity loop flies on
            vn += self._verr[0].x
            ve += self._verr[1].x
            vd += self._verr[2].x
        if self.estimator_state is not None:
            bn, be = self._velocity_bias()
            vn += bn
            ve += be
        return PositionNed(self.time_s, n, e, d, vn + r[0], ve + r[1], vd + r[2])

    def global_position(self) -> GlobalPosition:
        est = self._estimate()
        b = self._bias
        g = self._ltp.to_geo(est[0] + b[0], est[1] + b[1], est[2] + b[2])
        home_alt = self._home_reported.alt_amsl_m if self._home_reported else self._home_true.alt_amsl_m
        return GlobalPosition(self.time_s, g.lat_deg, g.lon_deg, g.alt_amsl_m, g.alt_amsl_m - home_alt)

    def gps_raw(self) -> GpsRaw:
        est = self._estimate()
        b = self._bias
        r = [x * self.cfg.gps_noise_m for x in self._rng_gps.standard_normal(3).tolist()]
        g = self._ltp.to_geo(est[0] + b[0] + r[0], est[1] + b[1] + r[1], est[2] + b[2] + r[2])
        return GpsRaw(self.time_s, g.lat_deg, g.lon_deg, g.alt_amsl_m, 3 if self.healthy else 1, 14, 0.8)

    def estimated_yaw(self) -> float:
        """The autopilot's yaw estimate: the true yaw plus its estimator state's offset (the truth
        itself without a state)."""
        if self.estimator_state is None:
            return self.yaw
        return wrap_angle(self.yaw + self._att_bias[2])

    def attitude(self) -> Attitude:
        p, q, r = self._rates
        if self.estimator_state is None:
            return Attitude(self.time_s, self.roll, self.pitch, self.yaw, p, q, r)
        b = self._att_bias  # what the estimator reports is off the truth by its state's offset
        return Attitude(self.time_s, self.roll + b[0], self.pitch + b[1], wrap_angle(self.yaw + b[2]), p, q, r)

    def imu(self) -> Imu:
        """Specific force and body rates in FRD, with white noise."""
        a_n, a_e, a_d = self._accel
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
        return self._wind[0], self._wind[1]

    def set_wind(self, speed_m_s: float, from_deg: float) -> None:
        """Change the mean wind (a test's weather change); the gusts go on around it."""
        wf = math.radians(from_deg)
        self._wind_mean = (-speed_m_s * math.cos(wf), -speed_m_s * math.sin(wf), 0.0)

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

"""The simulated autopilot's commander: arming, the flight modes and their rules, the offboard-loss
failsafe, and each mode's velocity setpoint, on the autopilot's own position estimate.

* HOLD / POSITION (and the modes without a setpoint of their own in the sim): a P position loop
  on a held target, ``HOLD_MAX_H_SPEED`` / ``HOLD_MAX_V_SPEED`` at most;
* TAKEOFF: climb at the take-off speed to the altitude, then HOLD;
* OFFBOARD (PX4) / GUIDED (ArduCopter): only with a setpoint stream of more than
  ``OFFBOARD_MIN_SETPOINT_RATE_HZ`` before the switch; the setpoint cut to the autopilot's limits,
  shaped as GUIDED does where the profile says so (``guided_*``); a stream older than
  ``offboard_loss_timeout_s`` is the failsafe (the vehicle's ``offboard_loss_mode``);
* LAND, and precision landing on LANDING_TARGET (PX4 AUTO.PRECLAND: the horizontal approach within
  ``PLD_HACC_RAD_M`` first; with no target for ``PLD_BTOUT_S`` a plain landing).

:class:`FlightModes` is the part of :class:`~companion_sitl.vehicle.SimVehicle` that holds the
commander's state; the vehicle keeps ``armed`` and ``mode`` (its status) and answers the commands
through it.
"""

from __future__ import annotations

import math
from typing import Protocol

from companion.autopilot.types import FlightMode, LandedState
from companion.guidance.setpoint import VelocitySetpoint
from companion_sitl.params import SimConfig
from companion_sitl.profiles import AutopilotProfile
from companion_sitl.velocity_control import VelocityController

HOLD_MAX_H_SPEED = 5.0
HOLD_MAX_V_SPEED = 1.5
OFFBOARD_MIN_SETPOINT_RATE_HZ = 2.0
PLD_HACC_RAD_M = 0.2  # PX4 precision landing: horizontal acceptance radius before descending
PLD_BTOUT_S = 5.0  # PX4 precision landing: target lost after this long -> plain landing

# the modes that hold a position target (no setpoint of their own in the sim)
POSITION_HOLD_MODES = (
    FlightMode.HOLD,
    FlightMode.POSITION,
    FlightMode.MANUAL,
    FlightMode.RTL,
    FlightMode.MISSION,
    FlightMode.UNKNOWN,
)

Vec3 = tuple[float, float, float]


class Vehicle(Protocol):
    """What the commander reads and sets of the vehicle (SimVehicle; a Protocol: no import cycle)."""

    cfg: SimConfig
    profile: AutopilotProfile
    time_s: float
    armed: bool
    mode: FlightMode
    landed: LandedState
    battery_pct: float
    offboard_loss_mode: FlightMode
    landing_targets_received: int
    control: VelocityController
    _armed_s: float
    _home_offset: Vec3

    @property
    def healthy(self) -> bool: ...

    def hold(self) -> None: ...

    def estimated_yaw(self) -> float: ...

    def _estimate(self) -> Vec3: ...

    def _velocity_estimate_h(self) -> tuple[float, float]: ...

    def _text(self, msg: str) -> None: ...


class SimCommandError(RuntimeError):
    """The simulated autopilot refused a command (as PX4 would, with its reason)."""


def sqrt_controller_2d(en: float, ee: float, p: float, second_ord_lim: float, dt: float) -> tuple[float, float]:
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


def position_control(kp: float, est: Vec3, target: Vec3) -> Vec3:
    """The position loop: P on the estimate's error to ``target``, within the hold speeds."""
    vn = kp * (target[0] - est[0])
    ve = kp * (target[1] - est[1])
    vd = kp * (target[2] - est[2])
    h = math.hypot(vn, ve)
    if h > HOLD_MAX_H_SPEED:
        vn, ve = vn * HOLD_MAX_H_SPEED / h, ve * HOLD_MAX_H_SPEED / h
    vd = max(-HOLD_MAX_V_SPEED, min(HOLD_MAX_V_SPEED, vd))
    return vn, ve, vd


class FlightModes:
    """The commander's state: ``hold_target`` (the position held, estimate frame), the take-off's
    target, ``yaw_sp``, the offboard setpoint ``sp`` and its arrival times ``sp_times``, the
    precision landing's target, and ``guided``: GUIDED's shaped setpoint (profiles.guided_*: the
    position target, desired velocity and acceleration, N, E; None outside OFFBOARD, set from the
    estimate on entering it)."""

    def __init__(self, vehicle: Vehicle) -> None:
        self.v = vehicle
        self.hold_target: Vec3 | None = None
        self.takeoff_target_d = 0.0
        self.yaw_sp = 0.0
        self.sp: VelocitySetpoint | None = None
        self.precland = False
        self.pl_target: tuple[float, float] | None = None
        self.pl_seen_s = -math.inf
        self.sp_times: list[float] = []
        self.guided: tuple[list[float], list[float], list[float]] | None = None

    # ------------------------------------------------------------------ commands
    def arm(self) -> None:
        v = self.v
        if v.armed:
            return
        if not v.healthy:
            raise SimCommandError("arming denied: estimator/GPS not ready")
        if v.landed is not LandedState.ON_GROUND:
            raise SimCommandError("arming denied: not landed")
        if v.battery_pct < 10.0:
            raise SimCommandError(f"arming denied: battery {v.battery_pct:.0f} %")
        v.armed = True
        v._armed_s = v.time_s  # the height estimate's drift counts from here (height_estimate_drift_m_s)
        v.mode = FlightMode.HOLD
        v.control.reset()
        self.yaw_sp = v.estimated_yaw()
        self.hold_target = None
        v._text("armed")

    def disarm(self) -> None:
        v = self.v
        if not v.armed:
            return
        if v.landed is not LandedState.ON_GROUND:
            raise SimCommandError("disarming denied: not landed")
        v.armed = False
        v._text("disarmed")

    def takeoff(self, alt_rel_m: float) -> None:
        v = self.v
        if not v.armed:
            raise SimCommandError("takeoff denied: not armed")
        if not (math.isfinite(alt_rel_m) and 0.5 <= alt_rel_m <= 100.0):
            raise SimCommandError(f"takeoff denied: altitude {alt_rel_m} m out of range")
        est = v._estimate()
        self.takeoff_target_d = est[2] - alt_rel_m
        self.hold_target = (est[0], est[1], self.takeoff_target_d)
        v.mode = FlightMode.TAKEOFF
        self.yaw_sp = v.estimated_yaw()

    def set_velocity(self, sp: VelocitySetpoint) -> None:
        v = self.v
        vals = (sp.north_m_s, sp.east_m_s, sp.down_m_s, sp.yaw_rad, *(sp.accel_ne_m_s2 or ()))
        if not all(math.isfinite(x) for x in vals):
            v._text(f"offboard setpoint rejected: not finite {vals}")
            return
        self.sp = sp
        self.note_setpoint(v.time_s)

    def note_setpoint(self, t: float) -> None:
        """A setpoint of the offboard stream arrived at ``t`` (the last 50 are kept)."""
        self.sp_times.append(t)
        if len(self.sp_times) > 50:
            del self.sp_times[:-50]

    def setpoint_fresh(self) -> bool:
        v = self.v
        return bool(self.sp_times) and v.time_s - self.sp_times[-1] <= v.cfg.vehicle.offboard_loss_timeout_s

    def start_offboard(self) -> None:
        v = self.v
        if not v.armed:
            raise SimCommandError("offboard denied: not armed")
        recent = [t for t in self.sp_times if v.time_s - t <= 1.0]
        if len(recent) < OFFBOARD_MIN_SETPOINT_RATE_HZ + 1 or v.time_s - recent[-1] > 0.5:
            raise SimCommandError("offboard denied: no setpoints streamed (need > 2 Hz before switching)")
        v.mode = FlightMode.OFFBOARD

    def hold(self) -> None:
        self.hold_target = self.v._estimate()
        self.v.mode = FlightMode.HOLD

    def land(self) -> None:
        v = self.v
        if not v.armed:
            raise SimCommandError("land denied: not armed")
        self.hold_target = v._estimate()
        self.precland = False
        v.mode = FlightMode.LAND

    def set_landing_target(self, north_m: float, east_m: float) -> None:
        v = self.v
        if not (math.isfinite(north_m) and math.isfinite(east_m)):
            v._text(f"landing target rejected: not finite {(north_m, east_m)}")
            return
        off = v._home_offset
        self.pl_target = (north_m + off[0], east_m + off[1])  # into the estimate frame the controller uses
        self.pl_seen_s = v.time_s
        v.landing_targets_received += 1

    def pilot_set_mode(self, mode: FlightMode) -> None:
        v = self.v
        if mode in (FlightMode.POSITION, FlightMode.HOLD, FlightMode.LAND):
            self.hold_target = v._estimate()
        v.mode = mode
        v._text(f"pilot switched to {mode.value}")

    # ------------------------------------------------------------------ setpoints
    def setpoint(self, t: float, dt: float) -> Vec3:
        """The mode logic (autopilot side, on its estimate): the velocity setpoint (N, E, D).
        A mode that hands over (OFFBOARD's failsafe, TAKEOFF done) lets the next one set it in
        the same tick."""
        v = self.v
        est = v._estimate()
        sp = (0.0, 0.0, 0.0)
        if v.armed:
            if v.mode is FlightMode.OFFBOARD:
                sp = self._offboard_setpoint(t, dt, est)
            if v.mode is FlightMode.TAKEOFF:
                assert self.hold_target is not None
                sp_n, sp_e, _ = position_control(v.cfg.vehicle.position_p_gain, est, self.hold_target)
                sp = (sp_n, sp_e, -v.cfg.vehicle.takeoff_speed_m_s)
                # done within the altitude acceptance radius: HOLD then climbs on to the height
                if est[2] <= self.takeoff_target_d + v.cfg.vehicle.takeoff_altitude_acceptance_m:
                    v.mode = FlightMode.HOLD
            if v.mode in POSITION_HOLD_MODES:
                if self.hold_target is None:
                    self.hold_target = est
                sp = position_control(v.cfg.vehicle.position_p_gain, est, self.hold_target)
            if v.mode is FlightMode.LAND:
                sp = self._land_setpoint(t, est)
        if not v.armed or v.mode is not FlightMode.OFFBOARD:
            self.guided = None
        return sp

    def feed_forward(self) -> tuple[float, float]:
        """The velocity loop's acceleration feed-forward (N, E): GUIDED's desired acceleration
        (updated this tick; None outside OFFBOARD), and the setpoint's own (PX4 adds it to its
        velocity loop's output; ArduCopter's GUIDED takes it)."""
        ff = self.guided[2] if self.guided is not None else (0.0, 0.0)
        if self.v.mode is FlightMode.OFFBOARD and self.sp is not None and self.sp.accel_ne_m_s2 is not None:
            ff = (ff[0] + self.sp.accel_ne_m_s2[0], ff[1] + self.sp.accel_ne_m_s2[1])
        return (ff[0], ff[1])

    def _offboard_setpoint(self, t: float, dt: float, est: Vec3) -> Vec3:
        """OFFBOARD: the companion's setpoint, cut to the autopilot's limits; a setpoint stream
        that stopped is the failsafe (its mode then holds position)."""
        v = self.v
        vc = v.cfg.vehicle
        if self.sp is None or t - self.sp_times[-1] > vc.offboard_loss_timeout_s:
            v._text(f"offboard lost: failsafe {v.offboard_loss_mode.value}")
            v.hold()
            v.mode = v.offboard_loss_mode  # holds position in either
            return (0.0, 0.0, 0.0)
        sp_n, sp_e, sp_d = self.sp.north_m_s, self.sp.east_m_s, self.sp.down_m_s
        self.yaw_sp = self.sp.yaw_rad
        # the autopilot cuts each axis on its own (PX4's position control: horizontal
        # norm to MPC_XY_VEL_MAX, down / up to MPC_Z_VEL_MAX_DN / _UP)
        h = math.hypot(sp_n, sp_e)
        if h > vc.offboard_max_horizontal_m_s:
            k_h = vc.offboard_max_horizontal_m_s / h
            sp_n, sp_e = sp_n * k_h, sp_e * k_h
        sp_d = min(max(sp_d, -vc.offboard_max_up_m_s), vc.offboard_max_down_m_s)
        if v.profile.guided_jerk_max_m_s3 > 0.0:
            sp_n, sp_e = self._guided_velocity(sp_n, sp_e, est, dt)
        return (sp_n, sp_e, sp_d)

    def _guided_velocity(self, sp_n: float, sp_e: float, est: Vec3, dt: float) -> tuple[float, float]:
        """ArduCopter GUIDED's answer to a velocity setpoint (profiles.guided_*): the velocity the
        velocity loop is asked for (the desired acceleration it feeds forward stays in ``guided``).

        AC_PosControl::input_vel_accel_xy advances the desired state (position target += v dt +
        a dt^2 / 2, v += a dt), then shapes the acceleration towards the setpoint
        (shape_vel_accel_xy: sqrt_controller on the velocity error with k = jerk / accel, the
        correction limited to accel, the change of acceleration to jerk dt);
        update_xy_controller asks for v + PSC_POSXY_P x (target - estimate)."""
        pr = self.v.profile
        if self.guided is None:  # init_xy_controller: the target from the estimate, at rest
            vn0, ve0 = self.v._velocity_estimate_h()
            self.guided = ([est[0], est[1]], [vn0, ve0], [0.0, 0.0])
        pos, vel, acc = self.guided
        for i in range(2):
            pos[i] += vel[i] * dt + 0.5 * acc[i] * dt * dt
            vel[i] += acc[i] * dt
        j_max, a_max = pr.guided_jerk_max_m_s3, pr.guided_accel_max_m_s2
        cn, ce = sqrt_controller_2d(sp_n - vel[0], sp_e - vel[1], j_max / a_max, j_max, dt)
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

    def _land_setpoint(self, t: float, est: Vec3) -> Vec3:
        """LAND: descend at the land speed, on the precision-landing target while it is seen
        (horizontal approach first, as PX4's precision landing does)."""
        v = self.v
        assert self.hold_target is not None
        sp_d = v.cfg.vehicle.land_speed_m_s
        pl = self.pl_target if self.precland and t - self.pl_seen_s <= PLD_BTOUT_S else None
        if pl is not None:
            self.hold_target = (pl[0], pl[1], self.hold_target[2])
            if math.hypot(pl[0] - est[0], pl[1] - est[1]) > PLD_HACC_RAD_M and v.landed is not LandedState.ON_GROUND:
                sp_d = 0.0
        sp_n, sp_e, _ = position_control(v.cfg.vehicle.position_p_gain, est, self.hold_target)
        return (sp_n, sp_e, sp_d)

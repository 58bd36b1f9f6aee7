"""The autopilot's inner loops as the simulated vehicle flies them (PX4's MulticopterPositionControl
velocity stage and attitude control, ArduCopter's AC_PosControl / AC_AttitudeControl in outline):

* :class:`VelocityController`: the velocity loop, P + I with conditional integration (anti-windup),
  the feed-forward acceleration, and the acceleration and tilt limits of ``[sim.vehicle]``;
* :func:`attitude_step`: the thrust tilted towards the acceleration setpoint with a first-order
  lag, the yaw turned towards its setpoint at most ``YAW_RATE_MAX``, both closed on the autopilot's
  attitude *estimate* (an estimator state's offset shows in the true attitude).
"""

from __future__ import annotations

import math

from companion.geometry.rotations import wrap_angle
from companion_sitl.params import VehicleSimConfig

G = 9.80665
YAW_RATE_MAX = math.radians(60.0)

Vec3 = tuple[float, float, float]


class VelocityController:
    """The velocity loop's state: its integrator ``integ`` (N, E, D)."""

    def __init__(self) -> None:
        self.integ = [0.0, 0.0, 0.0]

    def reset(self) -> None:
        self.integ = [0.0, 0.0, 0.0]

    def acceleration(
        self, vc: VehicleSimConfig, sp: Vec3, ve: Vec3, ff: tuple[float, float], integrate: bool, dt: float
    ) -> Vec3:
        """The velocity loop (P + I, conditional integration while ``integrate``) on the velocity
        estimate ``ve``, with the horizontal feed-forward ``ff`` -> the acceleration setpoint
        (N, E, D), within the limits."""
        sp_n, sp_e, sp_d = sp
        ve_n, ve_e, ve_d = ve
        kp, ki = vc.velocity_p_gain, vc.velocity_i_gain
        kp_z = kp if vc.vertical_velocity_p_gain is None else vc.vertical_velocity_p_gain
        ki_z = ki if vc.vertical_velocity_i_gain is None else vc.vertical_velocity_i_gain
        en, ee, ed = sp_n - ve_n, sp_e - ve_e, sp_d - ve_d
        an = kp * en + ki * self.integ[0] + ff[0]
        ae = kp * ee + ki * self.integ[1] + ff[1]
        ad = kp_z * ed + ki_z * self.integ[2]
        a_h_max = min(vc.max_horizontal_accel_m_s2, G * math.tan(math.radians(vc.max_tilt_deg)))
        ah = math.hypot(an, ae)
        sat_h = ah > a_h_max
        if sat_h:
            an, ae = an * a_h_max / ah, ae * a_h_max / ah
        sat_v = not (-vc.max_up_accel_m_s2 <= ad <= vc.max_down_accel_m_s2)
        ad = min(max(ad, -vc.max_up_accel_m_s2), vc.max_down_accel_m_s2)
        if integrate:
            if not sat_h:  # conditional integration (anti-windup)
                self.integ[0] += en * dt
                self.integ[1] += ee * dt
            if not sat_v:
                self.integ[2] += ed * dt
        return (an, ae, ad)


def attitude_step(
    vc: VehicleSimConfig,
    attitude: Vec3,
    a_sp: Vec3,
    yaw_estimate: float,
    att_bias: Vec3,
    yaw_sp: float | None,
    dt: float,
) -> tuple[Vec3, Vec3, float]:
    """Tilt the thrust towards f_sp = a_sp - g with first-order lag, turn the yaw towards its
    setpoint (``yaw_sp``; None: disarmed, no turn) from the true ``attitude`` (roll, pitch, yaw);
    returns the new attitude, the body rates and the thrust's magnitude. The autopilot makes its
    attitude setpoint with its own yaw (``yaw_estimate``) and drives its attitude *estimate* to it
    (PX4: the thrust vector and yaw setpoint become q_sp in the estimator's frame), so with an
    estimator state's offset (``att_bias``) the true tilt is the setpoint - the offset and the true
    thrust is f_sp turned by -yaw offset: the velocity loop's own response turns with the yaw error."""
    roll, pitch, yaw = attitude
    fn, fe, fd = a_sp[0], a_sp[1], a_sp[2] - G
    T = math.sqrt(fn * fn + fe * fe + fd * fd)
    cy, sy = math.cos(yaw_estimate), math.sin(yaw_estimate)
    fx = cy * fn + sy * fe
    fy = -sy * fn + cy * fe
    roll_d = math.asin(max(-1.0, min(1.0, fy / T))) - att_bias[0]
    pitch_d = math.atan2(-fx, -fd) - att_bias[1]
    k = min(1.0, dt / vc.attitude_time_constant_s)
    d_roll = (roll_d - roll) * k
    d_pitch = (pitch_d - pitch) * k
    roll += d_roll
    pitch += d_pitch
    # the yaw controller closes on the autopilot's yaw estimate (its heading setpoint is in the
    # estimator's frame: with a state's yaw offset the true heading is the setpoint - offset)
    dyaw = wrap_angle(yaw_sp - yaw_estimate) if yaw_sp is not None else 0.0
    dyaw = max(-YAW_RATE_MAX * dt, min(YAW_RATE_MAX * dt, dyaw))
    yaw = wrap_angle(yaw + dyaw)
    return (roll, pitch, yaw), (d_roll / dt, d_pitch / dt, dyaw / dt), T

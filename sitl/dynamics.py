"""The simulated vehicle's translational dynamics: the thrust along the body's -z of the true
attitude, gravity, linear drag against the air (the wind at the vehicle), and the ground: a hard
one (down = 0 carries the weight, friction stops sliding) or PX4 SIH's soft one (``soft_ground``:
the forces cancelled below the take-off level only while their sum points down).

:class:`TranslationalDynamics` is the part of :class:`~companion_sitl.vehicle.SimVehicle` that
moves its truth (``pn`` ... ``vd``) each physics step; it keeps the acceleration of the step (the
IMU's specific force) and whether the vehicle rests on the ground.
"""

from __future__ import annotations

import math
from typing import Protocol

from companion_sitl.params import SimConfig
from companion_sitl.velocity_control import G, VelocityController
from companion_sitl.wind import SimWind


class Body(Protocol):
    """What the dynamics move and read of the vehicle (SimVehicle; a Protocol: no import cycle)."""

    cfg: SimConfig
    pn: float
    pe: float
    pd: float
    vn: float
    ve: float
    vd: float
    roll: float
    pitch: float
    yaw: float
    wind_model: SimWind
    control: VelocityController


class TranslationalDynamics:
    """``accel``: the last step's acceleration (N, E, D; m/s^2); ``grounded``: resting on the
    ground (soft_ground: where it was caught)."""

    def __init__(self) -> None:
        self.accel = (0.0, 0.0, 0.0)
        self.grounded = True

    def step(self, v: Body, T: float, thrust_on: bool, on_ground: bool, dt: float) -> None:
        """Translational dynamics: a = f(actual attitude) + g - drag(v - wind), on the ground the
        ground's reaction (hard ground, or PX4 SIH's soft one); thrust ``T`` (per mass)."""
        vc = v.cfg.vehicle
        if thrust_on:
            cr, sr = math.cos(v.roll), math.sin(v.roll)
            cp, sp_ = math.cos(v.pitch), math.sin(v.pitch)
            cy, sy = math.cos(v.yaw), math.sin(v.yaw)
            f_n = -T * (cy * sp_ * cr + sy * sr)
            f_e = -T * (sy * sp_ * cr - cy * sr)
            f_d = -T * (cp * cr)
        else:
            f_n = f_e = f_d = 0.0
        kd = vc.drag_coefficient_1_s
        wind = v.wind_model.now
        a_n = f_n - kd * (v.vn - wind[0])
        a_e = f_e - kd * (v.ve - wind[1])
        a_d = f_d + G - kd * (v.vd - wind[2])
        if vc.soft_ground:
            # PX4 SIH's fake ground (sih.cpp, Sih::equations_of_motion): below the take-off level
            # it cancels the forces and stops the vehicle only while their sum points down. A
            # steady descent (thrust = weight - drag) is not caught: it sinks on until the thrust
            # drops, and the vehicle rests where it was caught (see docs/simulation.md).
            caught = v.pd >= -1e-6 and a_d > 0.0
            if caught:
                self._rest(v, thrust_on)
                a_n = a_e = a_d = 0.0
            else:
                self._integrate(v, a_n, a_e, a_d, dt)
            self.grounded = caught
        elif on_ground and a_d >= 0.0:
            # resting on the ground: the ground carries the weight, friction stops sliding
            self._rest(v, thrust_on)
            v.pd = 0.0
            a_n = a_e = a_d = 0.0
        else:
            self._integrate(v, a_n, a_e, a_d, dt)
            if v.pd > 0.0:  # touching down this step
                v.pd = 0.0
                v.vd = 0.0
        self.accel = (a_n, a_e, a_d)

    @staticmethod
    def _rest(v: Body, thrust_on: bool) -> None:
        """On the ground: it carries the weight, friction stops sliding (the velocity loop's
        horizontal integrator reset, the vertical one too without thrust)."""
        v.vn = v.ve = v.vd = 0.0
        c = v.control
        c.integ = [0.0, 0.0, c.integ[2] if thrust_on else 0.0]

    @staticmethod
    def _integrate(v: Body, a_n: float, a_e: float, a_d: float, dt: float) -> None:
        v.vn += a_n * dt
        v.ve += a_e * dt
        v.vd += a_d * dt
        v.pn += v.vn * dt
        v.pe += v.ve * dt
        v.pd += v.vd * dt

"""PID with a filtered derivative, and the Dart controller: four decoupled PIDs (dart 3.2.2).

:class:`Pid`
    u = P + I + D, clamped to [out_min, out_max].
    P = kp e, e = setpoint - measurement (wrapped to [-pi, pi) for angles).
    D = kd * lowpass(-d measurement / dt): derivative on the measurement, so a setpoint step
    does not kick; a first-order low-pass with time constant ``d_filter_tau_s``. The first
    sample after a reset has no derivative (nothing to difference).
    I accumulates ki e dt (stored in output units, limited to [i_min, i_max]) with conditional
    integration: while the output is saturated, the error that would push it further into
    saturation is not integrated (anti-windup).

:class:`DartController`
    C_x, C_y, C_z and C_psi (dart Fig. 6) map the position errors Q_bar - Q and the yaw error
    psi_bar - psi to roll, pitch, thrust and yaw-rate contributions, already in RC microseconds
    (offsets from the stick neutral, dart sec. 4: "the attitude set-points are first converted
    into time intervals"). The integrators run only while the autonomous mode is engaged and
    are reset on every engagement and disengagement (dart sec. 4: "the integral component ...
    is activated only ... whenever the autonomous flight mode is enabled ... to avoid
    discontinuities caused by the wind-up effect").

Sign convention of the contributions (FRD body): +roll = right side down, +pitch = nose up,
+thrust = up, +yaw rate = nose right. The RC mixer maps them onto channels and reversals.
``axis_channels`` says which command each of C_x, C_y, C_z drives and ``axis_signs`` its sign;
the defaults fit the paper's set-up (wall marker ahead, marker x to the right, y up, z towards
the drone): an error +x (target to the right) rolls right, +y climbs, +z (target further from
the wall) pitches nose up to back away.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass
from typing import Any, Literal, Protocol

from pydantic import Field, model_validator

from companion.config import _f, _Section
from companion.geometry import wrap_angle
from companion.param_kinds import _s

logger = logging.getLogger(__name__)

Command = Literal["roll", "pitch", "throttle"]


def _limit(default: float, description: str) -> Any:
    """An output or integrator limit, output units; +-inf (TOML inf) for none."""
    return _s(default, "out", description, allow_inf_nan=True)


class PidGains(_Section):
    """One PID loop's gains, in output units per error unit (here RC microseconds per metre or
    radian). A Dart file gives them as ``[control]`` (companion.param_kinds.DartControlTable:
    one horizontal set for C_x and C_z, one vertical for C_y, yaw proportional), turned into the
    four loops by companion.dart.params.controller_config."""

    kp: float = _s(..., "out/err", "proportional gain", ge=0.0)
    ki: float = _s(0.0, "out/(err s)", "integral gain", ge=0.0)
    kd: float = _s(0.0, "out s/err", "derivative gain (on the measurement)", ge=0.0)
    d_filter_tau_s: float = _s(0.1, "s", "derivative low-pass time constant (0: unfiltered)", ge=0.0)
    out_min: float = _limit(-math.inf, "output lower limit (< out_max)")
    out_max: float = _limit(math.inf, "output upper limit")
    i_min: float = _limit(-math.inf, "integral term lower limit (<= i_max)")
    i_max: float = _limit(math.inf, "integral term upper limit")
    wrap_error: bool = _s(False, "-", "angles: wrap the error and the measurement differences")
    max_dt_s: float = _s(0.5, "s", "a longer gap: the derivative restarts, integration uses max_dt_s", gt=0.0)

    @model_validator(mode="after")
    def _limits(self) -> PidGains:
        lims = (self.out_min, self.out_max, self.i_min, self.i_max)
        if any(math.isnan(v) for v in lims):
            raise ValueError(f"out_min, out_max, i_min, i_max = {lims}: NaN is not a limit")
        if not self.out_min < self.out_max:
            raise ValueError(f"need out_min < out_max, got {self.out_min}, {self.out_max}")
        if not self.i_min <= self.i_max:
            raise ValueError(f"need i_min <= i_max, got {self.i_min}, {self.i_max}")
        return self


class Pid:
    """One PID loop. Pure and synchronous: time is an argument."""

    def __init__(self, gains: PidGains) -> None:
        self.gains = gains
        self.rejected = 0
        self.reset()

    def reset(self, integral: float = 0.0) -> None:
        """Integral to ``integral`` (zero unless a caller starts the loop from a known one),
        derivative state cleared, output zero."""
        self._integral = integral
        self._d_filtered = 0.0
        self._prev_meas: float | None = None
        self._prev_t: float | None = None
        self._output = 0.0
        self._saturated = False

    @property
    def integral(self) -> float:
        return self._integral

    @property
    def output(self) -> float:
        return self._output

    @property
    def saturated(self) -> bool:
        return self._saturated

    def update(self, time_s: float, setpoint: float, measurement: float, *, integrate: bool = True) -> float:
        """One control step at ``time_s``. Non-finite inputs or a time that does not advance
        are rejected (counted): the previous output is returned and nothing changes."""
        g = self.gains
        if not (math.isfinite(time_s) and math.isfinite(setpoint) and math.isfinite(measurement)):
            self.rejected += 1
            return self._output
        if self._prev_t is not None and not time_s > self._prev_t:
            self.rejected += 1
            return self._output
        err = setpoint - measurement
        if g.wrap_error:
            err = wrap_angle(err)
        dt = 0.0 if self._prev_t is None else time_s - self._prev_t
        restart = self._prev_meas is None or dt > g.max_dt_s
        if restart:
            self._d_filtered = 0.0
        else:
            dm = measurement - self._prev_meas  # type: ignore[operator]
            if g.wrap_error:
                dm = wrap_angle(dm)
            raw = -dm / dt
            alpha = dt / (g.d_filter_tau_s + dt)
            self._d_filtered += alpha * (raw - self._d_filtered)
        dt_i = min(dt, g.max_dt_s)
        p_term = g.kp * err
        d_term = g.kd * self._d_filtered
        integral = self._integral
        if integrate and g.ki > 0.0 and dt_i > 0.0:
            candidate = min(g.i_max, max(g.i_min, integral + g.ki * err * dt_i))
            u_try = p_term + candidate + d_term
            # conditional integration: do not integrate further into saturation
            pushes_up = candidate > integral
            pushes_down = candidate < integral
            if not ((u_try > g.out_max and pushes_up) or (u_try < g.out_min and pushes_down)):
                integral = candidate
        self._integral = integral
        u = p_term + integral + d_term
        self._saturated = u > g.out_max or u < g.out_min
        u = min(g.out_max, max(g.out_min, u))
        self._output = u
        self._prev_meas = measurement
        self._prev_t = time_s
        return u


# ------------------------------------------------------------------------------ Dart control
class PoseLike(Protocol):
    """What the controller reads from a position estimate (dart_estimators.DartPositionEstimate
    satisfies it): marker-frame position in metres and the yaw relative to the reference."""

    @property
    def time_s(self) -> float: ...
    @property
    def x_m(self) -> float: ...
    @property
    def y_m(self) -> float: ...
    @property
    def z_m(self) -> float: ...
    @property
    def yaw_rad(self) -> float: ...


@dataclass(frozen=True, slots=True)
class DartSetpoint:
    """Desired position Q_bar (marker frame, metres) and yaw psi_bar (dart 3.2.2)."""

    x_m: float
    y_m: float
    z_m: float
    yaw_rad: float = 0.0


@dataclass(frozen=True, slots=True)
class DartCommand:
    """The cyber-pilot's contribution in RC microseconds, offsets from the stick neutral.

    ``valid`` is False when no usable estimate was available (the contribution is then zero).
    """

    time_s: float
    roll_us: float
    pitch_us: float
    thrust_us: float
    yaw_rate_us: float
    engaged: bool
    valid: bool = True


def _horizontal() -> PidGains:
    # ~120 us/m: 1 m error -> ~8.5 deg of roll/pitch with 500 us = 35 deg full stick
    return PidGains(
        kp=120.0, ki=20.0, kd=80.0, d_filter_tau_s=0.1, out_min=-200.0, out_max=200.0,
        i_min=-100.0, i_max=100.0,
    )  # fmt: skip


def _vertical() -> PidGains:
    return PidGains(
        kp=150.0, ki=40.0, kd=60.0, d_filter_tau_s=0.1, out_min=-200.0, out_max=200.0,
        i_min=-150.0, i_max=150.0,
    )  # fmt: skip


def _yaw() -> PidGains:
    # 200 us/rad: 0.3 rad error -> 60 us -> ~18 deg/s with 500 us = 150 deg/s full stick
    return PidGains(kp=200.0, out_min=-150.0, out_max=150.0, wrap_error=True)


class DartControllerConfig(_Section):
    """The four decoupled PIDs (dart Fig. 6; gains in us per m, us per m*s, us*s per m, yaw in us
    per rad) and the axis mapping; from a Dart file's ``[control]`` and ``[runtime] control_hz``
    (companion.dart.params.controller_config)."""

    x: PidGains = Field(default_factory=_horizontal, description="C_x (marker x error -> axis_channels[0])")
    y: PidGains = Field(default_factory=_vertical, description="C_y (marker y error -> axis_channels[1])")
    z: PidGains = Field(default_factory=_horizontal, description="C_z (marker z error -> axis_channels[2])")
    yaw: PidGains = Field(default_factory=_yaw, description="C_psi (yaw error, wrapped)")
    axis_channels: tuple[Command, Command, Command] = _f(
        ("roll", "throttle", "pitch"), "-", "stick each of C_x, C_y, C_z drives (roll, pitch, throttle once each)"
    )
    axis_signs: tuple[float, float, float] = _f((1.0, 1.0, 1.0), "-", "sign of each of C_x, C_y, C_z (+1 or -1)")
    yaw_sign: float = _s(1.0, "-", "sign of C_psi (+1 or -1)")
    rate_hz: float = _s(22.0, "Hz", "control rate (dart sec. 4: half the 44 Hz PPM bandwidth)", gt=0.0)
    max_estimate_age_s: float = _s(0.3, "s", "an older estimate gives no contribution", gt=0.0)

    @model_validator(mode="after")
    def _axes(self) -> DartControllerConfig:
        if sorted(self.axis_channels) != ["pitch", "roll", "throttle"]:
            raise ValueError(f"axis_channels must use roll, pitch and throttle once each: {self.axis_channels}")
        if any(s not in (1.0, -1.0) for s in (*self.axis_signs, self.yaw_sign)):
            raise ValueError("axis_signs and yaw_sign must be +1 or -1")
        return self


class DartController:
    """C_x, C_y, C_z, C_psi (dart Fig. 6), engaged by the pilot's switch.

    Call :meth:`update` at the control rate with ``engaged`` from the pilot switch
    (dart.mixer.RcMixer.engaged_from). On every change of ``engaged`` all four PIDs are reset,
    so an engagement starts with zero integral (no wind-up jump) and a disengagement leaves
    nothing behind; while disengaged the contribution is zero and nothing integrates.
    """

    def __init__(self, config: DartControllerConfig | None = None) -> None:
        self.config = config or DartControllerConfig()
        c = self.config
        self.pid_x = Pid(c.x)
        self.pid_y = Pid(c.y)
        self.pid_z = Pid(c.z)
        self.pid_yaw = Pid(c.yaw)
        self._engaged = False
        self.engagements = 0
        self.invalid_steps = 0

    @property
    def engaged(self) -> bool:
        return self._engaged

    @property
    def pids(self) -> tuple[Pid, Pid, Pid, Pid]:
        return (self.pid_x, self.pid_y, self.pid_z, self.pid_yaw)

    def reset(self) -> None:
        for pid in self.pids:
            pid.reset()

    def engage(self) -> None:
        if not self._engaged:
            self.reset()
            self._engaged = True
            self.engagements += 1
            logger.info("dart controller engaged")

    def disengage(self) -> None:
        """Immediate: the integrators are reset here, not at the next step."""
        if self._engaged:
            logger.info("dart controller disengaged")
        self._engaged = False
        self.reset()

    def update(
        self,
        time_s: float,
        estimate: PoseLike | None,
        setpoint: DartSetpoint,
        engaged: bool,
    ) -> DartCommand:
        if not engaged:
            self.disengage()
            return DartCommand(time_s, 0.0, 0.0, 0.0, 0.0, engaged=False, valid=True)
        self.engage()
        c = self.config
        if (
            estimate is None
            or not (time_s - estimate.time_s <= c.max_estimate_age_s)
            or not all(math.isfinite(v) for v in (estimate.x_m, estimate.y_m, estimate.z_m, estimate.yaw_rad))
        ):
            self.invalid_steps += 1
            return DartCommand(time_s, 0.0, 0.0, 0.0, 0.0, engaged=True, valid=False)
        u = (
            self.pid_x.update(time_s, setpoint.x_m, estimate.x_m),
            self.pid_y.update(time_s, setpoint.y_m, estimate.y_m),
            self.pid_z.update(time_s, setpoint.z_m, estimate.z_m),
        )
        out = {"roll": 0.0, "pitch": 0.0, "throttle": 0.0}
        for channel, sign, value in zip(c.axis_channels, c.axis_signs, u, strict=True):
            out[channel] = sign * value
        yaw_rate = c.yaw_sign * self.pid_yaw.update(time_s, setpoint.yaw_rad, estimate.yaw_rad)
        return DartCommand(
            time_s=time_s,
            roll_us=out["roll"],
            pitch_us=out["pitch"],
            thrust_us=out["throttle"],
            yaw_rate_us=yaw_rate,
            engaged=True,
            valid=True,
        )

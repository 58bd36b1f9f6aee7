"""The simulated winch and the parcel on its line (mission.delivery = "winch"; docs/winch.md).

:class:`SimWinch` answers DO_WINCH as ArduCopter's AP_Winch does (PWM backend): relative length
control (param 3 metres more than the current line, at WINCH_POS_P per metre of error, at most
WINCH_RATE_MAX), rate control (param 4, clamped to WINCH_RATE_MAX), relaxed; its line length is
the integral of the commanded rate, as AP_Winch_PWM estimates it (no encoder).

:class:`ParcelOnLine` is the parcel: a point mass under gravity and linear air drag (towards the
wind) hanging from the vehicle on an inextensible line of the winch's length (a spherical
pendulum whose suspension point moves with the vehicle; the line only pulls). The line's pull on
the vehicle is not modelled (a parcel of a few hundred grams against a vehicle of a few kilograms).
It touches down where it first reaches the ground (down = 0); that point is scored against the pad.
``snag_height_m`` > 0: on its first way down it catches on an obstacle that high above the ground
(a branch, a roof edge) and hangs there, the line slack, until the line lifts it off. ``taut``: the
line held the parcel in the last step (what a load cell on the line weighs).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from companion.autopilot.winch import (
    MAV_WINCH_STATUS_FULLY_RETRACTED,
    MAV_WINCH_STATUS_HEALTHY,
    MAV_WINCH_STATUS_MOVING,
    WinchAction,
    WinchCommand,
)

G_M_S2 = 9.80665
STOWED_M = 0.02  # below this line length the parcel sits in its bay under the vehicle


class WinchCommandError(RuntimeError):
    """DO_WINCH ends in FAILED (no winch fitted, or an action ArduCopter does not implement)."""


@dataclass(frozen=True, slots=True)
class ParcelTouchdown:
    """Where and how the parcel first reached the ground (NED, m; speeds m/s)."""

    time_s: float
    north_m: float
    east_m: float
    horizontal_speed_m_s: float
    vertical_speed_m_s: float


class SimWinch:
    """The drum: line length under AP_Winch's control laws. ``stuck``: the drum does not turn (an
    encoder-fitted winch then reports the line as it is); ``reel_in_jams``: it pays out but does not
    turn inwards (reported as an encoder would: the line as it is, at speed 0)."""

    def __init__(self, rate_max_m_s: float = 1.0, pos_p: float = 1.0, stuck: bool = False, reel_in_jams: bool = False):
        self.rate_max_m_s = rate_max_m_s
        self.pos_p = pos_p
        self.stuck = stuck
        self.reel_in_jams = reel_in_jams
        self.mode = WinchAction.RATE_CONTROL  # AP_Winch::init without "spin freely": rate 0
        self.length_m = 0.0
        self.length_desired_m = 0.0
        self.rate_desired_m_s = 0.0
        self.commands: list[WinchCommand] = []

    def command(self, cmd: WinchCommand) -> None:
        """GCS_MAVLINK_Copter::handle_MAV_CMD_DO_WINCH on an enabled winch."""
        self.commands.append(cmd)
        if cmd.action is WinchAction.RELAXED:
            self.mode = WinchAction.RELAXED
            self.rate_desired_m_s = 0.0
        elif cmd.action is WinchAction.RELATIVE_LENGTH_CONTROL:
            self.length_desired_m = self.length_m + cmd.length_m
            self.mode = WinchAction.RELATIVE_LENGTH_CONTROL
        elif cmd.action is WinchAction.RATE_CONTROL:
            self.rate_desired_m_s = max(-self.rate_max_m_s, min(self.rate_max_m_s, cmd.rate_m_s))
            self.mode = WinchAction.RATE_CONTROL
        else:  # pragma: no cover - WinchAction has no other member
            raise WinchCommandError(f"winch action {cmd.action}")

    def step(self, dt: float) -> None:
        if self.mode is WinchAction.RELAXED:
            return  # the drum spins freely: AP_Winch_PWM stops its output and its estimate
        if self.mode is WinchAction.RELATIVE_LENGTH_CONTROL:
            err = self.length_desired_m - self.length_m
            self.rate_desired_m_s = max(-self.rate_max_m_s, min(self.rate_max_m_s, err * self.pos_p))
        if not self.stuck and not self._jammed():
            # the drum stops at fully retracted (AP's PWM estimate would run on below zero)
            self.length_m = max(0.0, self.length_m + self.rate_desired_m_s * dt)

    def _jammed(self) -> bool:
        return self.reel_in_jams and self.rate_desired_m_s < 0.0

    @property
    def speed_m_s(self) -> float:
        """The line's speed WINCH_STATUS reports: the commanded rate (AP_Winch_PWM), 0 while jammed."""
        return 0.0 if self._jammed() else self.rate_desired_m_s

    def flags(self) -> int:
        f = MAV_WINCH_STATUS_HEALTHY
        if self.length_m <= 0.0:
            f |= MAV_WINCH_STATUS_FULLY_RETRACTED
        if self.rate_desired_m_s != 0.0 and not self.stuck and not self._jammed():
            f |= MAV_WINCH_STATUS_MOVING
        return f


class ParcelOnLine:
    """The parcel's position and velocity (NED, m, m/s), stepped with the suspension point (the
    vehicle) and the line length. Semi-implicit Euler, then the line's constraint: a parcel
    farther than the line from the suspension point is put back on the sphere and loses the
    velocity it had away from it beyond the line's payout rate (relative to the suspension point)."""

    def __init__(self, drag_1_s: float = 0.3, snag_height_m: float = 0.0):
        self.drag_1_s = drag_1_s
        self.snag_height_m = snag_height_m
        self.p = [0.0, 0.0, 0.0]
        self.v = [0.0, 0.0, 0.0]
        self.on_ground = False
        self.released = False
        self.caught = False  # hanging on the obstacle at snag_height_m
        self.taut = False
        self._snag_done = snag_height_m <= 0.0  # caught once (or no obstacle): the way is clear
        self.touchdown: ParcelTouchdown | None = None
        self._attached = False  # follows the vehicle (stowed) until the line is out
        self._last_length_m = 0.0

    def stow(self, a: tuple[float, float, float], va: tuple[float, float, float]) -> None:
        self.p, self.v = list(a), list(va)
        self._attached = True

    def step(
        self,
        t: float,
        dt: float,
        a: tuple[float, float, float],
        va: tuple[float, float, float],
        length_m: float,
        wind: tuple[float, float, float] = (0.0, 0.0, 0.0),
    ) -> None:
        """One step: ``a``/``va`` the suspension point's position and velocity, ``length_m`` the line."""
        line_rate = (length_m - self._last_length_m) / dt if dt > 0.0 else 0.0
        self._last_length_m = length_m
        self.taut = False
        if self.released and self.on_ground:
            return
        if length_m < STOWED_M and not self.on_ground and not self.released:
            self.stow(a, va)
            return
        self._attached = False
        p, v = self.p, self.v
        d = [p[i] - a[i] for i in range(3)]
        dist = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
        if self.on_ground or self.caught:
            if self.released or dist <= length_m:
                return  # standing on the ground (or the obstacle), the line slack (or cut loose)
            self.on_ground = self.caught = False  # the line lifts it again (reeled in before the release)
        k = self.drag_1_s
        acc = [-k * (v[0] - wind[0]), -k * (v[1] - wind[1]), G_M_S2 - k * (v[2] - wind[2])]
        for i in range(3):
            v[i] += acc[i] * dt
            p[i] += v[i] * dt
        if not self.released:
            d = [p[i] - a[i] for i in range(3)]
            dist = math.sqrt(d[0] * d[0] + d[1] * d[1] + d[2] * d[2])
            if dist > length_m and dist > 0.0:
                self.taut = True
                u = [x / dist for x in d]
                for i in range(3):
                    p[i] = a[i] + u[i] * length_m
                # away from the suspension point faster than the line pays out: the line takes it
                vr = sum((v[i] - va[i]) * u[i] for i in range(3)) - line_rate
                if vr > 0.0:
                    for i in range(3):
                        v[i] -= vr * u[i]
        if not self._snag_done and not self.released and p[2] >= -self.snag_height_m:
            p[2] = -self.snag_height_m
            self.v = [0.0, 0.0, 0.0]
            self.caught, self._snag_done, self.taut = True, True, False
            return
        if p[2] >= 0.0:
            self.taut = False
            if self.touchdown is None:
                self.touchdown = ParcelTouchdown(t, p[0], p[1], math.hypot(v[0], v[1]), v[2])
            p[2] = 0.0
            self.v = [0.0, 0.0, 0.0]
            self.on_ground = True

    def release(self) -> None:
        self.released = True

"""The final descent onto a target (the pad, or home), in the mission frame F_I: a controller
of its own, apart from the mission's policy, which decides only whether it may hold and wait.

The vector field's convergence term scales with v_r, so at land speed it corrects only a few
cm/s; here the horizontal error is closed proportionally (``descent.xy_gain_1_s``: firm, so the
part of a gust the autopilot's velocity loop lets through is taken back within a fraction of a
second), plus an integral term when ``descent.xy_integral_gain_1_s2`` > 0, and with
``descent.xy_accel_feedforward`` > 0 a share of that command's rate sent as an acceleration, so an
autopilot whose velocity loop answers slowly (PX4 SIH: ~1 s) does not make the loop circle the pad
(docs/flying.md). The descent slows while the vehicle is off-centre and holds height at twice the
tolerance (like PX4's precision landing) down to ``descent.hold_min_height_m`` while the mission
says it may hold; with ``descent.settle_s`` it waits at that height until settled.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

from companion.config import DescentConfig

# descent.settle_s: the descent ramps to zero over the height it covers in this long at land speed
# above the floor, about what an autopilot's vertical velocity loop needs to stop (PX4, ArduCopter:
# 0.3-0.5 s)
SETTLE_BAND_S = 0.4
# descent.contact_time_s: contact is sought only this close to the ground by the estimate (PX4
# SIH's height, GPS only, was 1.2 m off at the ground after 20 s of flight), and only while the
# commanded descent is at least half the land speed (a hold or a settle's wait is not a contact)
CONTACT_HEIGHT_M = 2.0
CONTACT_DESCENDING = 0.5  # the vehicle was descending: its sink rate reached this share of the command
CONTACT_STOPPED = 0.25  # and then stayed below this share for descent.contact_time_s


@dataclass(frozen=True, slots=True)
class DescentCommand:
    """Velocity in F_I (m/s, z up) and, with the feedforward, a horizontal acceleration in F_I."""

    x_m_s: float
    y_m_s: float
    z_m_s: float
    accel_xy_m_s2: tuple[float, float] | None = None


class PrecisionDescent:
    """One descent's controller: made anew for each landing phase, so its integral and its wait
    start from nothing every time."""

    def __init__(self, cfg: DescentConfig, land_speed_m_s: float):
        """``cfg``: the controller's section (``[mission.descent]``); ``land_speed_m_s``: the
        mission's descent speed (mission.land_speed_m_s), which it slows from."""
        self.cfg = cfg
        self.land_speed_m_s = land_speed_m_s
        self.integral_m_s: tuple[float, float] = (0.0, 0.0)  # k_i * integral of the error (F_I)
        self._integral_t: float | None = None
        self._settle_since: float | None = None  # the error within the tolerance since (descent.settle_s)
        self._settle_released = False
        self.contact = False  # ground contact seen (descent.contact_time_s): only the descent from then on
        self._descending = False
        self._stopped_since: float | None = None
        # the sinking stopped near the ground after a commanded descent (the rule of _contact,
        # without its confirmation time and whatever contact_time_s says): a moving pad's feed-forward
        # switches to the vehicle's own velocity from then on (delivery.mission.moving_pad)
        self.grounded = False
        self._ground_descending = False

    def command(
        self,
        ex: float,
        ey: float,
        height_m: float,
        time_s: float,
        may_hold: bool,
        velocity_xy: Callable[[], tuple[float, float]],
        down_m_s: float | None = None,
    ) -> DescentCommand:
        """``ex``, ``ey``: the error from the target in F_I (m); ``height_m`` above the ground;
        ``may_hold``: the target in sight and time left before the touchdown timeout (the policy's
        gate for the hold above the floor and for descent.settle_s's wait); ``velocity_xy``: the
        estimated velocity in F_I, asked only for the feedforward; ``down_m_s``: the estimated sink
        rate, for the ground contact (descent.contact_time_s)."""
        c = self.cfg
        e = math.hypot(ex, ey)
        vz = -self.land_speed_m_s * self._slow(e, height_m, time_s, may_hold)
        if c.contact_time_s > 0.0 and down_m_s is not None and not self.contact:
            self.contact = self._contact(-vz, down_m_s, height_m, time_s)
        if down_m_s is not None and not self.grounded:
            self.grounded = self._sinking_stopped(-vz, down_m_s, height_m)
        zeroed = height_m < c.touchdown_height_m or self.contact
        vx, vy = -c.xy_gain_1_s * ex, -c.xy_gain_1_s * ey
        if c.xy_integral_gain_1_s2 > 0.0:
            # not summed while the sinking has stopped either: on the ground the estimate of a
            # vehicle that cannot move drifts under the sideways command, and the sum chases it
            frozen = zeroed or self.sinking_stopped
            ix, iy = self._integral(ex, ey, time_s, frozen=frozen, p_cmd=(vx, vy))
            vx -= ix
            vy -= iy
        vh = math.hypot(vx, vy)
        saturated = vh > c.max_xy_speed_m_s
        if saturated:
            vx, vy = vx * c.max_xy_speed_m_s / vh, vy * c.max_xy_speed_m_s / vh
        if zeroed:
            # touching down: a sideways command on the ground keeps the autopilot's land detector
            # from ever firing (ArduCopter), so only the descent remains
            vx = vy = 0.0
        acc = None
        if c.xy_accel_feedforward > 0.0 and not zeroed and not saturated:
            # the command's rate: d/dt(-k_p e - k_i int e) = -k_p v - k_i e, v the estimated velocity
            v_x, v_y = velocity_xy()
            k = c.xy_accel_feedforward
            ax = -k * (c.xy_gain_1_s * v_x + c.xy_integral_gain_1_s2 * ex)
            ay = -k * (c.xy_gain_1_s * v_y + c.xy_integral_gain_1_s2 * ey)
            acc = (ax, ay)
        return DescentCommand(vx, vy, vz, acc)

    @property
    def sinking_stopped(self) -> bool:
        """Near the ground, a descent that sank has stopped sinking (descent.contact_time_s): the
        contact is confirmed once this has lasted contact_time_s."""
        return self._stopped_since is not None and not self.contact

    def _slow(self, e: float, height_m: float, time_s: float, may_hold: bool) -> float:
        """The descent's speed factor: slower while off-centre (by e, m) and held at twice the
        tolerance while the mission says it may hold above descent.hold_min_height_m; with
        descent.settle_s the wait at that floor."""
        c = self.cfg
        tol = c.xy_tolerance_m
        gated = may_hold and height_m > c.hold_min_height_m
        slow = min(1.0, max(0.0, 1.0 - (e - tol) / tol)) if gated else 1.0
        if c.settle_s > 0.0 and not self._settle_released:
            slow = min(slow, self._settle_slow(e, height_m, time_s, may_hold))
        return slow

    def _contact(self, sink_cmd_m_s: float, sink_m_s: float, height_m: float, time_s: float) -> bool:
        """Ground contact (descent.contact_time_s): within CONTACT_HEIGHT_M of the ground, under a
        commanded sink of at least half the land speed, the vehicle sank at CONTACT_DESCENDING of
        it and then below CONTACT_STOPPED of it for contact_time_s. An autopilot's land detector
        waits longer (PX4: its ground-contact and maybe-landed stages, 2-3 s on SIH), while the
        estimate of a vehicle that cannot move drifts under a sideways command."""
        if height_m > CONTACT_HEIGHT_M or sink_cmd_m_s < 0.5 * self.land_speed_m_s:
            self._descending, self._stopped_since = False, None
            return False
        if sink_m_s >= CONTACT_DESCENDING * sink_cmd_m_s:
            self._descending, self._stopped_since = True, None
            return False
        if not self._descending or sink_m_s >= CONTACT_STOPPED * sink_cmd_m_s:
            self._stopped_since = None
            return False
        if self._stopped_since is None:
            self._stopped_since = time_s
        return time_s - self._stopped_since >= self.cfg.contact_time_s

    def _sinking_stopped(self, sink_cmd_m_s: float, sink_m_s: float, height_m: float) -> bool:
        """Within CONTACT_HEIGHT_M of the ground, under a commanded sink of at least half the land
        speed, the vehicle sank at CONTACT_DESCENDING of it and now sinks below CONTACT_STOPPED of it."""
        if height_m > CONTACT_HEIGHT_M or sink_cmd_m_s < 0.5 * self.land_speed_m_s:
            self._ground_descending = False
            return False
        if sink_m_s >= CONTACT_DESCENDING * sink_cmd_m_s:
            self._ground_descending = True
            return False
        return self._ground_descending and sink_m_s < CONTACT_STOPPED * sink_cmd_m_s

    def _settle_slow(self, e: float, height: float, time_s: float, may_wait: bool) -> float:
        """The descent's speed factor from descent.settle_s: 1 while the error has stayed within
        the tolerance for descent.settle_s (and from then on, once the vehicle is down to the
        floor's band), else proportional to the height above descent.hold_min_height_m over
        SETTLE_BAND_S x land speed (negative below it: climbs back), so the vehicle waits at the
        floor. No wait where the mission says it may not (as the hold)."""
        c = self.cfg
        if not may_wait:
            self._settle_since = None
            return 1.0
        if e > c.xy_tolerance_m:
            self._settle_since = None
        elif self._settle_since is None:
            self._settle_since = time_s
        settled = self._settle_since is not None and time_s - self._settle_since >= c.settle_s
        above_m = height - c.hold_min_height_m
        band_m = SETTLE_BAND_S * self.land_speed_m_s
        if settled:
            if above_m <= band_m:
                self._settle_released = True  # on down; the last part is not waited in again
            return 1.0
        # held at the floor on the fused height: the autopilot's own drifts near the ground (under
        # a zero vertical command the px4-sih profile's vehicle sank from 0.3 m to the ground)
        return min(1.0, max(-1.0, above_m / band_m))

    def _integral(
        self, ex: float, ey: float, time_s: float, frozen: bool, p_cmd: tuple[float, float]
    ) -> tuple[float, float]:
        """k_i * integral of the error (m/s, F_I): an autopilot flying our velocity on a biased
        estimate of its own moves at setpoint - bias, so the proportional law alone settles
        bias / k_p off the target (PX4 SIH: 0.2-0.4 m/s of bias near the ground, 4-8 cm at 5 1/s;
        docs/notes.md). Off by default and in params/ardupilot_quad.toml; params/px4_sih_quad.toml
        turns it on. Rectangle rule per guidance tick; the sum is held to
        descent.xy_integral_max_m_s and frozen once only the descent is commanded. Anti-windup by
        conditional integration: no sum while the command (``p_cmd``, the proportional part, minus
        the sum) is beyond descent.max_xy_speed_m_s and the step would take it further, so a
        descent that starts far off (GPS only: 0.8 m) does not carry a full sum past the target."""
        c = self.cfg
        last = self._integral_t
        self._integral_t = time_s
        if last is None:
            return self.integral_m_s
        dt = time_s - last
        ix0, iy0 = self.integral_m_s
        if not frozen and 0.0 < dt <= 1.0:  # a longer gap (link loss) adds nothing
            ki = c.xy_integral_gain_1_s2
            ix, iy = ix0 + ki * ex * dt, iy0 + ki * ey * dt
            n = math.hypot(ix, iy)
            lim = c.xy_integral_max_m_s
            if n > lim:
                ix, iy = ix * lim / n, iy * lim / n
            was = math.hypot(p_cmd[0] - ix0, p_cmd[1] - iy0)
            now = math.hypot(p_cmd[0] - ix, p_cmd[1] - iy)
            if not (now > c.max_xy_speed_m_s and now > was):
                self.integral_m_s = (ix, iy)
        return self.integral_m_s

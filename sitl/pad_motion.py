"""The simulated pad on a moving vehicle: its true pose as a function of simulated time
(``[sim.pad_motion]``, docs/moving-pad.md).

The pad stands at its place (the configured pad plus ``sim.pad_offset_m``, at its true heading)
until ``start_s``; it then speeds up straight along ``course_deg`` at ``accel_m_s2`` until it
reaches ``speed_m_s`` (after ``speed / accel`` seconds), and from there drives on at that speed,
its course and heading turning at ``turn_rate_deg_s`` (a circle of radius ``speed / rate``; the
centripetal acceleration is ``speed * rate``). Both pieces are closed form, so the pose at any
time is exact and costs a few floats: the camera's target, the UWB anchors (fixed on the pad, as
on a van's roof) and the truth scoring all read :meth:`PadTrack.pose` at their own instants.

Times are on the clock the landing sensors render with (the event loop's). On the embedded
simulator that clock starts at 0 with the flight, so ``start_s`` counts from there. On real
firmware it is the host's monotonic clock: the harness sets the track's origin
(:meth:`PadTrack.start_clock`) and, since the SITL's ground cannot carry the vehicle, stops the pad
at the vehicle's first ground contact (:meth:`PadTrack.stop_at`; docs/moving-pad.md).
"""

from __future__ import annotations

import math

from companion.geometry.se3 import Transform
from companion_sitl.params import SimPadMotionConfig


class PadTrack:
    """The true pad pose over time: ``T_world_pad0`` (the standing pad, world NED) moved by
    ``config``'s motion. ``yaw0_rad`` is the standing pad's heading (``pad_pose_ned``'s yaw)."""

    def __init__(self, config: SimPadMotionConfig, north_m: float, east_m: float, yaw0_rad: float = 0.0):
        from companion.geometry.mounts import pad_pose_ned

        self.config = config
        self.north0_m, self.east0_m, self.yaw0_rad = float(north_m), float(east_m), float(yaw0_rad)
        self._pose_of = pad_pose_ned
        self._v = config.speed_m_s
        self._c0 = math.radians(config.course_deg)
        self._w = math.radians(config.turn_rate_deg_s)
        self._t_ramp = self._v / config.accel_m_s2  # time to reach speed
        self._s_ramp = 0.5 * config.accel_m_s2 * self._t_ramp**2  # distance covered meanwhile
        # the clock time of the track's t = 0 (None: not started, the pad stands); and the clock
        # time from which the pad stands where it was then (None: it never stops)
        self.origin_s: float | None = 0.0
        self.stopped_s: float | None = None

    def start_clock(self, origin_s: float | None) -> None:
        """The track's t = 0 is clock time ``origin_s`` (None: not started, the pad stands)."""
        self.origin_s = origin_s

    def stop_at(self, t_s: float) -> None:
        """The pad stops dead at clock time ``t_s`` (earlier or later than now) and stands there
        from then on; a second call keeps the first stop."""
        if self.stopped_s is None:
            self.stopped_s = float(t_s)

    @property
    def moving(self) -> bool:
        """The pad moves at all (``speed_m_s`` > 0)."""
        return self._v > 0.0

    @property
    def max_accel_m_s2(self) -> float:
        """The largest acceleration of the pad over its motion: the ramp's, or the turn's
        centripetal ``speed * rate``, whichever is larger."""
        return max(self.config.accel_m_s2 if self.moving else 0.0, self._v * abs(self._w))

    def state(self, t_s: float) -> tuple[float, float, float, float, float]:
        """(north m, east m, yaw rad, north m/s, east m/s) of the pad at clock time ``t_s``."""
        if self.origin_s is None:
            return self.north0_m, self.east0_m, self.yaw0_rad, 0.0, 0.0
        if self.stopped_s is not None and t_s >= self.stopped_s:
            n, e, yaw, _, _ = self._moving_state(self.stopped_s - self.origin_s)
            return n, e, yaw, 0.0, 0.0
        return self._moving_state(t_s - self.origin_s)

    def _moving_state(self, t_s: float) -> tuple[float, float, float, float, float]:
        """:meth:`state` at track time ``t_s`` (from the origin), never stopped."""
        tau = t_s - self.config.start_s
        n0, e0, c0 = self.north0_m, self.east0_m, self._c0
        if not self.moving or tau <= 0.0:
            return n0, e0, self.yaw0_rad, 0.0, 0.0
        a = self.config.accel_m_s2
        if tau <= self._t_ramp:  # speeding up, straight along the course
            s, v = 0.5 * a * tau * tau, a * tau
            return n0 + s * math.cos(c0), e0 + s * math.sin(c0), self.yaw0_rad, v * math.cos(c0), v * math.sin(c0)
        n1, e1 = n0 + self._s_ramp * math.cos(c0), e0 + self._s_ramp * math.sin(c0)
        t2 = tau - self._t_ramp
        v, w = self._v, self._w
        c = c0 + w * t2
        if w == 0.0:
            dn, de = v * t2 * math.cos(c0), v * t2 * math.sin(c0)
        else:  # d(n, e)/dt = v (cos c, sin c), c = c0 + w t: integrated in closed form
            dn = v / w * (math.sin(c) - math.sin(c0))
            de = -v / w * (math.cos(c) - math.cos(c0))
        return n1 + dn, e1 + de, self.yaw0_rad + w * t2, v * math.cos(c), v * math.sin(c)

    def ne(self, t_s: float) -> tuple[float, float]:
        """The pad's centre (north, east) at ``t_s`` (world NED, m)."""
        n, e, _, _, _ = self.state(t_s)
        return n, e

    def velocity_ne(self, t_s: float) -> tuple[float, float]:
        """The pad's velocity (north, east) at ``t_s`` (m/s)."""
        _, _, _, vn, ve = self.state(t_s)
        return vn, ve

    def standing_pose(self) -> Transform:
        """``T_world_pad`` before the pad starts moving."""
        return self._pose_of(self.north0_m, self.east0_m, 0.0, yaw_rad=self.yaw0_rad)

    def pose(self, t_s: float) -> Transform:
        """``T_world_pad`` at ``t_s`` (as :func:`companion.geometry.mounts.pad_pose_ned`)."""
        n, e, yaw, _, _ = self.state(t_s)
        return self._pose_of(n, e, 0.0, yaw_rad=yaw)


def pad_track(config: SimPadMotionConfig, north_m: float, east_m: float, yaw0_rad: float = 0.0) -> PadTrack | None:
    """The pad's track, or None when ``[sim.pad_motion]`` is off (the pad stands: every
    simulation as before, bit for bit)."""
    track = PadTrack(config, north_m, east_m, yaw0_rad)
    return track if track.moving else None

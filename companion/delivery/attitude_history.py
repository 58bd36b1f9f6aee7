"""The autopilot's recent attitude, to find the attitude at a camera exposure (interpolated, yaw
the shortest way): what turns an observation made by the camera into NED at the moment it was
taken, not at the moment it arrived (a vehicle turning at 60 deg/s moves 3 deg in 50 ms)."""

from __future__ import annotations

import bisect

from companion.geometry.heading import heading_difference_rad
from companion.geometry.rotations import wrap_angle

ATTITUDE_HISTORY_S = 2.0  # attitude samples kept to find the attitude at an exposure


class AttitudeHistory:
    def __init__(self, keep_s: float = ATTITUDE_HISTORY_S):
        self.keep_s = keep_s
        self._t: list[float] = []
        self._att: list[tuple[float, float, float]] = []

    def add(self, time_s: float, roll_rad: float, pitch_rad: float, yaw_rad: float) -> None:
        """The autopilot's attitude (in time order; an older sample is ignored)."""
        if self._t and time_s < self._t[-1]:
            return
        self._t.append(time_s)
        self._att.append((roll_rad, pitch_rad, yaw_rad))
        cut = bisect.bisect_left(self._t, time_s - self.keep_s)
        if cut > 0:
            del self._t[:cut]
            del self._att[:cut]

    def at(self, time_s: float) -> tuple[float, float, float] | None:
        """The attitude at ``time_s``, interpolated between the samples around it (yaw the
        shortest way); the newest sample for a later time; None before the first sample."""
        ts = self._t
        if not ts or time_s < ts[0]:
            return None
        i = bisect.bisect_right(ts, time_s)
        if i >= len(ts):
            return self._att[-1]
        t0, t1 = ts[i - 1], ts[i]
        a0, a1 = self._att[i - 1], self._att[i]
        f = (time_s - t0) / (t1 - t0) if t1 > t0 else 0.0
        return (
            a0[0] + f * (a1[0] - a0[0]),
            a0[1] + f * (a1[1] - a0[1]),
            wrap_angle(a0[2] + f * heading_difference_rad(a1[2], a0[2])),
        )

"""External navigation, backend-neutral: the pose the companion gives the autopilot as its position
source (:class:`ExternalNavPose`) and the watch on the autopilot's GNSS that says when to switch to
it (:class:`GnssWatch`). The backends send the pose and switch the source
(:meth:`companion.autopilot.interface.Autopilot.send_external_nav`,
:meth:`~companion.autopilot.interface.Autopilot.use_external_nav`); docs/external-nav.md.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from companion.autopilot.types import GpsRaw


class ExternalNavError(ValueError):
    """An external-navigation pose that cannot be sent (not finite, a negative variance)."""


@dataclass(frozen=True, slots=True)
class ExternalNavPose:
    """The vehicle's pose in the autopilot's own local NED frame (its EKF origin), metres and
    radians, measured at ``time_s`` (the shell's monotonic clock), with the position's standard
    deviation per axis (m) and the attitude's (rad)."""

    time_s: float
    north_m: float
    east_m: float
    down_m: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    sigma_north_m: float
    sigma_east_m: float
    sigma_down_m: float
    sigma_attitude_rad: float

    def validate(self) -> ExternalNavPose:
        values = (
            self.time_s,
            self.north_m,
            self.east_m,
            self.down_m,
            self.roll_rad,
            self.pitch_rad,
            self.yaw_rad,
        )
        if not all(math.isfinite(v) for v in values):
            raise ExternalNavError(f"external-navigation pose not finite: {values}")
        sigmas = (self.sigma_north_m, self.sigma_east_m, self.sigma_down_m, self.sigma_attitude_rad)
        if not all(math.isfinite(s) and s > 0.0 for s in sigmas):
            raise ExternalNavError(f"external-navigation standard deviations must be finite and > 0: {sigmas}")
        return self

    def covariance_upper(self) -> list[float]:
        """VISION_POSITION_ESTIMATE's ``covariance``: the 6x6 (x, y, z, roll, pitch, yaw) matrix's
        upper-right triangle row by row, 21 values; diagonal only (ArduPilot reads entries 0, 6, 11
        for the position and 15, 18, 20 for the attitude)."""
        diag = (
            self.sigma_north_m**2,
            self.sigma_east_m**2,
            self.sigma_down_m**2,
            self.sigma_attitude_rad**2,
            self.sigma_attitude_rad**2,
            self.sigma_attitude_rad**2,
        )
        out: list[float] = []
        for row in range(6):
            for col in range(row, 6):
                out.append(diag[row] if row == col else 0.0)
        return out


class GnssWatch:
    """Whether the autopilot's GNSS is lost: its GPS_RAW_INT fix type below ``min_fix_type``, fewer
    than ``min_satellites``, or no GPS_RAW_INT at all for ``silent_after_s``, for longer than
    ``lost_after_s``. Fed each guidance tick with the newest :class:`GpsRaw` (None: none yet)."""

    def __init__(self, min_fix_type: int, min_satellites: int, lost_after_s: float, silent_after_s: float = 2.0):
        if not 0 <= min_fix_type <= 6 or min_satellites < 0 or lost_after_s < 0.0 or silent_after_s <= 0.0:
            raise ValueError(
                f"GnssWatch: min_fix_type {min_fix_type} (0-6), min_satellites {min_satellites} (>= 0), "
                f"lost_after_s {lost_after_s} (>= 0), silent_after_s {silent_after_s} (> 0)"
            )
        self.min_fix_type = min_fix_type
        self.min_satellites = min_satellites
        self.lost_after_s = lost_after_s
        self.silent_after_s = silent_after_s
        self.ever_good = False  # GNSS was good once: only then can it be lost
        self._bad_since: float | None = None
        self.reason = ""

    def bad_reason(self, now_s: float, gps: GpsRaw | None) -> str:
        """Why the GNSS is bad now ("" when it is good)."""
        if gps is None or now_s - gps.time_s > self.silent_after_s:
            return f"no GPS_RAW_INT for {self.silent_after_s:.1f} s"
        if gps.fix_type < self.min_fix_type:
            return f"GPS fix type {gps.fix_type} (< {self.min_fix_type})"
        if gps.satellites < self.min_satellites:
            return f"{gps.satellites} satellites (< {self.min_satellites})"
        return ""

    def update(self, now_s: float, gps: GpsRaw | None) -> bool:
        """True once the GNSS has been bad for ``lost_after_s`` after having been good."""
        reason = self.bad_reason(now_s, gps)
        if not reason:
            self.ever_good = True
            self._bad_since = None
            self.reason = ""
            return False
        if not self.ever_good:
            return False
        if self._bad_since is None:
            self._bad_since = now_s
        self.reason = reason
        return now_s - self._bad_since >= self.lost_after_s

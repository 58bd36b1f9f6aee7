"""The pad's heading as the camera measures it (a dock, a charger, a locker placed with a heading).

The configured heading (``mission.pad.heading_deg``) is where the pad should point; the camera's
observations, turned into NED by the autopilot's attitude at their exposure, say where it does.
Each observation within ``heading_tolerance_deg`` of the configured heading counts (further: a
wrong marker or a flipped pose, rejected); once ``MIN_OBSERVATIONS`` have counted, their circular
mean is the pad's heading and wins over the configured one (docs/pad-heading.md).
"""

from __future__ import annotations

import bisect
import logging
import math

from numpy.typing import ArrayLike

from companion.config import MissionConfig, PadConfig
from companion.geometry.heading import heading_difference_rad, measured_pad_heading_rad
from companion.geometry.rotations import wrap_angle

log = logging.getLogger(__name__)

MIN_OBSERVATIONS = 5  # accepted observations before the measured heading wins
ATTITUDE_HISTORY_S = 2.0  # attitude samples kept to find the attitude at an exposure


class PadHeadingEstimator:
    def __init__(self, configured_rad: float, tolerance_rad: float, min_observations: int = MIN_OBSERVATIONS):
        if not (math.isfinite(configured_rad) and math.isfinite(tolerance_rad) and tolerance_rad > 0):
            raise ValueError(
                f"pad heading {configured_rad!r} rad, tolerance {tolerance_rad!r} rad: must be finite, tolerance > 0"
            )
        if min_observations < 1:
            raise ValueError(f"min_observations = {min_observations}: must be >= 1")
        self.configured_rad = wrap_angle(configured_rad)
        self.tolerance_rad = tolerance_rad
        self.min_observations = min_observations
        self._att_t: list[float] = []
        self._att: list[tuple[float, float, float]] = []
        self._sin = 0.0
        self._cos = 0.0
        self.accepted = 0
        self.rejected = 0
        self.last_measured_rad: float | None = None

    def on_attitude(self, time_s: float, roll_rad: float, pitch_rad: float, yaw_rad: float) -> None:
        """The autopilot's attitude (in time order; an older sample is ignored)."""
        if self._att_t and time_s < self._att_t[-1]:
            return
        self._att_t.append(time_s)
        self._att.append((roll_rad, pitch_rad, yaw_rad))
        cut = bisect.bisect_left(self._att_t, time_s - ATTITUDE_HISTORY_S)
        if cut > 0:
            del self._att_t[:cut]
            del self._att[:cut]

    def attitude_at(self, time_s: float) -> tuple[float, float, float] | None:
        """The attitude at ``time_s``, interpolated between the samples around it (yaw the
        shortest way); the newest sample for a later time; None before the first sample."""
        ts = self._att_t
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

    def on_observation(self, time_s: float, R_camera_pad: ArrayLike, R_body_camera: ArrayLike) -> bool:
        """One unambiguous pad observation exposed at ``time_s``; True when it counted."""
        att = self.attitude_at(time_s)
        if att is None:
            return False
        h = measured_pad_heading_rad(att[0], att[1], att[2], R_body_camera, R_camera_pad)
        if not math.isfinite(h):
            return False
        self.last_measured_rad = h
        if abs(heading_difference_rad(h, self.configured_rad)) > self.tolerance_rad:
            self.rejected += 1
            if self.rejected == 1:
                log.warning(
                    "pad heading measured %.1f deg, configured %.1f deg: beyond the %.1f deg bound, not used",
                    math.degrees(h),
                    math.degrees(self.configured_rad),
                    math.degrees(self.tolerance_rad),
                )
            return False
        self._sin += math.sin(h)
        self._cos += math.cos(h)
        self.accepted += 1
        if self.accepted == self.min_observations:
            log.info(
                "pad heading measured %.1f deg (configured %.1f deg)",
                math.degrees(self.measured_rad or 0.0),
                math.degrees(self.configured_rad),
            )
        return True

    @property
    def measured_rad(self) -> float | None:
        """The circular mean of the counted observations, once there are enough; else None."""
        if self.accepted < self.min_observations:
            return None
        return math.atan2(self._sin, self._cos)

    @property
    def target_rad(self) -> float:
        """The heading to land on: the measured one once there is one, else the configured one."""
        m = self.measured_rad
        return self.configured_rad if m is None else m


def landed_pad(mission: MissionConfig, pad_index: int) -> PadConfig | None:
    """The pad the mission lands on: the first (index 0) or, after a divert, the alternate."""
    return mission.pad if pad_index == 0 else mission.alternate_pad


def pad_yaw_and_tolerance_rad(mission: MissionConfig, pad_index: int) -> tuple[float, float | None]:
    """The configured pad's yaw for its ``T_world_pad`` (0 without a heading: the pad frame's
    default, x east and y north) and the measured heading's bound (None: no heading)."""
    pad = landed_pad(mission, pad_index)
    if pad is None or pad.heading_deg is None:
        return 0.0, None
    return math.radians(pad.heading_deg), math.radians(pad.heading_tolerance_deg)


def landing_heading_rad(mission: MissionConfig, pad_index: int, estimator: PadHeadingEstimator | None) -> float | None:
    """The heading to touch down on (MissionInputs.pad_heading_rad): None for a pad without one;
    the camera's measurement once there is one, else the configured heading."""
    pad = landed_pad(mission, pad_index)
    if pad is None or pad.heading_deg is None:
        return None
    if estimator is not None:
        return estimator.target_rad
    return wrap_angle(math.radians(pad.heading_deg))

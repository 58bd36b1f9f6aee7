"""The pad's heading as the camera measures it (a dock, a charger, a locker placed with a heading).

The configured heading (``mission.pad.heading_deg``) is where the pad should point; the camera's
observations, turned into NED by the autopilot's attitude at their exposure, say where it does.
Each observation within ``heading_tolerance_deg`` of the configured heading counts (further: a
wrong marker or a flipped pose, rejected); once ``MIN_OBSERVATIONS`` have counted, the circular
mean of the recent ones is the pad's heading and wins over the configured one (docs/pad-heading.md).

Recent, not all: the heading is measured in the frame of the autopilot's yaw, and that frame
drifts within a descent (PX4 SIH's does by degrees, docs/pad-heading.md), so a yaw setpoint lands
aligned only if it is made from observations taken in the frame of now.
"""

from __future__ import annotations

import logging
import math

from numpy.typing import ArrayLike

from companion.config import MissionConfig, PadConfig
from companion.delivery.attitude_history import AttitudeHistory
from companion.delivery.recent_window import RecentWindow
from companion.geometry.heading import heading_difference_rad, measured_pad_heading_rad
from companion.geometry.rotations import wrap_angle

log = logging.getLogger(__name__)

MIN_OBSERVATIONS = 5  # accepted observations before the measured heading wins
HEADING_WINDOW_S = 1.0  # observations averaged: those exposed this long before the newest one


class PadHeadingEstimator:
    def __init__(
        self,
        configured_rad: float,
        tolerance_rad: float,
        min_observations: int = MIN_OBSERVATIONS,
        attitudes: AttitudeHistory | None = None,
    ):
        if not (math.isfinite(configured_rad) and math.isfinite(tolerance_rad) and tolerance_rad > 0):
            raise ValueError(
                f"pad heading {configured_rad!r} rad, tolerance {tolerance_rad!r} rad: must be finite, tolerance > 0"
            )
        if min_observations < 1:
            raise ValueError(f"min_observations = {min_observations}: must be >= 1")
        self.configured_rad = wrap_angle(configured_rad)
        self.tolerance_rad = tolerance_rad
        self.min_observations = min_observations
        self.attitudes = attitudes if attitudes is not None else AttitudeHistory()
        self._recent: RecentWindow[float] = RecentWindow(HEADING_WINDOW_S, min_observations)  # accepted, rad
        self._measured_rad: float | None = None  # their circular mean, once enough have counted
        self.accepted = 0
        self.rejected = 0
        self.last_measured_rad: float | None = None

    def on_attitude(self, time_s: float, roll_rad: float, pitch_rad: float, yaw_rad: float) -> None:
        """The autopilot's attitude (in time order; an older sample is ignored). A fusion that
        shares its ``attitudes`` with other estimators feeds that history instead."""
        self.attitudes.add(time_s, roll_rad, pitch_rad, yaw_rad)

    def on_observation(self, time_s: float, R_camera_pad: ArrayLike, R_body_camera: ArrayLike) -> bool:
        """One unambiguous pad observation exposed at ``time_s``; True when it counted."""
        att = self.attitudes.at(time_s)
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
        self._recent.add(time_s, h)
        self.accepted += 1
        if self.accepted >= self.min_observations:
            hs = self._recent.values()
            self._measured_rad = math.atan2(sum(math.sin(x) for x in hs), sum(math.cos(x) for x in hs))
        if self.accepted == self.min_observations:
            log.info(
                "pad heading measured %.1f deg (configured %.1f deg)",
                math.degrees(self.measured_rad or 0.0),
                math.degrees(self.configured_rad),
            )
        return True

    @property
    def measured_rad(self) -> float | None:
        """The circular mean of the recent counted observations (those within HEADING_WINDOW_S of
        the newest, at least min_observations), once enough have counted; else None."""
        return self._measured_rad

    @property
    def last_accepted_s(self) -> float:
        """Exposure time of the newest observation that counted (-inf: none yet)."""
        return self._recent.newest_s

    @property
    def target_rad(self) -> float:
        """The heading to land on: the measured one once there is one, else the configured one."""
        m = self.measured_rad
        return self.configured_rad if m is None else m


def heading_observation_age_s(estimator: PadHeadingEstimator | None, time_s: float) -> float:
    """Age of the newest heading observation that counted (MissionInputs.pad_heading_age_s); inf:
    none yet, or no camera heading measured."""
    if estimator is None:
        return math.inf
    return time_s - estimator.last_accepted_s


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

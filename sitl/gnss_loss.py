"""The simulated vehicle's GNSS lost, and its external navigation (docs/external-nav.md), as the
real ArduCopter 4.7-dev SITL behaves (measured 2026-12-02, lab/gnss_loss.py, SIM_GPS1_ENABLE = 0
at 10 m in the approach):

- GPS_RAW_INT goes on at fix type 1 with 3 satellites;
- EKF3 dead-reckons on, and without another position source declares its failsafe ("EKF
  variance", then "EKF Failsafe: changed to LAND Mode" with FS_EKF_ACTION = 1) 8.1 s after the
  GPS went off (:data:`EKF_FAILSAFE_AFTER_S`);
- on source set 2 with EK3_SRC2_POSXY = 6 it navigates on the VISION_POSITION_ESTIMATE it is sent
  (its horizontal estimate is that pose) and no failsafe follows while poses keep coming.

The dead-reckoned estimate keeps the error it had when the GPS went (this model's simplification:
the firmware's grows with its velocity error, which the SITL's ideal sensors keep near zero). Only
the ArduCopter profile has it: the PX4 profiles refuse (:class:`GnssLossError`), since PX4's
behaviour without GNSS is not measured here.
"""

from __future__ import annotations

import logging
import math

log = logging.getLogger(__name__)

#: GPS off to ArduCopter's EKF failsafe with no other position source, s (measured, module doc)
EKF_FAILSAFE_AFTER_S = 8.1
#: an external pose older than this is no position source (AP_NavEKF3's extNavMeasTime timeout, 0.2 s,
#: with the companion's 20 Hz stream), s
EXTERNAL_NAV_TIMEOUT_S = 0.5
#: GPS_RAW_INT after the GPS went off (measured): fix type, satellites
LOST_FIX_TYPE, LOST_SATELLITES = 1, 3
#: the profiles that model it
PROFILES_WITH_GNSS_LOSS = ("arducopter-sitl",)


class GnssLossError(ValueError):
    """A GNSS loss or an external-navigation request the simulated autopilot does not model."""


class SimGnss:
    """The vehicle's GNSS state and position source (source set 1: GNSS; 2 or 3: external nav)."""

    def __init__(self, profile_name: str) -> None:
        self.profile_name = profile_name
        self.lost_at_s = math.inf
        self.source_set = 1
        self.external_source_sets: tuple[int, ...] = (2,)  # EK3_SRC2_POSXY = 6 (lab/gnss_loss.py's params)
        self.pose_local: tuple[float, float, float, float] | None = None  # (time, N, E, D) local frame
        self.poses_received = 0
        self.error_at_loss: tuple[float, float] | None = None  # estimate - truth when the GPS went
        self.unaided_since_s = math.inf
        self.failsafe_s = math.inf

    def modelled(self, what: str) -> None:
        if self.profile_name not in PROFILES_WITH_GNSS_LOSS:
            only = ", ".join(PROFILES_WITH_GNSS_LOSS)
            raise GnssLossError(f"{what}: the {self.profile_name!r} profile does not model it (only {only})")

    @property
    def lost(self) -> bool:
        return math.isfinite(self.lost_at_s)

    def lose(self, t_s: float, error_ne_m: tuple[float, float]) -> None:
        self.modelled("GNSS loss")
        if not self.lost:
            self.lost_at_s = t_s
            self.unaided_since_s = t_s
            self.error_at_loss = error_ne_m

    def on_pose(self, t_s: float, north_m: float, east_m: float, down_m: float) -> None:
        self.modelled("external navigation")
        if not all(math.isfinite(v) for v in (north_m, east_m, down_m)):
            raise GnssLossError(f"external-navigation pose not finite: {(north_m, east_m, down_m)}")
        self.pose_local = (t_s, north_m, east_m, down_m)
        self.poses_received += 1

    def use_source_set(self, source_set: int) -> None:
        self.modelled("EKF source set")
        if source_set not in (1, 2, 3):
            raise GnssLossError(f"EKF source set {source_set}: ArduPilot has sets 1, 2 and 3")
        self.source_set = source_set

    def external_fresh(self, t_s: float) -> bool:
        p = self.pose_local
        return self.source_set in self.external_source_sets and p is not None and t_s - p[0] <= EXTERNAL_NAV_TIMEOUT_S

    def step(self, t_s: float) -> bool:
        """True once, when the EKF failsafe fires (no position source for EKF_FAILSAFE_AFTER_S)."""
        if not self.lost or math.isfinite(self.failsafe_s):
            return False
        if self.external_fresh(t_s):
            self.unaided_since_s = math.inf
            return False
        if not math.isfinite(self.unaided_since_s):
            self.unaided_since_s = t_s
        if t_s - self.unaided_since_s >= EKF_FAILSAFE_AFTER_S:
            self.failsafe_s = t_s
            return True
        return False

"""The simulated vehicle's GNSS lost, and its external navigation (docs/external-nav.md), as the
real ArduCopter 4.7-dev SITL behaves (measured 2026-12-02, lab/gnss_loss.py, SIM_GPS1_ENABLE = 0
at 10 m in the approach):

- GPS_RAW_INT goes on at fix type 1 with 3 satellites;
- EKF3 dead-reckons on, and without another position source declares its failsafe ("EKF
  variance", then "EKF Failsafe: changed to LAND Mode" with FS_EKF_ACTION = 1) 8.1 s after the
  GPS went off (:data:`EKF_FAILSAFE_AFTER_S`);
- on source set 2 with EK3_SRC2_POSXY = 6 it navigates on the VISION_POSITION_ESTIMATE it is sent
  (its horizontal estimate is that pose) and no failsafe follows while poses keep coming.

The ``px4-sih`` profile as the real PX4 v1.16 SIH behaves (measured 2026-12-03,
lab/gnss_loss_px4.py, ``sensor_gps_sim stop`` at 3 m in the descent and in a 5 m hover):

- GPS_RAW_INT goes on at fix type 0 with 255 satellites (1 Hz);
- without another position source PX4's failsafe takes the vehicle 5.3 s after the GPS went (5.2,
  5.3, 5.5 and 5.8 s measured): out of OFFBOARD into ALTCTL (Altitude mode: the height held, the
  companion sees a manual mode), from HOLD into AUTO.LAND ("Failsafe: blind land");
- EKF2 fuses the ODOMETRY it is sent (EKF2_EV_CTRL = 1) from the first one on, beside GNSS: no
  source switch; no failsafe follows while poses keep coming.

The dead-reckoned estimate keeps the error it had when the GPS went (this model's simplification:
ArduCopter's grows with its velocity error, which the SITL's ideal sensors keep near zero; PX4
SIH's noisy sensors made it drift metres in the 5 s before its failsafe). The ``ideal`` profile
refuses (:class:`GnssLossError`).
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

log = logging.getLogger(__name__)

#: GPS off to ArduCopter's EKF failsafe with no other position source, s (measured, module doc)
EKF_FAILSAFE_AFTER_S = 8.1
#: GPS off to PX4 SIH's failsafe with no other position source, s (measured, module doc)
PX4_FAILSAFE_AFTER_S = 5.3
#: an external pose older than this is no position source (AP_NavEKF3's extNavMeasTime timeout, 0.2 s,
#: with the companion's 20 Hz stream), s
EXTERNAL_NAV_TIMEOUT_S = 0.5


@dataclass(frozen=True)
class GnssLossModel:
    """How one profile's autopilot behaves without GNSS (module doc)."""

    failsafe_after_s: float  # GPS off to its failsafe's LAND with no other position source
    lost_fix_type: int  # GPS_RAW_INT after the GPS went off
    lost_satellites: int
    needs_source_set: bool  # ArduPilot: poses navigated on only on source set 2 or 3; PX4: always
    failsafe_texts: tuple[str, ...]  # its STATUSTEXTs at the failsafe
    failsafe_lands: bool = True  # False: PX4's ALTCTL out of OFFBOARD (the height held)


#: the profiles that model it
MODELS = {
    "arducopter-sitl": GnssLossModel(
        EKF_FAILSAFE_AFTER_S, 1, 3, True, ("EKF variance", "EKF Failsafe: changed to LAND Mode")
    ),
    "px4-sih": GnssLossModel(PX4_FAILSAFE_AFTER_S, 0, 255, False, ("Failsafe activated",), failsafe_lands=False),
}
PROFILES_WITH_GNSS_LOSS = tuple(MODELS)


class GnssLossError(ValueError):
    """A GNSS loss or an external-navigation request the simulated autopilot does not model."""


class SimGnss:
    """The vehicle's GNSS state and position source (source set 1: GNSS; 2 or 3: external nav)."""

    def __init__(self, profile_name: str) -> None:
        self.profile_name = profile_name
        self.model = MODELS.get(profile_name)
        self.lost_at_s = math.inf
        self.source_set = 1
        self.external_source_sets: tuple[int, ...] = (2,)  # EK3_SRC2_POSXY = 6 (lab/gnss_loss.py's params)
        self.pose_local: tuple[float, float, float, float] | None = None  # (time, N, E, D) local frame
        self.poses_received = 0
        self.error_at_loss: tuple[float, float] | None = None  # estimate - truth when the GPS went
        self.unaided_since_s = math.inf
        self.failsafe_s = math.inf

    def modelled(self, what: str) -> GnssLossModel:
        if self.model is None:
            only = ", ".join(PROFILES_WITH_GNSS_LOSS)
            raise GnssLossError(f"{what}: the {self.profile_name!r} profile does not model it (only {only})")
        return self.model

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
        p, m = self.pose_local, self.model
        if m is None or (m.needs_source_set and self.source_set not in self.external_source_sets):
            return False
        return p is not None and t_s - p[0] <= EXTERNAL_NAV_TIMEOUT_S

    def step(self, t_s: float) -> bool:
        """True once, when the failsafe fires (no position source for the model's failsafe_after_s)."""
        if not self.lost or math.isfinite(self.failsafe_s) or self.model is None:
            return False
        if self.external_fresh(t_s):
            self.unaided_since_s = math.inf
            return False
        if not math.isfinite(self.unaided_since_s):
            self.unaided_since_s = t_s
        if t_s - self.unaided_since_s >= self.model.failsafe_after_s:
            self.failsafe_s = t_s
            return True
        return False

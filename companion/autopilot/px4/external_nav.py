"""PX4's external navigation: the companion's pose as ODOMETRY for EKF2's external vision
(docs/external-nav.md, the PX4 section).

Why ODOMETRY in MAV_FRAME_LOCAL_NED and not VISION_POSITION_ESTIMATE: PX4 takes the latter as a
FRD frame, and EKF2 then rotates the position by the heading difference between its attitude and
the pose's, which turns a small yaw error into a position error growing with the distance from the
origin; in LOCAL_NED the position is taken as it is. Position only, as on ArduPilot: EKF2_EV_CTRL
fuses the horizontal position alone (bit 0), so the velocity (zero, with a variance of
UNKNOWN_VARIANCE: the fused velocity is the autopilot's own) and the attitude (the pose's, which is
the autopilot's) are carried but never fused. No NaN: MavlinkDirect's JSON cannot carry one.
``time_usec`` is the pose's time on the monotonic clock, which PX4 maps into its own through
MAVSDK's TIMESYNC, as for LANDING_TARGET.

PX4 has no source switch: with EKF2_EV_CTRL bit 0 EKF2 fuses the pose beside GNSS (as a relative
measurement while GNSS is fused) and carries on with it alone when GNSS stops, so
:meth:`use_external_nav` and :meth:`use_gnss` change nothing on the vehicle.
"""

from __future__ import annotations

import json
import logging
from typing import Any

from companion.autopilot.external_nav import ExternalNavPose
from companion.autopilot.interface import AutopilotError
from companion.autopilot.liveness import LoopLiveness
from companion.geometry import euler_to_quat

log = logging.getLogger(__name__)

MAV_FRAME_LOCAL_NED = 1
MAV_FRAME_BODY_FRD = 12
MAV_ESTIMATOR_TYPE_VISION = 2
ODOMETRY_QUALITY_FULL = 100  # 0 is "unknown", -1 "failed"; EKF2_EV_QMIN compares with it
UNKNOWN_VARIANCE = 1e4  # of what the pose does not measure (velocity, rates), (m/s)^2


def odometry_fields(pose: ExternalNavPose, time_usec: int) -> str:
    """ODOMETRY's fields as MavlinkDirect's JSON: position, attitude and their covariance's diagonal;
    velocity zero with UNKNOWN_VARIANCE."""
    cov = [0.0] * 21  # the upper-right triangle of the 6x6 (x, y, z, roll, pitch, yaw) matrix, row by row
    cov[0], cov[6], cov[11] = pose.sigma_north_m**2, pose.sigma_east_m**2, pose.sigma_down_m**2
    cov[15] = cov[18] = cov[20] = pose.sigma_attitude_rad**2
    vcov = [0.0] * 21
    vcov[0] = vcov[6] = vcov[11] = vcov[15] = vcov[18] = vcov[20] = UNKNOWN_VARIANCE
    q = [float(v) for v in euler_to_quat(pose.roll_rad, pose.pitch_rad, pose.yaw_rad)]
    fields = {
        "time_usec": time_usec,
        "frame_id": MAV_FRAME_LOCAL_NED,
        "child_frame_id": MAV_FRAME_BODY_FRD,
        "x": pose.north_m,
        "y": pose.east_m,
        "z": pose.down_m,
        "q": q,
        "vx": 0.0,
        "vy": 0.0,
        "vz": 0.0,
        "rollspeed": 0.0,
        "pitchspeed": 0.0,
        "yawspeed": 0.0,
        "pose_covariance": cov,
        "velocity_covariance": vcov,
        "reset_counter": 0,
        "estimator_type": MAV_ESTIMATOR_TYPE_VISION,
        "quality": ODOMETRY_QUALITY_FULL,
    }
    return json.dumps(fields, allow_nan=False)


class Px4ExternalNav:
    """ODOMETRY out through MavlinkDirect; no source switch (see the module doc)."""

    system_id: int
    link_ok: bool
    liveness: LoopLiveness
    _system: Any
    _direct_sync: Any

    external_nav_sent = 0
    external_nav_dropped = 0

    def send_external_nav(self, pose: ExternalNavPose) -> None:
        """One ODOMETRY now, non-blocking; dropped (counted) without a link or while the loop is
        stalled (the liveness gate: a frozen companion's stale pose never goes out)."""
        pose.validate()
        if self._system is None or not self.link_ok or not self.liveness.may_send():
            self.external_nav_dropped += 1
            return
        from mavsdk.plugins.mavlink_direct import MavlinkMessage

        fields = odometry_fields(pose, max(0, int(pose.time_s * 1e6)))
        try:
            self._direct_sync.send_message(MavlinkMessage("ODOMETRY", 0, 0, self.system_id, 1, fields))
        except Exception as err:  # MAVSDK's MavlinkDirectError, or the link gone
            self.external_nav_dropped += 1
            log.debug("ODOMETRY not sent: %s", err)
            return
        self.external_nav_sent += 1

    def external_nav_source_name(self, source_set: int) -> str:
        del source_set  # PX4 has no source sets
        return "EKF2 external vision (EKF2_EV_CTRL), fused beside GNSS until it went"

    async def use_external_nav(self, source_set: int) -> None:
        """Nothing to switch: EKF2 has fused the pose since it began (module doc)."""
        if source_set not in (2, 3):
            raise AutopilotError(f"external_nav.source_set {source_set}: expected 2 or 3")
        log.info("PX4: EKF2 goes on with the external-vision pose alone (no source switch)")

    async def use_gnss(self) -> None:
        """Nothing to switch: EKF2 takes GNSS again by itself once its checks pass."""
        log.info("PX4: EKF2 takes GNSS back by itself")

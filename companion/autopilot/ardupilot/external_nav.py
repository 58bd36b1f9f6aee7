"""ArduPilot's external navigation: the companion's pose as VISION_POSITION_ESTIMATE
(AP_VisualOdom with VISO_TYPE = 1, MAVLink) and the switch of EKF3's position source to it with
MAV_CMD_SET_EKF_SOURCE_SET (docs/external-nav.md).

Why VISION_POSITION_ESTIMATE and not ODOMETRY: the fused pose's velocity is the autopilot's own
velocity (the companion's EKF takes it as its process input), so sending it back would feed EKF3
its own estimate; the position is what the camera and the UWB hold, so position only (EK3_SRC2_VELXY
= 0). GCS_MAVLINK::handle_common_vision_position_estimate_data reads the covariance's entries 0, 6,
11 (position) and 15, 18, 20 (attitude) as cbrt(sum of the variances squared), the error EK3 fuses
the position with (constrained to 0.01-10 m); the attitude is used only with EK3_SRC2_YAW = 6.
``usec`` is the companion's time since the backend started: ArduPilot corrects a remote clock's
offset and jitter itself (its jitter correction wants a monotonic stamp, which this is).
"""

from __future__ import annotations

import logging
import time

from companion.autopilot.ardupilot.dialect import mavlink
from companion.autopilot.ardupilot.requests import ArduPilotRequests
from companion.autopilot.external_nav import ExternalNavPose

log = logging.getLogger(__name__)

MAV_CMD_SET_EKF_SOURCE_SET = 42007  # param1: the source set, 1-3 (ArduPilot's EK3_SRCn_*)


class ArduPilotExternalNav(ArduPilotRequests):
    """VISION_POSITION_ESTIMATE out, and the EKF source set switched."""

    external_nav_sent = 0
    external_nav_dropped = 0

    def send_external_nav(self, pose: ExternalNavPose) -> None:
        """One VISION_POSITION_ESTIMATE now, non-blocking; dropped (counted) without a link or while
        the loop is stalled (the liveness gate: a frozen companion's stale pose never goes out)."""
        pose.validate()
        if not self.link_ok or self.target_system is None or not self.liveness.may_send():
            self.external_nav_dropped += 1
            return
        usec = max(0, int((pose.time_s - self._t_boot) * 1e6))
        cov = pose.covariance_upper()
        ok = self._send(
            lambda mav: mav.vision_position_estimate_send(
                usec, pose.north_m, pose.east_m, pose.down_m, pose.roll_rad, pose.pitch_rad, pose.yaw_rad, cov, 0
            )
        )
        if ok:
            self.external_nav_sent += 1
        else:
            self.external_nav_dropped += 1

    async def use_external_nav(self, source_set: int) -> None:
        """EKF3 on source set ``source_set`` (2 or 3), whose EK3_SRCn_POSXY = 6 takes the pose sent;
        raises :class:`~companion.autopilot.interface.CommandRejected` when ArduCopter refuses."""
        if source_set not in (1, 2, 3):
            raise ValueError(f"EKF source set {source_set}: ArduPilot has sets 1, 2 and 3")
        t0 = time.monotonic()
        await self._command(MAV_CMD_SET_EKF_SOURCE_SET, source_set, what=f"EKF source set {source_set}")
        log.info("EKF3 source set %d accepted in %.0f ms", source_set, (time.monotonic() - t0) * 1e3)

    async def use_gnss(self) -> None:
        """EKF3 back on source set 1 (GNSS, copter.parm's EK3_SRC1_*)."""
        await self._command(MAV_CMD_SET_EKF_SOURCE_SET, 1, what="EKF source set 1")


# the dialect knows the command by name from ArduPilot's common.xml of 2023 on
assert getattr(mavlink, "MAV_CMD_SET_EKF_SOURCE_SET", MAV_CMD_SET_EKF_SOURCE_SET) == MAV_CMD_SET_EKF_SOURCE_SET

"""The delivery shell's external-navigation feed (``[external_nav] enabled``, docs/external-nav.md).

Each guidance tick, once the landing fusion has locked the pad and while the camera or the UWB
was fused within ``pad_data_max_age_s``, the fused pose goes to the autopilot at ``rate_hz``
(:meth:`Autopilot.send_external_nav`), in the autopilot's own frame: the fused position is in the
frame where the pad sits at its configured position, and the EKF's GPS-bias state b is what
separates the two (delivery eq 12: the autopilot's position is p + b), so p + b is sent. The
autopilot's position therefore does not jump when it switches to it, and the fusion's h_SDK keeps
seeing what it predicts.

The autopilot's GNSS is watched (:class:`~companion.autopilot.external_nav.GnssWatch`). When it is
lost:

- near the pad (the pose is being sent): the autopilot's position source is switched to it
  (:meth:`Autopilot.use_external_nav`, ArduPilot's EKF source set ``source_set``), once; the
  mission flies on (it steers on the fused estimate there, and releases only on a locked pad);
- GNSS good again for GNSS_BACK_S (2 s): the autopilot goes back to it (EKF source set 1), so the
  way home, out of camera and UWB range, does not fly on a source that no longer comes;
- anywhere else (outbound, homebound, out of camera and UWB range): nothing is switched; the
  autopilot's own failsafe acts (ArduCopter: the EKF failsafe, FS_EKF_ACTION), which takes the
  vehicle out of GUIDED, which ends the companion's autonomy (a mode it did not ask for: the
  pilot-takeover path). No release follows either way: a release needs a locked pad.

Each decision is a WARNING event (a STATUSTEXT to the operator's GCS with ``[gcs]``).
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from companion.autopilot.external_nav import ExternalNavError, ExternalNavPose, GnssWatch
from companion.autopilot.interface import Autopilot, AutopilotError
from companion.config import ExternalNavConfig
from companion.events import EventKind, MissionEvent, Phase

log = logging.getLogger(__name__)

#: GNSS good this long after a loss counts as back (the switch back to it), s
GNSS_BACK_S = 2.0


@dataclass
class ExternalNavStats:
    poses_sent: int = 0
    poses_refused: int = 0  # not finite: never sent
    gnss_lost_at_s: float = math.nan  # when the GNSS was found lost (the shell's clock)
    switch_requested_at_s: float = math.nan
    switch_accepted_at_s: float = math.nan
    switch_failed: str = ""
    # the autopilot's position minus the pose sent, the tick before the switch and the first after
    # its acceptance: the jump the switch makes in the autopilot's position, m
    position_before_switch_ned_m: tuple[float, float, float] | None = None
    position_after_switch_ned_m: tuple[float, float, float] | None = None


def fused_pose_in_autopilot_frame(fusion: Any, sigma_min_m: float) -> ExternalNavPose | None:
    """The fused estimate as the autopilot's frame sees it (p + b), with the EKF's standard
    deviation of p + b per axis (at least ``sigma_min_m``); None before the fusion has an estimate."""
    est = fusion.estimate()
    if est is None:
        return None
    P = fusion.ekf.P
    sig = []
    for i in range(3):
        var = float(P[i, i] + P[6 + i, 6 + i] + 2.0 * P[i, 6 + i])
        sig.append(max(sigma_min_m, math.sqrt(var) if var > 0.0 else 0.0))
    att_var = float(np.max(np.diag(P)[3:6]))
    return ExternalNavPose(
        est.time_s,
        est.north_m + est.gps_bias_north_m,
        est.east_m + est.gps_bias_east_m,
        est.down_m + est.gps_bias_down_m,
        est.roll_rad,
        est.pitch_rad,
        est.yaw_rad,
        sig[0],
        sig[1],
        sig[2],
        max(0.01, math.sqrt(att_var) if att_var > 0.0 else 0.0),
    )


class ExternalNavFeed:
    def __init__(self, config: ExternalNavConfig, autopilot: Autopilot):
        self.config = config
        self.autopilot = autopilot
        self.watch = GnssWatch(config.gnss_min_fix_type, config.gnss_min_satellites, config.gnss_lost_after_s)
        self.stats = ExternalNavStats()
        self.period_s = 1.0 / config.rate_hz
        self._next_send_s = -math.inf
        self._last_pose: ExternalNavPose | None = None
        self._gnss_lost = False
        self._switch: asyncio.Task[None] | None = None
        self.switched = False

    @property
    def streaming(self) -> bool:
        """A pose went out within the last half second."""
        return self._last_pose is not None and self._last_sent_s + 0.5 >= self._now

    _last_sent_s = -math.inf
    _now = -math.inf

    def step(self, now: float, fusion: Any, phase: Phase) -> tuple[MissionEvent, ...]:
        """One guidance tick: the pose sent when due, the GNSS watched, the source switched when it
        is lost near the pad; the events of this tick (WARNING)."""
        self._now = now
        self._send_when_due(now, fusion)
        self._measure_jump()
        lost = self.watch.update(now, self.autopilot.telemetry.gps)
        if self._gnss_lost and not self.watch.reason:
            return self._gnss_back(now, phase)
        self._good_since_s = math.inf
        if not lost or self._gnss_lost:
            return ()
        self._gnss_lost = True
        self.stats.gnss_lost_at_s = now
        if self.streaming:
            self.stats.switch_requested_at_s = now
            self.stats.position_before_switch_ned_m = self._autopilot_minus_pose()
            self._switch = asyncio.get_running_loop().create_task(self._use_external_nav())
            detail = (
                f"GNSS lost ({self.watch.reason}): the autopilot navigates on the fused pose "
                f"({self.autopilot.external_nav_source_name(self.config.source_set)})"
            )
        else:
            detail = (
                f"GNSS lost ({self.watch.reason}) out of camera and UWB range: no external navigation, "
                "the autopilot's failsafe acts; no release"
            )
        log.warning("t=%.2f %s", now, detail)
        return (MissionEvent(now, EventKind.WARNING, phase, detail),)

    _good_since_s = math.inf

    def _gnss_back(self, now: float, phase: Phase) -> tuple[MissionEvent, ...]:
        """GNSS good again for GNSS_BACK_S after a loss: the autopilot back on it (when it was
        switched), and a later loss is a new one."""
        if not math.isfinite(self._good_since_s):
            self._good_since_s = now
        if now - self._good_since_s < GNSS_BACK_S:
            return ()
        self._gnss_lost = False
        self._good_since_s = math.inf
        detail = "GNSS back"
        if self.switched or (self._switch is not None and not self._switch.done()):
            if self._switch is not None and not self._switch.done():
                self._switch.cancel()
            self.switched = False
            self._switch = asyncio.get_running_loop().create_task(self._use_gnss())
            detail = "GNSS back: the autopilot navigates on it again (EKF source set 1)"
        log.warning("t=%.2f %s", now, detail)
        return (MissionEvent(now, EventKind.WARNING, phase, detail),)

    async def _use_gnss(self) -> None:
        try:
            await self.autopilot.use_gnss()
        except AutopilotError as err:
            log.error("the autopilot refused to go back to GNSS: %s", err)

    def _send_when_due(self, now: float, fusion: Any) -> None:
        if fusion is None or not fusion.pad_locked or now < self._next_send_s:
            return
        if fusion.pad_data_age_s(now) > self.config.pad_data_max_age_s:
            return
        pose = fused_pose_in_autopilot_frame(fusion, self.config.position_sigma_min_m)
        if pose is None:
            return
        try:
            self.autopilot.send_external_nav(pose)
        except ExternalNavError as err:
            self.stats.poses_refused += 1
            log.warning("external-navigation pose not sent: %s", err)
            return
        except AutopilotError as err:  # the autopilot cannot take one: said once, never sent again
            self.stats.switch_failed = str(err)
            self._next_send_s = math.inf
            log.error("external navigation off: %s", err)
            return
        self._next_send_s = max(self._next_send_s + self.period_s, now)
        self._last_pose = pose
        self._last_sent_s = now
        self.stats.poses_sent += 1

    def _autopilot_minus_pose(self) -> tuple[float, float, float] | None:
        pos, pose = self.autopilot.telemetry.position_ned, self._last_pose
        if pos is None or pose is None:
            return None
        return (pos.north_m - pose.north_m, pos.east_m - pose.east_m, pos.down_m - pose.down_m)

    def _measure_jump(self) -> None:
        st = self.stats
        if self.switched and st.position_after_switch_ned_m is None:
            pos = self.autopilot.telemetry.position_ned
            if pos is not None and pos.time_s > st.switch_accepted_at_s + 0.5:
                st.position_after_switch_ned_m = self._autopilot_minus_pose()

    async def _use_external_nav(self) -> None:
        try:
            await self.autopilot.use_external_nav(self.config.source_set)
        except AutopilotError as err:
            self.stats.switch_failed = str(err)
            log.error("the autopilot refused external navigation: %s; its failsafe acts", err)
            return
        self.switched = True
        self.stats.switch_accepted_at_s = asyncio.get_running_loop().time()
        source = self.autopilot.external_nav_source_name(self.config.source_set)
        log.warning("the autopilot navigates on the fused pose (%s)", source)

    async def stop(self) -> None:
        task = self._switch
        if task is not None and not task.done():
            task.cancel()
            with contextlib.suppress(asyncio.CancelledError):
                await task

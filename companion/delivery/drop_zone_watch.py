"""The drop-zone check in flight (docs/drop-zone.md): each detected frame of the approach and the
descent is also judged by :class:`companion.vision.drop_zone.DropZoneCheck`, and the verdict goes
to the mission (``MissionInputs.drop_zone``), whose drop-zone policy stops the descent above an
occupied pad.

The pad's pose in the frame is the detector's when the outer marker gives it (a lone inner marker's
tilt is off by degrees, and the check extrapolates it a metre and a half past the pad), else one
predicted from the landing fusion's estimate: the pad hidden by a box is exactly when the detector
has no pose to give.
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from companion.config import DropZoneConfig
from companion.geometry import Transform
from companion.vision.detector import check_image
from companion.vision.drop_zone import DropZoneCheck, DropZoneStatus, DropZoneVerdict

log = logging.getLogger(__name__)


def predicted_camera_pad(fusion: Any, T_body_camera: Transform) -> Transform | None:
    """The pad's pose in the camera from the landing fusion's estimate; None before the pad is
    locked (until then the estimate places the pad where GPS says, metres from where it lies)."""
    est = fusion.estimate() if fusion is not None and fusion.pad_locked else None
    if est is None:
        return None
    T_world_body = Transform.from_euler(est.position_ned, est.roll_rad, est.pitch_rad, est.yaw_rad)
    T_world_cam = T_world_body @ T_body_camera
    return T_world_cam.inverse() @ fusion.T_world_pad


def detector_pose(obs: Any) -> Transform | None:
    """The detector's pad pose when it can serve the check: unambiguous and from the outer marker."""
    if obs is None or getattr(obs, "ambiguous", False) or "outer" not in obs.markers:
        return None
    pose: Transform = obs.T_camera_pad
    return pose


class DropZoneWatch:
    """One camera stream's drop-zone verdict over a flight; :meth:`judge` may run off the event
    loop (on the detector's thread), :meth:`verdict` on it. ``reset`` on a new pad (a divert)."""

    def __init__(self, camera_model: Any, layout: Any, config: DropZoneConfig):
        self.config = config
        self.check = DropZoneCheck(camera_model, layout, config)
        self._size = camera_model.size
        self._last: DropZoneStatus | None = None
        self._reported = DropZoneVerdict.UNKNOWN
        self.frames_judged = 0
        self.frames_predicted = 0  # judged on the fusion's predicted pose (no outer marker)

    def reset(self) -> None:
        self.check.reset()
        self._last = None

    def judge(self, image: Any, time_s: float, obs: Any, T_predicted: Transform | None) -> DropZoneStatus | None:
        """One frame exposed at ``time_s`` with the detector's observation (None: not seen) and the
        fusion's predicted pose; None when neither gives a pose (the check cannot place the pad)."""
        T_use = detector_pose(obs)
        if T_use is None:
            T_use = T_predicted
            if T_use is None:
                return None
            self.frames_predicted += 1
        gray = np.ascontiguousarray(check_image(image, self._size))
        if obs is not None:
            st = self.check.update(gray, time_s, T_use, obs.markers, obs.corners_px)
        else:
            st = self.check.update(gray, time_s, T_use)
        self.frames_judged += 1
        self._last = st
        return st

    def verdict(self, now_s: float) -> DropZoneVerdict:
        """The verdict for the mission at ``now_s``: UNKNOWN when no frame was judged within the
        configured ``stale_s`` (the check's own staleness needs a frame to notice)."""
        st = self._last
        stale = st is None or now_s - st.evidence.time_s > self.config.stale_s
        v = DropZoneVerdict.UNKNOWN if stale or st is None else st.verdict
        if v is not self._reported:
            why = st.evidence.reason if st is not None else "no frame judged"
            log.info(
                "drop zone %s -> %s at t=%.2f (%s; %d frames judged, %d on the predicted pose)",
                self._reported.value,
                v.value,
                now_s,
                why,
                self.frames_judged,
                self.frames_predicted,
            )
            self._reported = v
        return v

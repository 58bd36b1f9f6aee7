"""The autopilot's roll and pitch error, measured on a pad that lies level (``landing.ekf_level_pad``).

Each unambiguous camera observation, turned into NED by the autopilot's attitude at its exposure,
shows the pad tilted by that attitude's error (:mod:`companion.geometry.level`). The mean of the
recent tilts (those exposed within TILT_WINDOW_S of the newest, never fewer than MIN_OBSERVATIONS)
is taken out of the attitude the EKF fuses (delivery eq 12), so the camera's position measurement
(eqs 13-14) is turned into NED with the true tilt: a tilt error of d puts the fused position
h x tan(d) off at a height h above the pad (docs/firmware-px4.md: PX4 SIH's is 1-2.5 deg).
A tilt beyond ``max_tilt_rad`` is not the autopilot's error but a wrong pose (the IPPE mirror pair)
or a pad that does not lie level: rejected and counted.
"""

from __future__ import annotations

import logging
import math

import numpy as np
from numpy.typing import ArrayLike

from companion.delivery.attitude_history import AttitudeHistory
from companion.delivery.recent_window import RecentWindow
from companion.geometry.level import pad_tilt_rotvec, tilt_rotation
from companion.geometry.rotations import euler_to_rotmat, rotmat_to_euler

log = logging.getLogger(__name__)

MIN_OBSERVATIONS = 5  # accepted observations before the tilt is taken out
TILT_WINDOW_S = 2.0  # observations averaged: those exposed this long before the newest one
MAX_TILT_RAD = math.radians(6.0)  # an autopilot's attitude error beyond this: not believed


class PadTiltEstimator:
    def __init__(
        self,
        attitudes: AttitudeHistory,
        max_tilt_rad: float = MAX_TILT_RAD,
        min_observations: int = MIN_OBSERVATIONS,
    ):
        if not (math.isfinite(max_tilt_rad) and max_tilt_rad > 0.0):
            raise ValueError(f"max_tilt_rad = {max_tilt_rad!r}: must be finite and > 0")
        if min_observations < 1:
            raise ValueError(f"min_observations = {min_observations}: must be >= 1")
        self.attitudes = attitudes
        self.max_tilt_rad = max_tilt_rad
        self.min_observations = min_observations
        self._recent: RecentWindow[np.ndarray] = RecentWindow(TILT_WINDOW_S, min_observations)  # accepted rotvecs
        # their mean and its rotation E, once enough have counted: computed per observation, used
        # on every autopilot position sample
        self._tilt: np.ndarray | None = None
        self._E: np.ndarray | None = None
        self.accepted = 0
        self.rejected = 0

    def on_observation(self, time_s: float, R_camera_pad: ArrayLike, R_body_camera: ArrayLike) -> bool:
        """One unambiguous pad observation exposed at ``time_s``; True when it counted."""
        att = self.attitudes.at(time_s)
        if att is None:
            return False
        R_wp = euler_to_rotmat(*att) @ np.asarray(R_body_camera, dtype=float) @ np.asarray(R_camera_pad, dtype=float)
        e = pad_tilt_rotvec(R_wp)
        tilt = math.hypot(float(e[0]), float(e[1]))
        if not math.isfinite(tilt):
            return False
        if tilt > self.max_tilt_rad:
            self.rejected += 1
            if self.rejected == 1:
                log.warning(
                    "the pad seen tilted %.1f deg: beyond the %.1f deg an autopilot's attitude is off, not used",
                    math.degrees(tilt),
                    math.degrees(self.max_tilt_rad),
                )
            return False
        self._recent.add(time_s, e)
        self.accepted += 1
        if self.accepted >= self.min_observations:
            self._tilt = np.mean(self._recent.values(), axis=0)
            self._E = tilt_rotation(self._tilt)
        if self.accepted == self.min_observations:
            log.info(
                "autopilot attitude error from the level pad: %.2f / %.2f deg about north / east",
                *np.degrees(self._tilt[:2]),  # type: ignore[index]
            )
        return True

    @property
    def tilt_rotvec(self) -> np.ndarray | None:
        """The mean tilt of the recent counted observations (NED rotation vector, rad), once
        enough have counted; else None."""
        return self._tilt

    def corrected(self, euler_rad: ArrayLike) -> np.ndarray:
        """The autopilot's attitude (roll, pitch, yaw) with the measured tilt taken out; as given
        until the tilt is measured."""
        eul = np.asarray(euler_rad, dtype=float).reshape(3)
        if self._E is None:
            return eul
        return np.array(rotmat_to_euler(self._E.T @ euler_to_rotmat(float(eul[0]), float(eul[1]), float(eul[2]))))

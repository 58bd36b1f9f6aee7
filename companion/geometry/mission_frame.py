"""The delivery mission frame F_I (delivery section 4.1) and its conversion to/from NED.

F_I has its origin at the pad (p_f = 0), its x axis horizontal and pointing from the start
towards the pad, and z up; y = z x x completes a right-handed frame (left of travel). This is
the only place that converts between F_I and the world NED frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from companion.geometry.rotations import FloatArray, wrap_angle


@dataclass(frozen=True, eq=False)
class MissionFrame:
    """F_I anchored at ``pad_ned`` with its x axis along NED heading ``heading_rad``."""

    pad_ned: FloatArray  # pad centre (ground level) in world NED, metres
    heading_rad: float  # NED yaw of F_I's x axis (from start towards pad)

    @staticmethod
    def from_start_and_pad(start_ned: ArrayLike, pad_ned: ArrayLike) -> MissionFrame:
        s = np.asarray(start_ned, dtype=float)
        p = np.asarray(pad_ned, dtype=float)
        dn, de = p[0] - s[0], p[1] - s[1]
        if math.hypot(dn, de) < 1e-6:
            raise ValueError("start and pad coincide horizontally: the mission frame is undefined")
        return MissionFrame(p.copy(), math.atan2(de, dn))

    @property
    def R_ned_mission(self) -> FloatArray:
        """Columns are F_I's axes expressed in NED: x = (c, s, 0), y = (s, -c, 0), z = (0,0,-1)."""
        c, s = math.cos(self.heading_rad), math.sin(self.heading_rad)
        return np.array([[c, s, 0.0], [s, -c, 0.0], [0.0, 0.0, -1.0]])

    def point_to_ned(self, p_mission: ArrayLike) -> FloatArray:
        return self.pad_ned + self.R_ned_mission @ np.asarray(p_mission, dtype=float)

    def point_from_ned(self, p_ned: ArrayLike) -> FloatArray:
        return self.R_ned_mission.T @ (np.asarray(p_ned, dtype=float) - self.pad_ned)

    def vector_to_ned(self, v_mission: ArrayLike) -> FloatArray:
        return self.R_ned_mission @ np.asarray(v_mission, dtype=float)

    def vector_from_ned(self, v_ned: ArrayLike) -> FloatArray:
        return self.R_ned_mission.T @ np.asarray(v_ned, dtype=float)

    def yaw_to_ned(self, yaw_mission_rad: float) -> float:
        """A yaw about F_I's z (up, counter-clockwise seen from above) as an NED yaw."""
        return wrap_angle(self.heading_rad - yaw_mission_rad)

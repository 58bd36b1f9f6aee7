"""A level pad as an attitude reference: the tilt the camera sees on a pad that lies level is the
error of the attitude the observation was turned into NED with.

With the autopilot's attitude R_wb = E R_wb_true off by the world-frame rotation E, an observation
R_camera_pad of a level pad gives R_world_pad = R_wb R_body_camera R_camera_pad = E R_level, so
the pad's normal is E turned up, and R_wb_true = E^T R_wb.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from companion.geometry.rotations import euler_to_rotmat, rotmat_to_euler, rotvec_to_rotmat


def pad_tilt_rotvec(R_world_pad: ArrayLike) -> np.ndarray:
    """The tilt of a pad whose orientation in world NED is ``R_world_pad``: the rotation vector
    (NED, rad; about a horizontal axis) of the shortest rotation taking up (a level pad's normal,
    its z axis) to the pad's normal. For an attitude error about a horizontal axis that rotation is
    E exactly; a heading error is :mod:`companion.geometry.heading`'s business."""
    n = np.asarray(R_world_pad, dtype=float).reshape(3, 3)[:, 2]
    axis = np.cross(_UP, n)  # (n_e, -n_n, 0): horizontal
    s = float(np.hypot(axis[0], axis[1]))
    if s == 0.0:
        return np.zeros(3)
    angle = math.atan2(s, float(_UP @ n))
    return np.array([axis[0] / s * angle, axis[1] / s * angle, 0.0])


def tilt_rotation(tilt_rotvec: ArrayLike) -> np.ndarray:
    """E, the rotation matrix of a tilt's rotation vector (:func:`pad_tilt_rotvec`)."""
    return rotvec_to_rotmat(tilt_rotvec)


def untilted_euler(
    roll_rad: float, pitch_rad: float, yaw_rad: float, tilt_rotvec: ArrayLike
) -> tuple[float, float, float]:
    """The attitude (ZYX Euler, rad) with a world-frame tilt error taken out: E^T R_wb, E the
    rotation of ``tilt_rotvec`` (:func:`pad_tilt_rotvec` of an observation turned by this attitude)."""
    return rotmat_to_euler(tilt_rotation(tilt_rotvec).T @ euler_to_rotmat(roll_rad, pitch_rad, yaw_rad))


_UP = np.array([0.0, 0.0, -1.0])  # NED

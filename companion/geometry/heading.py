"""Headings: the pad's heading from its pose, and turning a yaw setpoint towards a heading.

A heading is a NED yaw (radians, clockwise from north seen from above). A pad's heading is where
its 'up' edge (the pad frame's +y axis, see :mod:`companion.geometry.mounts`) points; a vehicle is
aligned with the pad when its yaw (the direction of its nose) equals the pad's heading.
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import ArrayLike

from companion.geometry.rotations import euler_to_rotmat, wrap_angle


def pad_heading_rad(R_world_pad: ArrayLike) -> float:
    """The heading of a pad whose orientation in world NED is ``R_world_pad`` (pad frame: x
    right, y up the printed pad, z out of it): the direction of its +y axis projected on the
    horizontal plane. ``pad_pose_ned(..., yaw_rad=h)`` has heading h."""
    R = np.asarray(R_world_pad, dtype=float).reshape(3, 3)
    return math.atan2(float(R[1, 1]), float(R[0, 1]))


def measured_pad_heading_rad(
    roll_rad: float, pitch_rad: float, yaw_rad: float, R_body_camera: ArrayLike, R_camera_pad: ArrayLike
) -> float:
    """The pad's heading from one camera observation (``R_camera_pad``, the pad's orientation in
    the camera) and the vehicle's attitude at the exposure: R_world_pad = R_world_body R_body_camera
    R_camera_pad. In the frame of the attitude's yaw: an autopilot's yaw offset is in the result
    too, so a yaw setpoint to this heading aligns the vehicle with the pad on the truth."""
    R_wb = euler_to_rotmat(roll_rad, pitch_rad, yaw_rad)
    R_bc = np.asarray(R_body_camera, dtype=float).reshape(3, 3)
    R = R_wb @ R_bc @ np.asarray(R_camera_pad, dtype=float).reshape(3, 3)
    return pad_heading_rad(R)


def heading_difference_rad(a_rad: float, b_rad: float) -> float:
    """a - b wrapped to [-pi, pi): the shortest signed turn from b to a."""
    return wrap_angle(a_rad - b_rad)


def yaw_toward(current_rad: float, target_rad: float, max_step_rad: float) -> float:
    """The yaw setpoint one step from ``current_rad`` towards ``target_rad`` the shortest way
    round, turning at most ``max_step_rad`` (>= 0); the result is wrapped to [-pi, pi)."""
    if not max_step_rad >= 0.0:
        raise ValueError(f"max_step_rad = {max_step_rad!r}: must be >= 0")
    d = heading_difference_rad(target_rad, current_rad)
    if abs(d) <= max_step_rad:
        return wrap_angle(target_rad)
    return wrap_angle(current_rad + math.copysign(max_step_rad, d))

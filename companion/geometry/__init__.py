"""Frames, rotations, quaternions, SE(3) and flat-earth conversion.

Conventions (docs/architecture.md): SI units, radians inside; world frame local NED at the origin;
mission frame F_I (delivery section 4.1) with origin at the pad, x horizontal towards the pad
from the start, z up; body frame FRD; quaternions (w, x, y, z) Hamilton; Euler roll-pitch-yaw
ZYX; ``T_a_b`` is the pose of b in a (maps points from b to a).
"""

from companion.geometry.earth import GeoPoint, LocalTangentPlane, geo_to_ned, ned_to_geo
from companion.geometry.mission_frame import MissionFrame
from companion.geometry.rotations import (
    euler_rates_matrix,
    euler_to_quat,
    euler_to_rotmat,
    quat_conjugate,
    quat_multiply,
    quat_normalize,
    quat_rotate,
    quat_to_euler,
    quat_to_rotmat,
    rot_x,
    rot_y,
    rot_z,
    rotmat_to_euler,
    rotmat_to_quat,
    wrap_angle,
)
from companion.geometry.se3 import Transform

__all__ = [
    "GeoPoint",
    "LocalTangentPlane",
    "MissionFrame",
    "Transform",
    "euler_rates_matrix",
    "euler_to_quat",
    "euler_to_rotmat",
    "geo_to_ned",
    "ned_to_geo",
    "quat_conjugate",
    "quat_multiply",
    "quat_normalize",
    "quat_rotate",
    "quat_to_euler",
    "quat_to_rotmat",
    "rot_x",
    "rot_y",
    "rot_z",
    "rotmat_to_euler",
    "rotmat_to_quat",
    "wrap_angle",
]

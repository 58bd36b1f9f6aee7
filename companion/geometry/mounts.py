"""Sensor mounts and the pad frame, one convention for the app, the EKF and the simulator.

- Downward camera: OpenCV camera frame (x right, y down, z optical axis) with the image top edge
  towards the body's front: camera x -> body y (right), camera y -> body -x, camera z -> body z.
- Pad frame (OpenCV ArUco marker frame): x right, y up (in the image of the printed pad), z out
  of the pad (up). Laid flat with yaw 0, pad x points east and pad y north.
"""

from __future__ import annotations

import math

import numpy as np

from companion.geometry.rotations import rot_x, rot_z
from companion.geometry.se3 import Transform

R_BODY_CAMERA_DOWN = rot_z(math.pi / 2.0)


def downward_mount(offset_body_m: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> Transform:
    """``T_body_camera`` for the downward camera at ``offset_body_m`` (FRD) from the body origin."""
    return Transform(R_BODY_CAMERA_DOWN.copy(), np.asarray(offset_body_m, dtype=float))


def pad_pose_ned(north_m: float = 0.0, east_m: float = 0.0, down_m: float = 0.0, yaw_rad: float = 0.0) -> Transform:
    """``T_world_pad`` for a pad lying flat at (north, east, down); yaw turns the pad's y axis
    from north towards east. Pad x = east, y = north, z = up when yaw = 0."""
    R0 = rot_z(math.pi / 2.0) @ rot_x(math.pi)  # columns: pad x = E, pad y = N, pad z = up
    return Transform(rot_z(yaw_rad) @ R0, np.array([north_m, east_m, down_m], dtype=float))

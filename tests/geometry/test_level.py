"""A level pad as an attitude reference (companion.geometry.level): the tilt seen on the pad is
the attitude's world-frame error, and taking it out gives the true attitude back."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from companion.geometry.level import pad_tilt_rotvec, untilted_euler
from companion.geometry.mounts import downward_mount, pad_pose_ned
from companion.geometry.rotations import euler_to_rotmat, rotmat_to_euler

R_BC = downward_mount().R


def test_a_level_pad_has_no_tilt_at_any_heading() -> None:
    for h in (-170.0, -30.0, 0.0, 45.0, 135.0):
        assert np.allclose(pad_tilt_rotvec(pad_pose_ned(yaw_rad=math.radians(h)).R), 0.0, atol=1e-12)


def test_a_pad_tilted_about_north_by_two_degrees() -> None:
    """By hand: a rotation of 2 deg about north (NED x) applied in the world to a level pad."""
    E = Rotation.from_rotvec([math.radians(2.0), 0.0, 0.0]).as_matrix()
    e = pad_tilt_rotvec(E @ pad_pose_ned(yaw_rad=math.radians(60.0)).R)
    assert np.degrees(e) == pytest.approx([2.0, 0.0, 0.0], abs=1e-9)


@pytest.mark.parametrize("att_deg", [(0.0, 0.0, 0.0), (3.0, -5.0, 120.0), (-8.0, 2.0, -100.0)])
@pytest.mark.parametrize("err_deg", [(1.5, -2.0), (-2.5, 0.4)])
def test_the_tilt_seen_on_a_level_pad_is_the_attitudes_error_and_taking_it_out_gives_the_truth(
    att_deg: tuple[float, float, float], err_deg: tuple[float, float]
) -> None:
    R_true = euler_to_rotmat(*np.radians(att_deg))
    E = Rotation.from_rotvec([math.radians(err_deg[0]), math.radians(err_deg[1]), 0.0]).as_matrix()
    R_reported = E @ R_true  # the autopilot's attitude, off by E in the world
    R_wp = pad_pose_ned(yaw_rad=math.radians(30.0)).R
    R_cp = (R_true @ R_BC).T @ R_wp  # what the camera sees of the level pad
    e = pad_tilt_rotvec(R_reported @ R_BC @ R_cp)
    assert np.degrees(e[:2]) == pytest.approx(err_deg, abs=1e-6)
    fixed = untilted_euler(*rotmat_to_euler(R_reported), e)
    assert np.allclose(euler_to_rotmat(*fixed), R_true, atol=1e-6)

"""Heading math: a pad's heading from its pose and from a camera observation, and the yaw setpoint
turning towards a heading the shortest way (docs/pad-heading.md)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from companion.geometry.heading import heading_difference_rad, measured_pad_heading_rad, pad_heading_rad, yaw_toward
from companion.geometry.mounts import downward_mount, pad_pose_ned
from companion.geometry.rotations import euler_to_rotmat


@pytest.mark.parametrize("heading_deg", [0.0, 45.0, 135.0, 179.0, -90.0, -179.5])
def test_pad_heading_is_the_yaw_of_its_pose(heading_deg: float) -> None:
    T = pad_pose_ned(3.0, -2.0, 0.0, yaw_rad=math.radians(heading_deg))
    assert math.degrees(pad_heading_rad(T.R)) == pytest.approx(heading_deg, abs=1e-9)
    # heading 0: the pad's up edge (its +y axis) points north
    assert pad_pose_ned().R[:, 1] == pytest.approx([1.0, 0.0, 0.0])


@pytest.mark.parametrize(
    ("roll_deg", "pitch_deg", "yaw_deg", "pad_deg"),
    [(0.0, 0.0, 0.0, 135.0), (4.0, -6.0, 30.0, 135.0), (-3.0, 2.0, -170.0, 175.0), (8.0, 5.0, 91.0, -45.0)],
)
def test_measured_heading_from_a_synthetic_observation(
    roll_deg: float, pitch_deg: float, yaw_deg: float, pad_deg: float
) -> None:
    """The camera sees R_camera_pad = (R_world_body R_body_camera)^T R_world_pad; turned back by the
    attitude it gives the pad's heading, whatever the vehicle's roll, pitch and yaw."""
    att = [math.radians(a) for a in (roll_deg, pitch_deg, yaw_deg)]
    R_wb = euler_to_rotmat(*att)
    R_bc = downward_mount((0.1, 0.0, 0.05)).R
    R_wp = pad_pose_ned(yaw_rad=math.radians(pad_deg)).R
    R_cp = (R_wb @ R_bc).T @ R_wp
    h = measured_pad_heading_rad(att[0], att[1], att[2], R_bc, R_cp)
    assert math.degrees(heading_difference_rad(h, math.radians(pad_deg))) == pytest.approx(0.0, abs=1e-9)


def test_a_yaw_offset_of_the_autopilot_is_in_the_measured_heading() -> None:
    """An autopilot whose yaw reads 4 deg high measures the pad 4 deg high too: a yaw setpoint to it
    (in the same autopilot frame) aligns the vehicle with the pad on the truth."""
    true_yaw, bias = math.radians(20.0), math.radians(4.0)
    R_bc = downward_mount().R
    R_wp = pad_pose_ned(yaw_rad=math.radians(135.0)).R
    R_cp = (euler_to_rotmat(0.0, 0.0, true_yaw) @ R_bc).T @ R_wp
    h = measured_pad_heading_rad(0.0, 0.0, true_yaw + bias, R_bc, R_cp)
    assert math.degrees(h) == pytest.approx(139.0, abs=1e-9)


def test_yaw_toward_turns_the_short_way_round_across_180() -> None:
    step = math.radians(5.0)
    # from 170 deg to -170 deg: 20 deg through 180, not 340 deg back through 0
    y = yaw_toward(math.radians(170.0), math.radians(-170.0), step)
    assert math.degrees(y) == pytest.approx(175.0)
    y = yaw_toward(y, math.radians(-170.0), step)
    assert math.degrees(y) == pytest.approx(-180.0)
    y = yaw_toward(y, math.radians(-170.0), step)
    assert math.degrees(y) == pytest.approx(-175.0)
    # and the other way: -175 to 175 turns negative through -180
    assert math.degrees(yaw_toward(math.radians(-175.0), math.radians(175.0), step)) == pytest.approx(180.0 - 360.0)


def test_yaw_toward_reaches_the_target_and_limits_the_step() -> None:
    assert yaw_toward(0.1, 0.12, 0.05) == pytest.approx(0.12)
    assert yaw_toward(0.0, math.radians(135.0), math.radians(6.0)) == pytest.approx(math.radians(6.0))
    assert yaw_toward(0.0, math.radians(-135.0), math.radians(6.0)) == pytest.approx(math.radians(-6.0))
    assert yaw_toward(1.0, 2.0, 0.0) == 1.0
    with pytest.raises(ValueError, match="max_step_rad"):
        yaw_toward(0.0, 1.0, -0.1)
    with pytest.raises(ValueError, match="max_step_rad"):
        yaw_toward(0.0, 1.0, float("nan"))


def test_the_turn_takes_at_most_180_deg_at_the_rate() -> None:
    """Any start, any target: stepping at the rate reaches the target within 180 deg / step steps."""
    rng = np.random.default_rng(5)
    step = math.radians(60.0) * 0.05
    for _ in range(200):
        y, target = (float(v) for v in rng.uniform(-math.pi, math.pi, 2))
        for _ in range(int(math.pi / step) + 1):
            y = yaw_toward(y, target, step)
        assert abs(heading_difference_rad(y, target)) < 1e-12
